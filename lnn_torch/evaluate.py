"""``lnn-torch evaluate``: a checkpoint against a dataset split, with the closed-form scene as ground truth.

Reports (JSON, Markdown and PNG plots in ``--output-dir``):

* relative L2 acceleration error: total, per coordinate, per-trajectory median and 90th percentile;
* rollouts (chosen integrator and dt) from the true initial states: time until the angle error first
  exceeds 0.1 and 0.5 rad (median and quartiles), beside the same figure for the exact system
  started 1e-6 rad off (the predictability limit);
* true-energy drift |E(t) - E(0)| / (V_max - V_min) of the model's rollouts (closed-form energy);
* mass-matrix error against the scene's M (relative Frobenius after the best scale per system) and
  the condition number of the learned M (structured variants);
* the reference design's four out-of-distribution double-pendulum cases;
* a stability table on hard cases (``lnn_torch.stability``): non-finite fraction, max true-energy
  drift and the condition number of the learned mass matrix, including a long horizon of 1e5 RK4
  steps.

The checkpoint may be ``pretrained:<name>`` for a shipped model. A missing data file is generated
from the dataset specification the checkpoint records.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from .evaluation import (condition_numbers, counting_failures, divergence_time, energy_drift, learned_mass_matrix,
                         relative_l2)
from .integrators import rollout

OOD_CASES = [  # (m1, m2, l1, l2), [theta1, theta2, thetad1, thetad2]
    ((2.5, 1.5, 1.2, 1.3), (0.4, -0.4, 0.1, -0.1)),
    ((1.0, 0.8, 2.5, 2.3), (-0.8, 0.8, 0.3, -0.3)),
    ((3.0, 2.0, 2.8, 2.5), (-0.6, 0.6, -0.9, 0.9)),
    ((0.3, 0.2, 0.5, 0.6), (1.5, 1.0, -1.2, 0.35)),
]
THRESHOLDS = (0.1, 0.5)


def _quartiles(x: torch.Tensor) -> dict:
    q = torch.quantile(x.double(), torch.tensor([0.25, 0.5, 0.75], dtype=torch.float64))
    return {"q25": float(q[0]), "median": float(q[1]), "q75": float(q[2])}


def model_accel_fn(module):
    """Float64 in, float64 out; the model runs in its own dtype. Undefined accelerations are NaN."""
    model = module.model

    def fn(q, qd, p):
        with torch.set_grad_enabled(model.needs_autograd), counting_failures(model):
            return model.acceleration(q, qd, p, check=False).detach()

    return fn


def model_rollout(module, q0, qd0, params, dt, num_steps, method):
    """The model's rollout; trajectories through undefined accelerations become NaN (counted)."""
    with torch.set_grad_enabled(module.model.needs_autograd), counting_failures(module.model):
        q, qd = module.model.rollout(q0, qd0, params, dt, num_steps, method)
    return q.detach(), qd.detach()


def mass_matrix_metrics(module, system, q: torch.Tensor, params: torch.Tensor) -> dict | None:
    """Relative Frobenius error of the learned M after the best scale per system, and cond(M).

    q ``(B, T, dof)``, params ``(B, P)``. The learned M lives in normalised velocities
    ``qd_n = qd * tau / scale``, i.e. it equals ``D M_n D`` (``D = diag(tau / scale)``) in SI units.
    """
    model = module.model
    B, T, dof = q.shape
    p = params[:, None, :].expand(-1, T, -1).reshape(-1, params.shape[-1])
    qf = q.reshape(-1, dof)
    M_n = learned_mass_matrix(model, qf, p)
    if M_n is None:
        return None
    norm = model.normalizer
    D = (norm.time_scale.double() / norm.coord_scale.double())
    M_model = (D[:, None] * M_n * D[None, :]).reshape(B, T, dof, dof)
    M_true = system.mass_matrix(qf, p).reshape(B, T, dof, dof)
    c = (M_true * M_model).sum((1, 2, 3)) / (M_model * M_model).sum((1, 2, 3))
    err = ((M_true - c[:, None, None, None] * M_model).pow(2).sum((1, 2, 3)) / M_true.pow(2).sum((1, 2, 3))).sqrt()
    cond = condition_numbers(M_n)
    return {"rel_frobenius_median": float(err.median()), "rel_frobenius_max": float(err.max()),
            "cond_median": float(cond.median()), "cond_max": float(cond.max())}


def stability(module, stability_seconds: float = 5.0, long_horizon_steps: int = 100_000) -> list[dict]:
    """The hard cases of ``lnn_torch.stability`` for this model, plus a long horizon (2 trajectories)."""
    from .stability import HardCase, hard_cases, run_hard_cases

    system = module.system
    cases = hard_cases(system, num=8, num_steps=int(round(stability_seconds / 0.005)))
    if long_horizon_steps:
        nominal = cases[0]
        cases.append(HardCase(f"long horizon: {long_horizon_steps:.0e} RK4 steps", nominal.q0[:2], nominal.qd0[:2],
                              nominal.params[:2], dt=0.005, num_steps=long_horizon_steps))
    return run_hard_cases(lambda *a: model_rollout(module, *a), system, cases, model=module.model)


def evaluate(module, data_path: str | Path, split: str = "test", method: str = "rk4", dt: float | None = None,
             horizon: float = 15.0, max_trajectories: int | None = None, perturbation: float = 1e-6,
             stability_seconds: float = 5.0, long_horizon_steps: int = 100_000) -> dict:
    """Compute every metric of the report; returns a JSON-ready dict (plus ``_arrays`` for plots)."""
    from .data import read_dataset

    f = read_dataset(data_path)
    system = module.system
    if f.attrs["scene"] != system.name:
        raise ValueError(f"{data_path} holds scene '{f.attrs['scene']}' but the checkpoint models '{system.name}'")
    idx = np.sort(f.splits[split])
    if len(idx) == 0:
        raise ValueError(f"{data_path} has an empty '{split}' split")
    if max_trajectories:
        idx = idx[:max_trajectories]
    with f.open() as h:
        q, qd, qdd = (torch.from_numpy(h[k][idx]) for k in ("q", "qd", "qdd"))
        params = torch.from_numpy(h["params"][idx])
        t = h["t"][()]
    data_dt = float(t[1] - t[0])
    dt = dt or data_dt
    stride = int(round(dt / data_dt))
    if abs(stride * data_dt - dt) > 1e-9 or stride < 1:
        raise ValueError(f"dt={dt} must be a multiple of the data's sampling interval {data_dt}")
    accel = model_accel_fn(module)
    out: dict = {"checkpoint_variant": module.hparams.variant, "data": str(data_path), "split": split,
                 "num_trajectories": int(len(idx)), "integrator": method, "dt": dt, "horizon_s": horizon}

    # ---- accelerations at every 10th stored point
    sub = slice(0, None, 10)
    B, T, dof = q[:, sub].shape
    start = time.perf_counter()
    pred = torch.cat([accel(q[i:i + 1, sub].reshape(-1, dof), qd[i:i + 1, sub].reshape(-1, dof),
                            params[i:i + 1, None, :].expand(1, T, -1).reshape(-1, params.shape[-1]))
                      for i in range(B)]).reshape(B, T, dof)
    out["acceleration_eval_seconds"] = time.perf_counter() - start
    true = qdd[:, sub]
    per_traj = relative_l2(pred.reshape(B, -1), true.reshape(B, -1), dim=1)
    out["acc_rel_err"] = {"total": float(relative_l2(pred, true)),
                          **{n: float(relative_l2(pred[..., i], true[..., i])) for i, n in enumerate(system.coord_names)},
                          "per_trajectory_median": float(per_traj.median()),
                          "per_trajectory_p90": float(torch.quantile(per_traj, 0.9))}

    # ---- rollouts: model, and the exact system started `perturbation` rad off
    steps = min(int(round(horizon / dt)), (q.shape[1] - 1) // stride)
    q_true, qd_true = q[:, : steps * stride + 1 : stride], qd[:, : steps * stride + 1 : stride]
    start = time.perf_counter()
    q_m, qd_m = model_rollout(module, q_true[:, 0], qd_true[:, 0], params, dt, steps, method)
    out["rollout_seconds"] = time.perf_counter() - start
    q_x, _ = rollout(system.acceleration, q_true[:, 0] + perturbation, qd_true[:, 0], params, dt, steps, method)
    for thr in THRESHOLDS:
        out[f"divergence_time@{thr:g}"] = {
            "model": _quartiles(divergence_time(q_m, q_true, dt, thr, system.angle_mask)),
            "exact_perturbed": _quartiles(divergence_time(q_x, q_true, dt, thr, system.angle_mask)),
        }
    drift = energy_drift(system, q_m, qd_m, params)
    finite = torch.isfinite(drift).all(1)
    out["energy_drift"] = {"mean": float(drift[finite].mean()), "max": float(drift[finite].max()),
                           "non_finite_fraction": float(1 - finite.double().mean())}
    mm = mass_matrix_metrics(module, system, q[:, sub], params)
    if mm is not None:
        out["mass_matrix"] = mm

    # ---- the reference design's out-of-distribution cases (double pendulum only)
    if system.name == "double_pendulum":
        p_ood = torch.tensor([c[0] for c in OOD_CASES], dtype=torch.float64)
        s_ood = torch.tensor([c[1] for c in OOD_CASES], dtype=torch.float64)
        q0, qd0 = s_ood[:, :2], s_ood[:, 2:]
        n = int(round(horizon / dt))
        qt, qdt = rollout(system.acceleration, q0, qd0, p_ood, dt / 4, 4 * n, "rk8")
        qt, qdt = qt[:, ::4], qdt[:, ::4]
        qm, qdm = model_rollout(module, q0, qd0, p_ood, dt, n, method)
        a_true = system.acceleration(qt, qdt, p_ood[:, None].expand(-1, n + 1, -1))
        a_pred = accel(qt.reshape(-1, 2), qdt.reshape(-1, 2), p_ood[:, None].expand(-1, n + 1, -1).reshape(-1, 4))
        a_pred = a_pred.reshape(a_true.shape)
        d = energy_drift(system, qm, qdm, p_ood)
        out["ood"] = [{"params": list(c[0]), "state0": list(c[1]),
                       "acc_rel_err": float(relative_l2(a_pred[i], a_true[i])),
                       "divergence_time@0.1": float(divergence_time(qm[i:i + 1], qt[i:i + 1], dt, 0.1, system.angle_mask)[0]),
                       "energy_drift_mean": float(d[i].mean()), "energy_drift_max": float(d[i].max())}
                      for i, c in enumerate(OOD_CASES)]
        out["_ood_arrays"] = {"q_true": qt, "q_model": qm, "params": p_ood}
    if stability_seconds > 0:
        out["stability"] = stability(module, stability_seconds, long_horizon_steps)
    out["_arrays"] = {"q_true": q_true, "q_model": q_m, "qd_model": qd_m, "q_exact": q_x, "params": params,
                      "drift": drift}
    return out


def write_report(result: dict, output_dir: Path, system) -> list[Path]:
    """metrics.json, report.md and PNG plots."""
    from .plots import evaluation_plots

    output_dir.mkdir(parents=True, exist_ok=True)
    clean = {k: v for k, v in result.items() if not k.startswith("_")}
    (output_dir / "metrics.json").write_text(json.dumps(clean, indent=2))
    pngs = evaluation_plots(result, output_dir, system)
    lines = [f"# Evaluation: {clean['checkpoint_variant']} on {clean['data']} ({clean['split']} split, "
             f"{clean['num_trajectories']} trajectories)", "",
             f"Rollouts: {clean['integrator']}, dt = {clean['dt']} s, horizon {clean['horizon_s']} s.", "",
             "| metric | value |", "|---|---|"]
    for k, v in clean["acc_rel_err"].items():
        lines.append(f"| acceleration rel. L2 error ({k}) | {v:.4f} |")
    for thr in THRESHOLDS:
        d = clean[f"divergence_time@{thr:g}"]
        lines.append(f"| time to {thr:g} rad error, model: median [q25, q75] (s) | {d['model']['median']:.2f} "
                     f"[{d['model']['q25']:.2f}, {d['model']['q75']:.2f}] |")
        lines.append(f"| same, exact system started 1e-6 rad off (s) | {d['exact_perturbed']['median']:.2f} "
                     f"[{d['exact_perturbed']['q25']:.2f}, {d['exact_perturbed']['q75']:.2f}] |")
    e = clean["energy_drift"]
    lines.append(f"| true-energy drift / (V_max - V_min): mean, max | {e['mean']:.2e}, {e['max']:.2e} |")
    lines.append(f"| non-finite rollouts | {e['non_finite_fraction']:.3f} |")
    if "mass_matrix" in clean:
        m = clean["mass_matrix"]
        lines.append(f"| mass-matrix rel. Frobenius error (best scale per system): median, max | "
                     f"{m['rel_frobenius_median']:.4f}, {m['rel_frobenius_max']:.4f} |")
        lines.append(f"| cond(M) of the learned mass matrix: median, max | {m['cond_median']:.1f}, {m['cond_max']:.1f} |")
    if "ood" in clean:
        lines += ["", "Out-of-distribution cases (the reference design's):", "",
                  "| (m1, m2, l1, l2) | [θ1, θ2, θ̇1, θ̇2]₀ | acc. rel. L2 | time to 0.1 rad (s) | energy drift mean / max |",
                  "|---|---|---|---|---|"]
        for c in clean["ood"]:
            lines.append(f"| {tuple(c['params'])} | {c['state0']} | {c['acc_rel_err']:.4f} | "
                         f"{c['divergence_time@0.1']:.2f} | {c['energy_drift_mean']:.2e} / {c['energy_drift_max']:.2e} |")
    if "stability" in clean:
        from .stability import stability_markdown

        lines += ["", "Stability on hard cases (RK4, dt = 0.005 s; `lnn_torch.stability`):", "",
                  stability_markdown({clean["checkpoint_variant"]: clean["stability"]})]
    lines += ["", "Plots: " + ", ".join(p.name for p in pngs)]
    (output_dir / "report.md").write_text("\n".join(lines) + "\n")
    return [output_dir / "metrics.json", output_dir / "report.md", *pngs]


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="lnn-torch evaluate", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", help="a .ckpt written by lnn-torch fit, or pretrained:<name> for a shipped model")
    ap.add_argument("--data", default=None, help="HDF5 dataset (default: the checkpoint's data path)")
    ap.add_argument("--split", default="test", choices=("train", "val", "test"))
    ap.add_argument("--integrator", default="rk4", help="rk4, rk8, leapfrog or semi_implicit_euler")
    ap.add_argument("--dt", type=float, default=None, help="rollout step, s (default: the data's)")
    ap.add_argument("--horizon", type=float, default=15.0, help="rollout length, s")
    ap.add_argument("--max-trajectories", type=int, default=None)
    ap.add_argument("--stability-seconds", type=float, default=5.0, help="horizon of the hard cases (0: skip them)")
    ap.add_argument("--long-horizon-steps", type=int, default=100_000, help="RK4 steps of the long-horizon case (0: skip)")
    ap.add_argument("--output-dir", "-o", default=None, help="default: <checkpoint folder>/../evaluation")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--compile", action="store_true",
                    help="accelerations through torch.compile (compiled once per batch shape; falls back to eager)")
    args = ap.parse_args(argv)
    from .perf import configure_cpu

    configure_cpu(args.threads)
    module, saved = load_checkpoint(args.checkpoint)
    if args.compile:
        module.model.compile_dynamics()
    data = args.data or saved.get("path")
    if data is None:
        raise ValueError("the checkpoint records no data path: pass --data")
    if not Path(data).exists():
        from .data import DatasetSpec, generate_dataset

        spec = DatasetSpec(**(saved.get("spec") or {}))
        print(f"dataset {data} not found: generating it from the checkpoint's specification "
              f"({spec.num_trajectories} trajectories)")
        generate_dataset(spec, data, progress=True)
    result = evaluate(module, data, args.split, args.integrator, args.dt, args.horizon, args.max_trajectories,
                      stability_seconds=args.stability_seconds, long_horizon_steps=args.long_horizon_steps)
    if args.output_dir:
        out_dir = Path(args.output_dir)
    elif args.checkpoint.startswith("pretrained:"):
        out_dir = Path("evaluation") / args.checkpoint.split(":", 1)[1]
    else:
        out_dir = Path(args.checkpoint).parent.parent / "evaluation"
    files = write_report(result, out_dir, module.system)
    print((out_dir / "report.md").read_text())
    print("wrote " + ", ".join(str(f) for f in files))
    return 0


def load_checkpoint(checkpoint: str):
    """``(LNNModule in eval mode, the datamodule hyper-parameters it records)``."""
    from .module import LNNModule

    if checkpoint.startswith("pretrained:"):
        from .pretrained import info, load_pretrained

        name = checkpoint.split(":", 1)[1]
        return load_pretrained(name), info(name).get("datamodule_hyper_parameters", {})
    ckpt = Path(checkpoint)
    if not ckpt.exists():
        raise FileNotFoundError(f"checkpoint {ckpt} does not exist")
    module = LNNModule.load_from_checkpoint(ckpt, map_location="cpu")
    module.eval()
    saved = torch.load(ckpt, map_location="cpu", weights_only=False).get("datamodule_hyper_parameters", {})
    return module, saved
