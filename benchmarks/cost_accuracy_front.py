"""The cost-accuracy front of the structured model (film_lnn), beside the original JAX FiLM-LNN.

Every point of the sweep (hidden widths and depth, per-neuron or per-layer FiLM, FiLM on the
potential or not) is trained with the same data, seed and step budget (``--steps`` steps of 512
states: 64 chunks of 8 points of data/front.h5, the 200-trajectory set of seed 0; cosine learning rate
3e-3 -> 3e-5 over the budget), then evaluated on the test split with ``lnn_torch.evaluation``
(acceleration error at every 10th point, median time until the angle error of an RK4 rollout at
the data's step first exceeds 0.1 rad, 10 s horizon).

Costs are timed in ONE process, interleaved (round-robin; per round and candidate one untimed
call, then the median of ``--calls`` timed calls), one thread, after warm-up and compilation:

* ``accel``: 512 accelerations (float32, no autograd), test states;
* ``train step``: a training step on 512 states (loss, backward, gradient clipping, AdamW step);
* ``rollout step``: one RK4 step of 64 trajectories (4 acceleration evaluations);

for each point eagerly and compiled (``model.compile_dynamics()``, ``LNNModule(compile=True)``),
and the widest point also in float64. The original (released checkpoint, its own model call and
its own ``train.train_step``; ``benchmarks/jax_original.py``) is timed the same way in the same
rounds, and its accuracy is measured on the same test split through the same evaluation (its
accelerations, our RK4). Its rollout step is its accelerations inside one jitted RK4 step.

    python benchmarks/cost_accuracy_front.py train                 # trains every point (~15 min)
    LNN_JAX_ORIGINAL_SRC=... PYTHONPATH=.venv/lib/python3.11/site-packages:. \\
        ../jax_original/venv/bin/python benchmarks/cost_accuracy_front.py time     # needs the original
    python benchmarks/cost_accuracy_front.py time --no-original    # lnn_torch points only
    ... cost_accuracy_front.py time --untrained   # time freshly initialised networks where a checkpoint is absent
    python benchmarks/cost_accuracy_front.py report                # table and plot

The ``time`` step runs under the original's environment (jax 0.9.1, see ``benchmarks/jax_original.py``)
with lnn_torch's packages on ``PYTHONPATH``. Writes ``results/cost_accuracy/{train,time}.json``,
``README.md`` and ``front.png``; checkpoints go to ``data/front/``.
"""

from __future__ import annotations

import os
import sys

os.environ.setdefault("TORCHINDUCTOR_COMPILE_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

from timing import ROOT, HelpFormatter, in_turn, machine_header, median_ratio, wrote  # noqa: E402

from lnn_torch.perf import median_seconds  # noqa: E402

OUT = ROOT / "results" / "cost_accuracy"
CKPT = ROOT / "data" / "front"
DATA = ROOT / "data" / "front.h5"  # its own 200-trajectory set (the quickstart now trains on 2000)
SPEC = dict(scene="double_pendulum", num_trajectories=200, duration=20.0, dt=0.005, seed=0)

# name -> film_lnn options; "w64" has the shipped model's widths, "w128" the quickstart's and the box model's
POINTS = {
    "w8": dict(hidden_dims=[8, 8]),
    "w16 x1": dict(hidden_dims=[16]),
    "w16": dict(hidden_dims=[16, 16]),
    "w32": dict(hidden_dims=[32, 32]),
    "w32 layer-FiLM": dict(hidden_dims=[32, 32], film_mode="layer"),
    "w64": dict(hidden_dims=[64, 64]),
    "w64 no potential FiLM": dict(hidden_dims=[64, 64], potential_film=False),
    "w64 layer-FiLM": dict(hidden_dims=[64, 64], film_mode="layer"),
    "w64 x3": dict(hidden_dims=[64, 64, 64]),
    "w128": dict(hidden_dims=[128, 128]),
    "w128 layer-FiLM": dict(hidden_dims=[128, 128], film_mode="layer"),
    # one shared network for the Cholesky entries and the potential (film_lnn's shared=True)
    "w16 shared": dict(hidden_dims=[16, 16], model_options={"shared": True}),
    "w32 shared": dict(hidden_dims=[32, 32], model_options={"shared": True}),
    "w64 shared": dict(hidden_dims=[64, 64], model_options={"shared": True}),
    "w96 shared": dict(hidden_dims=[96, 96], model_options={"shared": True}),
    "w128 shared": dict(hidden_dims=[128, 128], model_options={"shared": True}),
}
# the same networks trained longer (16,000 steps): accuracy only, their costs
# are those of the network they share
LONGER = {"w64, 16k steps": ("w64", 16000), "w32, 16k steps": ("w32", 16000),
          "w64 shared, 16k steps": ("w64 shared", 16000), "w64 layer-FiLM, 16k steps": ("w64 layer-FiLM", 16000)}
ORIGINAL = "JAX original (released)"


def slug(name: str) -> str:
    return name.replace(" ", "_")


def test_data():
    from lnn_torch.data import read_dataset

    return read_dataset(DATA).trajectories("test")


def accuracy(model, system, test) -> dict:
    from lnn_torch.evaluation import evaluate_model

    r = evaluate_model(model, system, test, sections=("accelerations", "rollouts"), horizon=10.0,
                       thresholds=(0.1,), accel_stride=10)
    div = r["divergence_time@0.1"]["model"]
    return {"acc_rel_err": r["acc_rel_err"]["total"], "divergence_median_s": div["median"],
            "divergence_q25_s": div["q25"], "horizon_s": r["horizon_s"]}


# ---------------------------------------------------------------------------- training
def train(args) -> None:
    import lightning as L
    import torch

    from lnn_torch import LNNModule, TrajectoryDataModule
    from lnn_torch.training import make_trainer

    OUT.mkdir(parents=True, exist_ok=True)
    CKPT.mkdir(parents=True, exist_ok=True)
    path = OUT / "train.json"
    done = json.loads(path.read_text()) if path.exists() else {}
    torch.set_num_threads(args.threads)
    names = args.points or [*POINTS, *LONGER]
    had_data, written = DATA.exists(), []  # the dataset is generated when missing
    for name in names:
        if name in done and not args.again:
            print(f"{name}: trained already (--again to redo)")
            continue
        base, steps = LONGER.get(name, (name, args.steps))
        L.seed_everything(0, workers=True)
        dm = TrajectoryDataModule(path=str(DATA), spec=SPEC, chunk_len=8, chunks_per_batch=64, steps_per_epoch=500,
                                  seed=0)
        module = LNNModule(variant="film_lnn", val_rollouts=0, lr=3e-3, lr_min=3e-5, **POINTS[base])
        # as `lnn-torch fit` trains (gradient clipping at 1.0), without its logger, checkpoints and validation
        trainer = make_trainer(max_steps=steps, max_epochs=-1, limit_val_batches=0, num_sanity_val_steps=0,
                               enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False,
                               logger=False, callbacks=[], accelerator="cpu", devices=1)
        start = time.perf_counter()
        trainer.fit(module, dm)
        seconds = time.perf_counter() - start
        trainer.save_checkpoint(str(CKPT / f"{slug(name)}.ckpt"))
        written.append(CKPT / f"{slug(name)}.ckpt")
        module.eval()
        row = {"options": POINTS[base], "network": base, "steps": trainer.global_step, "train_seconds": seconds,
               "train_threads": args.threads, "parameters": sum(p.numel() for p in module.model.parameters()),
               **accuracy(module.model, module.system, test_data())}
        done[name] = row
        path.write_text(json.dumps(done, indent=1))
        print(f"{name}: {row['acc_rel_err']:.4f} acc. rel. L2, divergence median {row['divergence_median_s']:.2f} s, "
              f"{seconds:.0f} s training", flush=True)
    wrote([path] if written else [], written, [] if had_data or not DATA.exists() else [DATA])


# ---------------------------------------------------------------------------- timing
class Candidate:
    """One timed configuration: ``calls[what]()`` runs one call of ``what``."""

    def __init__(self, name: str, path: str, dtype: str, calls: dict):
        self.name, self.path, self.dtype, self.calls = name, path, dtype, calls


def torch_candidates(name: str, compiled: bool, dtype, batch: dict, untrained: bool = False):
    import torch

    from lnn_torch import LNNModule, load_model
    from lnn_torch.perf import adamw
    from lnn_torch.training import TrainingPass

    ckpt = CKPT / f"{slug(name)}.ckpt"
    if ckpt.exists():
        module = load_model(ckpt).to(dtype)
    elif untrained:  # the same network, freshly initialised: a call's cost does not depend on the weights' values
        module = LNNModule(variant="film_lnn", val_rollouts=0, compile=compiled, **POINTS[name]).to(dtype)
    else:
        raise SystemExit(f"{ckpt} is missing: run the train step first, or time fresh networks with --untrained")
    model = module.model
    if compiled:
        model.compile_dynamics()
    cast = {k: v.to(dtype) for k, v in batch.items()}
    q, qd, params = cast["q512"], cast["qd512"], cast["p512"]
    q64, qd64, p64 = cast["q64"], cast["qd64"], cast["p64"]
    chunk = {k: cast[k].reshape(64, 8, -1) for k in ("q", "qd", "qdd", "params")}
    opt = adamw(module.parameters(), lr=1e-6)
    pass_fn = TrainingPass(module.training_terms, compiled).function(0, module.device)  # compiled or eager

    def accel():
        with torch.no_grad():
            model.acceleration(q, qd, params, check=False)

    def step():
        loss, _ = module.batch_loss(chunk, pass_fn)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(module.parameters(), 1.0)
        opt.step()
        opt.zero_grad(set_to_none=True)

    def rollout():
        with torch.no_grad():
            model.rollout(q64, qd64, p64, 0.005, 1)

    path = "compiled" if compiled else "eager"
    return Candidate(name, path, str(dtype).replace("torch.", ""), {"accel": accel, "train step": step,
                                                                    "rollout step": rollout})


def original_candidate(batch: dict):
    import jax_original as harness  # this folder's harness around the original

    m = harness.load("float32")
    import jax  # after the harness: it sets XLA's flags before jax starts
    q, qd, params = m.to_device(batch["q512"].numpy(), batch["qd512"].numpy(), batch["p512"].numpy())
    q64, qd64, p64 = m.to_device(batch["q64"].numpy(), batch["qd64"].numpy(), batch["p64"].numpy())
    step = harness.train_step_fn("float32")
    # a contiguous 512-point piece of one training trajectory (its loss has a variance-of-energy term)
    x, y = step.to_device(*step.normalise(*(batch[k].numpy() for k in ("cq", "cqd", "cqdd", "cp"))))

    def rk4(q, qd, p, dt=0.005):
        def f(q, qd):
            return qd, m.accel_traced(q, qd, p)

        k1 = f(q, qd)
        k2 = f(q + 0.5 * dt * k1[0], qd + 0.5 * dt * k1[1])
        k3 = f(q + 0.5 * dt * k2[0], qd + 0.5 * dt * k2[1])
        k4 = f(q + dt * k3[0], qd + dt * k3[1])
        return (q + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0]),
                qd + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1]))

    rk4_jit = jax.jit(rk4)
    calls = {"accel": lambda: m.accel_device(q, qd, params).block_until_ready(),
             "train step": lambda: step.step_normalised(x, y),
             "rollout step": lambda: jax.block_until_ready(rk4_jit(q64, qd64, p64))}
    return Candidate(ORIGINAL, "jit", "float32", calls), m


class OriginalAsModel:
    """The released original behind lnn_torch's model interface (SI, float32), for the evaluation
    pipeline: accelerations from its own model call, rollouts by lnn_torch's integrators."""

    variant = ORIGINAL

    def __init__(self, m):
        self.m = m

    def acceleration(self, q, qd, params, tau=None, check=False):
        import torch

        return torch.from_numpy(self.m.accel(q.numpy(), qd.numpy(), params.numpy()).astype("float64")).to(q.dtype)

    def rollout(self, q0, qd0, params, dt, num_steps, method="rk4", tau=None):
        from lnn_torch.mechanics import rollout

        return rollout(self.acceleration, q0, qd0, params, dt, num_steps, method)


def op_profile(fn) -> dict:
    """What one eager call spends: the number of aten operator calls, and the share of the profiled CPU
    time in the matrix products (the rest is element-wise work and per-operator dispatch)."""
    import torch

    fn()
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
        fn()
    events = [e for e in prof.key_averages() if e.key.startswith("aten::")]
    total = sum(e.self_cpu_time_total for e in events)
    products = sum(e.self_cpu_time_total for e in events if e.key in ("aten::mm", "aten::addmm", "aten::bmm",
                                                                     "aten::baddbmm", "aten::addmv", "aten::mv"))
    # top-level operators only: those not called from within another aten operator
    calls = sum(e.count for e in events if e.key not in ("aten::as_strided", "aten::empty", "aten::empty_strided",
                                                          "aten::resolve_conj", "aten::resolve_neg"))
    return {"aten calls (incl. nested)": calls, "matrix-product share": products / total if total else float("nan")}


def time_all(args) -> None:
    import torch

    torch.set_num_threads(1)
    test = test_data()
    g = torch.Generator().manual_seed(0)
    flat = lambda x: x[:, ::10].reshape(-1, x.shape[-1])  # noqa: E731
    T = test.q[:, ::10].shape[1]
    states = [flat(test.q), flat(test.qd), test.params[:, None].expand(-1, T, -1).reshape(-1, test.params.shape[-1])]
    pick = torch.randperm(states[0].shape[0], generator=g)
    batch = {"q512": states[0][pick[:512]], "qd512": states[1][pick[:512]], "p512": states[2][pick[:512]],
             "q64": states[0][pick[:64]], "qd64": states[1][pick[:64]], "p64": states[2][pick[:64]]}
    # a training batch: 64 chunks of 8 consecutive points; the original's: 512 consecutive points
    starts = torch.randint(0, test.num_points - 8, (64,), generator=g)
    rows = torch.arange(64) % len(test)
    for key, src in (("q", test.q), ("qd", test.qd), ("qdd", test.qdd)):
        batch[key] = torch.stack([src[r, s:s + 8] for r, s in zip(rows, starts, strict=True)]).reshape(512, -1)
    batch["params"] = test.params[rows][:, None].expand(-1, 8, -1).reshape(512, -1)
    for key, src in (("cq", test.q), ("cqd", test.qd), ("cqdd", test.qdd)):
        batch[key] = src[0, 1000:1512].float()
    batch["cp"] = test.params[0].float()
    batch = {k: v.float() if k[0] != "c" else v for k, v in batch.items()}

    trained = json.loads((OUT / "train.json").read_text())
    candidates, original_accuracy = [], None
    if not args.no_original:
        cand, m = original_candidate(batch)
        candidates.append(cand)
        from lnn_torch.systems import get_system

        original_accuracy = accuracy(OriginalAsModel(m), get_system("double_pendulum"), test)
        print(f"original: {original_accuracy}", flush=True)
    names = args.points or [n for n in POINTS if n in trained]
    for name in names:
        candidates.append(torch_candidates(name, False, torch.float32, batch, args.untrained))
        if not args.no_compile:
            candidates.append(torch_candidates(name, True, torch.float32, batch, args.untrained))
    if "w128" in names:
        candidates.append(torch_candidates("w128", False, torch.float64, batch, args.untrained))
    whats = ("accel", "train step", "rollout step")
    start = time.perf_counter()
    for c in candidates:  # warm-up: compilation, caches
        for what in whats:
            for _ in range(3):
                c.calls[what]()
    print(f"warm-up and compilation: {time.perf_counter() - start:.0f} s", flush=True)
    # per round, candidate and call kind: one untimed call, then the median of --calls timed calls
    times = in_turn({(c.name, c.path, c.dtype, w): c.calls[w] for c in candidates for w in whats}, args.rounds,
                    lambda fn: median_seconds(fn, args.calls, warmup=1),
                    lambda r: print(f"round {r}/{args.rounds}", flush=True) if r % 5 == 0 else None)
    rows = []
    for c in candidates:
        row = {"point": c.name, "path": c.path, "dtype": c.dtype}
        if c.path == "eager":
            row.update(op_profile(c.calls["accel"]))
        for what in whats:
            own = times[(c.name, c.path, c.dtype, what)]
            row[f"{what} ms"] = 1e3 * statistics.median(own)
            if not args.no_original:
                base = times[(ORIGINAL, "jit", "float32", what)]
                row[f"{what} / original"] = median_ratio(own, base)
        rows.append(row)
    head = {"machine": machine_header(), "rounds": args.rounds, "calls_per_round": args.calls,
            "command": " ".join(["python", *sys.argv]), "original_accuracy": original_accuracy,
            "untrained_networks": bool(args.untrained)}
    (OUT / "time.json").write_text(json.dumps({"header": head, "rows": rows}, indent=1))
    for row in rows:
        print(row, flush=True)
    wrote(OUT / "time.json")


# ---------------------------------------------------------------------------- report
def report(args) -> None:
    import numpy as np

    from lnn_torch.evaluation import plots, table_header, table_row

    plt = plots.plt
    trained = json.loads((OUT / "train.json").read_text())
    timed = json.loads((OUT / "time.json").read_text())
    head, rows = timed["header"], timed["rows"]
    # the longer-trained points take the costs of the network they share
    rows = rows + [{**r, "point": name} for name, (base, _) in LONGER.items() if name in trained
                   for r in timed["rows"] if r["point"] == base and r["dtype"] == "float32"]
    orig_acc = head.get("original_accuracy")
    lines = ["# Cost against accuracy: film_lnn configurations and the original JAX FiLM-LNN", "",
             f"Commands: `python benchmarks/cost_accuracy_front.py train` (each point {trained['w16']['steps']}"
             f" steps of 512 states on `data/front.h5`, 200 trajectories of seed 0; the points named '16k steps' "
             f"16,000 steps, with the costs of the network they share), then `{head['command']}` (run under the "
             "original's environment, see the script), then `python benchmarks/cost_accuracy_front.py report`. The "
             "float64 row is the float32-trained network cast to float64 (same accuracy to 1e-6).", "",
             f"{head['machine']}; one thread; {head['rounds']} rounds in turn, each candidate's median of "
             f"{head['calls_per_round']} calls per round; the table gives the median over rounds and the median "
             "per-round ratio to the original (the comparable quantity on a shared machine).", "",
             "Accuracy on the 20 held-out test trajectories of `data/front.h5`: acceleration rel. L2 error "
             "(every 10th point) and the median time until an RK4 rollout (dt = 5 ms) leaves 0.1 rad (10 s horizon)."
             + (" Points whose checkpoint was absent when timed were timed as freshly initialised networks of the "
                "same architecture (`--untrained`: a call's cost does not depend on the weights' values); their "
                "accuracy is that of the trained network (`train.json`)." if head.get("untrained_networks") else ""),
             "", *table_header(["point", "parameters", "path", "dtype", "test acc. error",
                                "time within 0.1 rad, median (s)", "512 accel (ms)", "× original", "train step (ms)",
                                "× original", "RK4 step, 64 traj. (ms)", "× original"])]
    for r in rows:
        if r["point"] == ORIGINAL:
            acc, div, n = (orig_acc or {}).get("acc_rel_err"), (orig_acc or {}).get("divergence_median_s"), 36680
        else:
            t = trained[r["point"]]
            acc, div, n = t["acc_rel_err"], t["divergence_median_s"], t["parameters"]
        cells = [r["point"], f"{n:,}", r["path"], r["dtype"], "-" if acc is None else f"{100 * acc:.3g} %",
                 "-" if div is None else f"{div:.2f}"]
        for what in ("accel", "train step", "rollout step"):
            cells += [f"{r[f'{what} ms']:.2f}", f"{r.get(f'{what} / original', float('nan')):.2f}"]
        lines.append(table_row(cells))
    lines += ["", "Where an eager call of 512 accelerations goes (torch profiler, one call): operator calls and the "
              "share of the profiled CPU time in matrix products; the rest is element-wise work and per-operator "
              "dispatch, which compilation removes.", "",
              *table_header(["point", "dtype", "aten operator calls (incl. nested)", "matrix-product share"])]
    for r in rows:
        if "aten calls (incl. nested)" in r and r["point"] not in LONGER:
            lines.append(table_row([r["point"], r["dtype"], r["aten calls (incl. nested)"],
                                    f"{100 * r['matrix-product share']:.0f} %"]))
    (OUT / "README.md").write_text("\n".join(lines) + "\n")
    summary(rows, trained, orig_acc)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, what in zip(axes, ("accel", "train step"), strict=True):
        for path, marker in (("eager", "o"), ("compiled", "s"), ("jit", "*")):
            pts = [(r[f"{what} ms"], (orig_acc or {}).get("acc_rel_err") if r["point"] == ORIGINAL
                    else trained[r["point"]]["acc_rel_err"], r["point"]) for r in rows
                   if r["path"] == path and r["dtype"] == "float32"]
            pts = [p for p in pts if p[1] is not None]
            if not pts:
                continue
            xs, ys, names = zip(*pts, strict=True)
            ax.scatter(xs, 100 * np.array(ys), marker=marker, s=80 if path == "jit" else 30,
                       label={"jit": ORIGINAL}.get(path, f"film_lnn, {path}"))
            for x, y, n in zip(xs, ys, names, strict=True):
                if path != "jit":
                    ax.annotate(n, (x, 100 * y), fontsize=6, xytext=(3, 3), textcoords="offset points")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(f"{what} cost (ms, 512 states, one thread)")
        ax.set_ylabel("held-out acceleration error (%)")
        ax.grid(alpha=0.3, which="both")
    axes[1].legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(OUT / "front.png", dpi=110)
    print("\n".join(lines))
    wrote(OUT / "README.md", OUT / "summary.md", OUT / "front.png")


# the README's short table: point -> its label there
SUMMARY = {"w8": "`film_lnn` 8 × 8", "w16 x1": "`film_lnn` one hidden layer of 16", "w16": "`film_lnn` 16 × 16",
           "w32": "`film_lnn` 32 × 32 (`configs/quickstart_fast.yaml`)",
           "w64": "`film_lnn` 64 × 64 (the default of `film_lnn`, the shipped model's width)",
           "w128": "`film_lnn` 128 × 128 (the quickstart's width, the box model's)",
           "w32, 16k steps": "`film_lnn` 32 × 32, 16,000 steps",
           "w64, 16k steps": "`film_lnn` 64 × 64, 16,000 steps"}


def summary(rows: list, trained: dict, orig_acc: dict | None) -> None:
    """``summary.md``: the README's table (ratios to the original, eager / compiled)."""
    from lnn_torch.evaluation import table_header, table_row

    by = {(r["point"], r["path"], r["dtype"]): r for r in rows}
    orig = by.get((ORIGINAL, "jit", "float32"))
    lines = table_header(["configuration", "held-out acc. error", "time within 0.1 rad (median)",
                          "512 accel, eager / compiled", "train step, eager / compiled",
                          "RK4 step of 64, eager / compiled"])
    if orig is not None and orig_acc:
        lines.append(table_row(["JAX original (released, 50,000 steps)", f"{100 * orig_acc['acc_rel_err']:.2f} %",
                                f"{orig_acc['divergence_median_s']:.1f} s", f"1 ({orig['accel ms']:.2f} ms)",
                                f"1 ({orig['train step ms']:.1f} ms)", f"1 ({orig['rollout step ms']:.2f} ms)"]))
    for point, label in SUMMARY.items():
        eager, comp = by.get((point, "eager", "float32")), by.get((point, "compiled", "float32"))
        if point not in trained or eager is None or comp is None:
            continue
        t = trained[point]
        div = t["divergence_median_s"]
        cells = [label, f"{100 * t['acc_rel_err']:.2f} %",
                 f"≥ {t['horizon_s']:.0f} s" if div >= t["horizon_s"] else f"{div:.1f} s"]
        for what in ("accel", "train step", "rollout step"):
            cells.append(f"{eager[f'{what} / original']:.2f} / {comp[f'{what} / original']:.2f} ×")
        lines.append(table_row(cells))
    (OUT / "summary.md").write_text("\n".join(lines) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("step", choices=("train", "time", "report"),
                    help="train the points, time them, or write the report from train.json and time.json")
    ap.add_argument("--points", nargs="*", help=f"points to train or time (default: all): {', '.join(POINTS)}")
    ap.add_argument("--steps", type=int, default=6000, help="training steps per point")
    ap.add_argument("--threads", type=int, default=2, help="training threads")
    ap.add_argument("--again", action="store_true", help="retrain points already trained")
    ap.add_argument("--rounds", type=int, default=20, help="time: rounds, each timing every candidate in turn")
    ap.add_argument("--calls", type=int, default=9, help="time: timed calls per candidate and round")
    ap.add_argument("--no-original", action="store_true", help="time: lnn_torch points only, without the original")
    ap.add_argument("--no-compile", action="store_true", help="time: no compiled candidates")
    ap.add_argument("--untrained", action="store_true",
                    help="time: build a point's network freshly initialised where its checkpoint is absent (costs do "
                         "not depend on the weights' values; accuracies come from train.json)")
    args = ap.parse_args()
    {"train": train, "time": time_all, "report": report}[args.step](args)


if __name__ == "__main__":
    main()
