"""Speed against error, measured in one run on this machine, for one scene.

Every applicable model variant is trained on the same data, with the same seed and the same
wall-clock budget (the cosine schedule ends with the budget); the validation error is recorded
against training time (time-to-accuracy curves). Then, on the test split, for every integrator and
step size: acceleration throughput (states/s), rollout cost (s per 1000 steps for a batch of 64),
held-out relative L2 acceleration error, median time until the angle error first exceeds 0.1, and
the mean true-energy drift |E(t) - E(0)| / (V_max - V_min) (for a scene with inputs and friction:
the power-balance error |E(t) - E(0) - W(t)|, rollouts driven by the recorded inputs, and the
inverse-dynamics torque error of the structured models). The scene's closed form is the ceiling
row of both speed and accuracy. Timings run on one thread after warm-up (medians); training on
``--threads``.

    python scripts/benchmark.py --scene double_pendulum --minutes 5      # ~35 min
    python scripts/benchmark.py --scene relativistic_particle --minutes 2
    python scripts/benchmark.py --report          # merge into results/benchmark/README.md and summary.md

Writes ``<scene>.json``, ``<scene>.md``, ``<scene>_curves.png`` and ``<scene>_pareto.png`` (and, for
the double pendulum, the stability table of every variant) to ``--output-dir`` (default
``results/benchmark``); the training runs' TensorBoard logs go to ``lightning_logs/benchmark_<scene>``.
"""

from __future__ import annotations

import argparse
import functools
import json
import time
from pathlib import Path

import numpy as np
import torch
from _common import ROOT, HelpFormatter, add_output_dir, wrote

from lnn_torch.perf import machine_header, median_seconds

OUT = ROOT / "results" / "benchmark"

# per scene: dataset (generated if missing), default budget (minutes), rollout horizon (s), threshold
SCENES = {
    "double_pendulum": dict(path="data/quickstart.h5", spec=dict(num_trajectories=200, duration=20.0, seed=0),
                            minutes=5.0, horizon=10.0, threshold=0.1),
    "chain_pendulum": dict(path="data/bench_chain_pendulum.h5", spec=dict(num_trajectories=200, duration=20.0, seed=0),
                           minutes=4.0, horizon=10.0, threshold=0.1),
    "pendulum": dict(path="data/bench_pendulum.h5", spec=dict(num_trajectories=200, duration=10.0, seed=0),
                     minutes=1.0, horizon=10.0, threshold=0.1),
    "mass_spring": dict(path="data/bench_mass_spring.h5", spec=dict(num_trajectories=200, duration=10.0, seed=0),
                        minutes=1.0, horizon=10.0, threshold=0.1),
    "relativistic_particle": dict(path="data/bench_relativistic_particle.h5",
                                  spec=dict(num_trajectories=200, duration=10.0, seed=0),
                                  minutes=2.0, horizon=10.0, threshold=0.1),
    "actuated_double_pendulum": dict(path="data/actuated_double_pendulum.h5",
                                     spec=dict(num_trajectories=200, duration=10.0, seed=0),
                                     minutes=5.0, horizon=10.0, threshold=0.1),
    # the 7-joint arm (MuJoCo ground truth): the data of configs/robot_arm.yaml; one integrator at the
    # data's rate; single points from many trajectories per batch (four payload parameters), the
    # inverse-dynamics (torque) loss beside the acceleration loss, checkpoints kept for identification
    "robot_arm": dict(path="data/robot_arm.h5", spec=dict(num_trajectories=1000, duration=3.0, dt=0.005, seed=0),
                      minutes=5.0, horizon=3.0, threshold=0.1, integrators=[("rk4", 0.005)], chunk_len=1,
                      chunks_per_batch=512, torque_weight=1.0, variants="arm"),
    # the same arm built from a perturbed copy of its description (masses +-20 %, centres of mass +-1 cm,
    # inertias +-30 %, armature and damping changed): what a user with a URDF and a real robot has
    "robot_arm_perturbed": dict(scene="robot_arm", scene_config={"perturbation": 1}, path="data/robot_arm_perturbed.h5",
                                spec=dict(num_trajectories=1000, duration=3.0, dt=0.005, seed=0),
                                minutes=5.0, horizon=3.0, threshold=0.1, integrators=[("rk4", 0.005)], chunk_len=1,
                                chunks_per_batch=512, torque_weight=1.0, variants="perturbed_arm"),
}
GREY_BOX = {"kinetic": {"spatial": {}}, "potential": {"spatial": {}}}
RESIDUAL = {"kinetic": {"spatial": {}, "mlp": {}}, "potential": {"spatial": {}, "mlp": {}}}
DESCRIPTION = {"kinetic": {"spatial": {"learn": False}}, "potential": {"spatial": {}}}
ARM_VARIANTS = {
    "arm": [("film_lnn", {"variant": "film_lnn", "model_options": {"mass_invariant": [0]}}),
            ("grey box", {"variant": "film_lnn", "model_options": GREY_BOX, "eps": 0.0}),
            ("grey box + residual", {"variant": "film_lnn", "model_options": RESIDUAL, "eps": 0.0}),
            ("delan", {"variant": "delan", "model_options": {"mass_invariant": [0]}}), ("lnn", {"variant": "lnn"}),
            ("mlp", {"variant": "mlp"})],
    "perturbed_arm": [("description (inertia as shipped, friction fitted)",
                       {"variant": "film_lnn", "model_options": DESCRIPTION, "eps": 0.0}),
                      ("grey box", {"variant": "film_lnn", "model_options": GREY_BOX, "eps": 0.0}),
                      ("grey box + residual", {"variant": "film_lnn", "model_options": RESIDUAL, "eps": 0.0}),
                      ("film_lnn", {"variant": "film_lnn", "model_options": {"mass_invariant": [0]}})],
}
INTEGRATORS = [("rk4", 0.005), ("rk4", 0.01), ("leapfrog", 0.005), ("leapfrog", 0.01),
               ("semi_implicit_euler", 0.005), ("semi_implicit_euler", 0.001)]


def variants_for(system, cfg: dict | None = None) -> list[tuple[str, dict]]:
    """(row name, LNNModule overrides) of every variant that applies to the scene."""
    if cfg and cfg.get("variants"):
        return ARM_VARIANTS[cfg["variants"]]
    rows = [("film_lnn", {"variant": "film_lnn"}), ("delan", {"variant": "delan"})] if system.quadratic_kinetic else []
    rows += [("lnn", {"variant": "lnn"}), ("mlp", {"variant": "mlp"}),
             ("hnn (canonical p)", {"variant": "hnn", "hnn_coordinates": "canonical"})]
    if not system.quadratic_kinetic:  # the LNN paper's point: an HNN fed (q, qd) fails here
        rows.append(("hnn (q, qd)", {"variant": "hnn", "hnn_coordinates": "velocity"}))
    return rows


# ---------------------------------------------------------------------------- training
def train(name: str, overrides: dict, scene: str, cfg: dict, args) -> tuple:
    import lightning as L
    from lightning.pytorch.loggers import TensorBoardLogger

    from lnn_torch import LNNModule, TrajectoryDataModule
    from lnn_torch.training import make_trainer

    class Curve(L.Callback):
        """Validation error on a fixed sample of validation points against training time (the
        evaluation time itself is excluded)."""

        def __init__(self, sample, every_s):
            self.sample, self.every_s, self.points = sample, every_s, []
            self.train_s, self.mark = 0.0, None

        def on_train_start(self, trainer, module):
            self.mark = time.perf_counter()
            self._record(module)

        def on_train_batch_end(self, trainer, module, *a):
            now = time.perf_counter()
            self.train_s += now - self.mark
            self.mark = now
            if not self.points or self.train_s - self.points[-1][0] >= self.every_s:
                self._record(module)
                self.mark = time.perf_counter()

        def on_train_end(self, trainer, module):
            self.train_s += time.perf_counter() - self.mark
            self._record(module)

        def _record(self, module):
            q, qd, qdd, params, tau = self.sample
            with torch.no_grad():
                pred = module.model.acceleration(q, qd, params, tau, check=False)
            self.points.append((self.train_s, float((pred - qdd).norm() / qdd.norm())))

    torch.manual_seed(args.seed)
    scene, scene_config = cfg.get("scene", scene), cfg.get("scene_config", {})
    dm = TrajectoryDataModule(path=str(ROOT / cfg["path"]),
                              spec=dict(scene=scene, scene_config=scene_config, **cfg["spec"]),
                              chunk_len=cfg.get("chunk_len", args.chunk_len),
                              chunks_per_batch=cfg.get("chunks_per_batch", args.chunks_per_batch), steps_per_epoch=500,
                              seed=args.seed)
    dm.prepare_data()
    val = dm.trajectories("val", 64)
    idx = slice(0, None, 50)
    flat = lambda x: x[:, idx].reshape(-1, x.shape[-1]).float()  # noqa: E731
    T = val.q[:, idx].shape[1]
    # every sampled point with its trajectory's parameters (and recorded inputs, for an actuated scene)
    params = val.params[:, None].expand(-1, T, -1).reshape(-1, val.params.shape[-1]).float()
    sample = [flat(val.q), flat(val.qd), flat(val.qdd), params, None if val.tau is None else flat(val.tau)]
    # the inverse-dynamics loss for the variants that have inverse dynamics (structured Lagrangians)
    inverse = overrides.get("variant") in ("film_lnn", "delan")
    extra = {"torque_weight": cfg["torque_weight"]} if "torque_weight" in cfg and inverse else {}
    if args.lr is not None:
        extra["lr"] = args.lr
    model = LNNModule(scene=scene, scene_config=scene_config, val_rollouts=0, energy_weight=args.energy_weight,
                      hidden_dims=[128, 128], **extra, **overrides)
    curve = Curve(sample, every_s=max(5.0, args.minutes * 60 / 40))
    # as `lnn-torch fit` trains (gradient clipping at 1.0, inference mode off), on a wall-clock budget, its own
    # TensorBoard folder, no checkpoints or validation
    trainer = make_trainer(max_time={"seconds": int(args.minutes * 60)}, max_epochs=-1, limit_val_batches=0,
                           num_sanity_val_steps=0, enable_checkpointing=False, enable_progress_bar=False,
                           enable_model_summary=False,
                           logger=TensorBoardLogger(str(ROOT / "lightning_logs"), name=f"benchmark_{scene}",
                                                    default_hp_metric=False),
                           callbacks=[curve], accelerator="cpu", devices=1)
    start = time.perf_counter()
    trainer.fit(model, dm)
    if args.save_checkpoints:
        stem = name.split(" (")[0].replace(" ", "_").replace("+", "plus")
        path = Path(args.output_dir) / "checkpoints" / f"{cfg.get('name', scene)}_{stem}.ckpt"
        path.parent.mkdir(parents=True, exist_ok=True)
        trainer.save_checkpoint(path)
    model.eval()
    return model, dm, {"train_seconds": time.perf_counter() - start, "steps": trainer.global_step,
                       "skipped_steps": int(model.skipped_steps), "curve": curve.points}, trainer.log_dir


# ---------------------------------------------------------------------------- evaluation
def evaluate_dynamics(name: str, model, system, test, cfg: dict, first_order: bool) -> list[dict]:
    """Rows (one per integrator x dt) of speed and accuracy for one dynamics model: accuracy from
    ``lnn_torch.evaluation.evaluate_model`` (the same pipeline as ``lnn-torch evaluate`` and
    validation), speed timed here on one thread."""
    from lnn_torch.evaluation import evaluate_model
    from lnn_torch.networks import model_rollout

    torch.set_num_threads(1)
    base = evaluate_model(model, system, test, sections=("accelerations", "torques"), accel_stride=10)
    acc = base["acc_rel_err"]
    torque = base.get("torque_nrmse", {}).get("mean")
    torque_nmse = base.get("torque_nmse", {}).get("mean")
    # throughput: float32 batches of 8192 states (the model's own dtype), one thread
    n = 8192
    states = [x[:, ::10].reshape(-1, x.shape[-1]) for x in (test.q, test.qd)]
    rep = lambda x: x[torch.arange(n) % x.shape[0]].float()  # noqa: E731
    T = test.q[:, ::10].shape[1]
    params = test.params[:, None].expand(-1, T, -1).reshape(-1, test.params.shape[-1])
    qq, qqd, pp = rep(states[0]), rep(states[1]), rep(params)
    uu = None if test.tau is None else rep(test.tau[:, ::10].reshape(-1, test.tau.shape[-1]))  # recorded inputs

    def ev():
        with torch.no_grad():
            model.acceleration(qq, qqd, pp, uu, check=False)

    throughput = n / median_seconds(ev, repeats=5)
    rows = []
    B = len(test)
    for method, dt in cfg.get("integrators", INTEGRATORS):
        row = {"model": name, "integrator": method, "dt": dt, "acc_rel_err": acc["total"],
               "acc_non_finite": acc["non_finite_fraction"], "states_per_s": throughput, "torque_nrmse": torque,
               "torque_nmse": torque_nmse}
        if first_order and method not in ("rk4", "rk8"):
            row["note"] = "n/a: a Hamiltonian network integrates its own first-order flow (RK methods only)"
            rows.append(row)
            continue
        # rollout cost: batch 64 (test states repeated), 200 steps, scaled to 1000 steps
        idx = torch.arange(64) % B
        held = None if test.tau is None else test.tau[idx, :1].expand(-1, 200, -1)
        def roll(idx=idx, dt=dt, method=method, held=held):
            return model_rollout(model, test.q[idx, 0], test.qd[idx, 0], test.params[idx], dt, 200, method, held)

        cost = median_seconds(roll, repeats=3, warmup=1) * 5
        r = evaluate_model(model, system, test, sections=("rollouts", "energy"), integrator=method, dt=dt,
                           horizon=cfg["horizon"], thresholds=(cfg["threshold"],))
        div = r[f"divergence_time@{cfg['threshold']:g}"]["model"]
        drift = r["power_balance_error" if system.has_forces else "energy_drift"]
        row.update({"rollout_s_per_1000_steps_b64": cost, "non_finite_fraction": r["rollout_non_finite_fraction"],
                    "energy_drift_mean": drift["mean"], "energy_drift_max": drift["max"],
                    "divergence_time_median": div["median"], "divergence_time_q25": div["q25"]})
        rows.append(row)
    torch.set_num_threads(THREADS)
    return rows


def test_data(dm, max_trajectories: int = 64):
    from lnn_torch.data import read_dataset

    return read_dataset(dm.path).trajectories("test", max_trajectories)


# ---------------------------------------------------------------------------- report
def fmt(x, spec):
    return "-" if x is None or (isinstance(x, float) and np.isnan(x)) else format(x, spec)


def acc_cell(r: dict) -> str:
    cell = f"{r['acc_rel_err']:.4f}"
    if r.get("acc_non_finite"):
        cell += f" ({100 * r['acc_non_finite']:.1f} % undefined)"
    return cell


def energy_label(result: dict) -> str:
    from lnn_torch.systems import get_system

    forces = result["has_forces"] if "has_forces" in result else get_system(result["scene"]).has_forces
    return "power-balance error" if forces else "true-energy drift"


def drift_cell(r: dict) -> str:
    cell = fmt(r["energy_drift_mean"], ".2e")
    if r.get("non_finite_fraction"):
        cell += f" ({100 * r['non_finite_fraction']:.0f} % of rollouts non-finite)"
    return cell


def markdown(result: dict) -> str:
    from lnn_torch.evaluation import stability_markdown, table_header, table_row

    scene = result["scene"]
    lines = [f"### {scene}", "",
             f"{result['machine']}; each variant trained {result['minutes']:g} min on {result['train_threads']} "
             "threads "
             f"(same data, seed, budget); speed on 1 thread; {result['num_test']} test trajectories, rollouts over "
             f"{result['horizon']:g} s. Command: `{result['command']}`"
             + "".join(f"; then `{c}`" for c in result.get("added", [])), "",
             *table_header(["model", "integrator", "dt (s)", "accel. throughput (states/s)",
                            "rollout cost (s / 1000 steps, batch 64)", "x closed form", "test acc. rel. L2",
                            "time to 0.1 error, median (s)", f"{energy_label(result)}, mean"])]
    ceiling = {(r["integrator"], r["dt"]): r for r in result["rows"] if r["model"] == "closed form"}
    for r in result["rows"]:
        if "note" in r:
            lines.append(table_row([r["model"], r["integrator"], f"{r['dt']:g}", f"{r['states_per_s']:.3g}", r["note"],
                                    "-", acc_cell(r), "-", "-"]))
            continue
        base = ceiling.get((r["integrator"], r["dt"]), {}).get("rollout_s_per_1000_steps_b64")
        ratio = r["rollout_s_per_1000_steps_b64"] / base if base else None
        lines.append(table_row([r["model"], r["integrator"], f"{r['dt']:g}", f"{r['states_per_s']:.3g}",
                                f"{r['rollout_s_per_1000_steps_b64']:.3g}", fmt(ratio, ".0f"), acc_cell(r),
                                fmt(r.get("divergence_time_median"), ".2f"), drift_cell(r)]))
    lines += ["", "Training (same budget): steps done, skipped steps, final validation error:", "",
              *table_header(["model", "steps", "skipped", "val. acc. rel. L2 at the end"])]
    for name, t in result["training"].items():
        lines.append(table_row([name, t["steps"], t["skipped_steps"], f"{t['curve'][-1][1]:.4f}"]))
    if result.get("stability"):
        lines += ["", f"Stability on hard cases (trained models, RK4, dt = 0.005 s, "
                      f"{result['stability_seconds']:g} s, 8 trajectories per case):", "",
                  stability_markdown(result["stability"])]
    return "\n".join(lines) + "\n"


def plots(result: dict, out: Path) -> list[Path]:
    from lnn_torch.evaluation import plots as figures

    plt = figures.plt
    scene = result["scene"]
    fig, ax = plt.subplots(figsize=(6.5, 3.6))
    for name, t in result["training"].items():
        xs, ys = zip(*t["curve"], strict=True)
        ax.loglog(np.maximum(xs, 1.0), ys, label=name)
    ax.set_xlabel("training time (s)")
    ax.set_ylabel("validation acc. rel. L2")
    ax.set_title(f"{scene}: time to accuracy")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / f"{scene}_curves.png", dpi=110)
    plt.close(fig)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for i, model in enumerate(dict.fromkeys(r["model"] for r in result["rows"])):
        rows = [r for r in result["rows"] if r["model"] == model and "note" not in r]
        if not rows:
            continue
        axes[0].scatter([1 / rows[0]["states_per_s"]], [max(rows[0]["acc_rel_err"], 1e-16)], color=f"C{i}", label=model)
        xs = [r["rollout_s_per_1000_steps_b64"] for r in rows]
        ys = [max(r["energy_drift_mean"], 1e-16) for r in rows]
        axes[1].scatter(xs, ys, color=f"C{i}", label=model)
        for r, x, y in zip(rows, xs, ys, strict=True):
            axes[1].annotate(f"{r['integrator'][:4]} {r['dt']:g}", (x, y), fontsize=6)
    axes[0].set(xscale="log", yscale="log", xlabel="seconds per state (accel., batch 8192, 1 thread)",
                ylabel="test acc. rel. L2", title="acceleration: cost vs error")
    axes[1].set(xscale="log", yscale="log", xlabel="rollout cost (s / 1000 steps, batch 64)",
                ylabel="true-energy drift, mean", title="rollouts: cost vs energy drift")
    axes[1].legend(fontsize=7)
    fig.suptitle(scene)
    fig.tight_layout()
    fig.savefig(out / f"{scene}_pareto.png", dpi=110)
    plt.close(fig)
    return [out / f"{scene}_curves.png", out / f"{scene}_pareto.png"]


def summary(result: dict, integrator: str = "rk4", dt: float = 0.005) -> str:
    """One row per model: its row at ``integrator``/``dt``, with both costs relative to the closed form."""
    from lnn_torch.evaluation import table_header, table_row

    rows = [r for r in result["rows"] if r["integrator"] == integrator and r["dt"] == dt]
    ceiling = next(r for r in rows if r["model"] == "closed form")
    torques = any(r.get("torque_nrmse") is not None for r in rows)
    lines = [f"**{result['scene']}** ({result['minutes']:g} min of training per model on {result['train_threads']} "
             f"thread(s); {result['num_test']} test trajectories; {integrator}, dt = {dt:g} s, {result['horizon']:g} s "
             f"rollouts; `{result['command']}`)", "",
             *table_header(["model", "training steps", "test acc. rel. L2", "time to 0.1 error, median (s)",
                            f"{energy_label(result)}, mean", *(["torque nRMSE"] if torques else []),
                            "accel. cost x closed form", "rollout cost x closed form"])]
    for r in rows:
        steps = result["training"].get(r["model"], {}).get("steps")
        lines.append(table_row([r["model"], fmt(steps, ","), acc_cell(r), fmt(r.get("divergence_time_median"), ".2f"),
                                drift_cell(r), *([fmt(r.get("torque_nrmse"), ".4f")] if torques else []),
                                f"{ceiling['states_per_s'] / r['states_per_s']:.0f}",
                                f"{r['rollout_s_per_1000_steps_b64'] / ceiling['rollout_s_per_1000_steps_b64']:.1f}"]))
    return "\n".join(lines) + "\n"


def report(out: Path) -> None:
    parts, short = ["# Benchmark: speed against error", ""], ["# Benchmark summary (RK4, dt = 0.005 s)", ""]
    for path in sorted(out.glob("*.json")):
        result = json.loads(path.read_text())
        parts.append(markdown(result))
        parts.append(f"![{result['scene']} curves]({result['scene']}_curves.png) "
                     f"![{result['scene']} pareto]({result['scene']}_pareto.png)\n")
        short.append(summary(result))
        if result.get("stability"):
            from lnn_torch.evaluation import stability_pivot

            short += [f"Stability on hard cases (max true-energy drift / (V_max - V_min), RK4, dt = 0.005 s, "
                      f"{result['stability_seconds']:g} s, 8 trajectories per case):", "",
                      stability_pivot(result["stability"]), ""]
    (out / "README.md").write_text("\n".join(parts))
    (out / "summary.md").write_text("\n".join(short))
    wrote(out / "README.md", out / "summary.md")


# ---------------------------------------------------------------------------- main
THREADS = 2


def main() -> None:
    global THREADS
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--scene", choices=sorted(SCENES), default="double_pendulum", help="the scene to benchmark")
    ap.add_argument("--minutes", type=float, default=None, help="training budget per variant (default: per scene)")
    ap.add_argument("--variants", nargs="*", default=None, help="row names to run (default: all applicable)")
    ap.add_argument("--energy-weight", type=float, default=None, help="default: LNNModule's default")
    ap.add_argument("--seed", type=int, default=0, help="seed of the initialisation and the chunk sampling")
    ap.add_argument("--lr", type=float, default=None, help="peak learning rate of every variant (default: LNNModule's)")
    ap.add_argument("--chunk-len", type=int, default=8, help="points per training chunk (every variant)")
    ap.add_argument("--chunks-per-batch", type=int, default=64, help="chunks per training batch (every variant)")
    ap.add_argument("--threads", type=int, default=2, help="training threads (timings use 1)")
    ap.add_argument("--merge-from", metavar="DIR",
                    help="only merge the variants of another run of --scene (in DIR) into the folder's result")
    ap.add_argument("--add", action="store_true",
                    help="add the --variants to the folder's existing result of the scene (theirs replaced)")
    ap.add_argument("--save-checkpoints", action="store_true",
                    help="keep each trained model under <output-dir>/checkpoints (for the arm's identification study)")
    ap.add_argument("--stability-seconds", type=float, default=2.0, help="rollout length of the hard cases, s")
    add_output_dir(ap, str(OUT), "the folder of the results (and of the merged report)")
    ap.add_argument("--report", action="store_true",
                    help="only merge the folder's existing results into its README.md and summary.md")
    args = ap.parse_args()
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    if args.report:
        report(out)
        return
    if args.merge_from:  # another run's variants of the same scene (run beside this one) into this folder's result
        mine, theirs = (json.loads((Path(d) / f"{args.scene}.json").read_text()) for d in (out, args.merge_from))
        names = set(theirs["training"])
        mine["rows"] = [r for r in mine["rows"] if r["model"] not in names] + [
            r for r in theirs["rows"] if r["model"] in names]
        mine["training"].update(theirs["training"])
        mine.setdefault("stability", {}).update({k: v for k, v in theirs.get("stability", {}).items() if k in names})
        mine.setdefault("added", []).append(theirs["command"] + " --variants " + " ".join(f'"{n}"' for n in names))
        (out / f"{args.scene}.json").write_text(json.dumps(mine, indent=1))
        (out / f"{args.scene}.md").write_text(markdown(mine))
        wrote(out / f"{args.scene}.json", out / f"{args.scene}.md")
        return
    from lnn_torch import LNNModule
    from lnn_torch.evaluation import hard_cases, run_hard_cases
    from lnn_torch.networks import model_rollout
    from lnn_torch.perf import configure_cpu
    from lnn_torch.systems import ClosedForm, get_system

    THREADS = args.threads
    configure_cpu(args.threads)
    cfg = SCENES[args.scene]
    args.minutes = args.minutes if args.minutes is not None else cfg["minutes"]
    if args.energy_weight is None:
        import inspect

        args.energy_weight = inspect.signature(LNNModule.__init__).parameters["energy_weight"].default
    cfg["name"] = args.scene
    system = get_system(cfg.get("scene", args.scene), **cfg.get("scene_config", {}))
    rows_spec = [v for v in variants_for(system, cfg) if args.variants is None or v[0] in args.variants]
    result = {"scene": args.scene, "has_forces": system.has_forces, "minutes": args.minutes,
              "train_threads": args.threads,
              "machine": machine_header(),
              "horizon": cfg["horizon"], "energy_weight": args.energy_weight,
              "command": "python scripts/benchmark.py " + " ".join(f"--{k.replace('_', '-')} {v}" for k, v in
                                                                   (("scene", args.scene), ("minutes", args.minutes),
                                                                    ("threads", args.threads))
                                                                   + ((("chunk_len", args.chunk_len),
                                                                       ("chunks_per_batch", args.chunks_per_batch))
                                                                      if "chunk_len" not in cfg else ())),
              "chunking": {"chunk_len": cfg.get("chunk_len", args.chunk_len),
                           "chunks_per_batch": cfg.get("chunks_per_batch", args.chunks_per_batch)},
              "rows": [], "training": {}, "stability": {}, "stability_seconds": args.stability_seconds}
    previous = out / f"{args.scene}.json"
    if args.add and previous.exists():  # more variants into an existing result: theirs replaced, the rest kept
        old = json.loads(previous.read_text())
        names = {n for n, _ in rows_spec}
        old["rows"] = [r for r in old["rows"] if r["model"] not in names]
        old["training"] = {k: v for k, v in old["training"].items() if k not in names}
        old["stability"] = {k: v for k, v in old.get("stability", {}).items() if k not in names}
        old.setdefault("added", []).append(result["command"] + " --add --variants " + " ".join(f'"{n}"' for n in names))
        result = old
    test = None
    written = [] if (ROOT / cfg["path"]).exists() else [ROOT / cfg["path"]]  # the dataset, generated when missing
    for name, overrides in rows_spec:
        print(f"[{args.scene}] training {name} for {args.minutes:g} min", flush=True)
        module, dm, info, log_dir = train(name, overrides, args.scene, cfg, args)
        result["training"][name] = info
        written.append(log_dir)
        if test is None:
            test = test_data(dm)
            result["num_test"] = len(test)
            if not any(r["model"] == "closed form" for r in result["rows"]):
                result["rows"] += evaluate_dynamics("closed form", ClosedForm(system), system, test, cfg, False)
        model = module.model
        result["rows"] += evaluate_dynamics(name, model, system, test, cfg, overrides.get("variant") == "hnn")
        cases = system.hard_parameter_cases()
        if cases:  # scenes with extreme parameter cases of their own get the stability grid
            steps = int(round(args.stability_seconds / 0.005))
            result["stability"][name] = run_hard_cases(functools.partial(model_rollout, model), system,
                                                       hard_cases(system, num=8, num_steps=steps), model=model)
        (out / f"{args.scene}.json").write_text(json.dumps(result, indent=1))
        print(markdown(result), flush=True)
    if result["stability"]:
        steps = int(round(args.stability_seconds / 0.005))
        result["stability"] = {"closed form": run_hard_cases(ClosedForm(system).rollout, system,
                                                             hard_cases(system, num=8, num_steps=steps)),
                               **result["stability"]}
    (out / f"{args.scene}.json").write_text(json.dumps(result, indent=1))
    (out / f"{args.scene}.md").write_text(markdown(result))
    pngs = plots(result, out)
    print(markdown(result))
    wrote(out / f"{args.scene}.json", out / f"{args.scene}.md", pngs, written)


if __name__ == "__main__":
    main()
