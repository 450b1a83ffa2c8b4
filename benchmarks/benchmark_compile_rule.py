"""Where compiling pays: compilation time against the time it saves per acceleration call (rollouts)
and per optimiser step (training).

For the shipped double-pendulum model (film_lnn 64 x 64, float32, one thread, no autograd) and
batch sizes 1, 20, 64 and 512: the time of one RK4 step eagerly and compiled (the whole step, as a rollout runs it)
(medians), the first compiled call's time on an empty inductor cache (a fresh cache directory: what
a user's first run pays) and again in a new process with that cache filled, and the break-even: the
number of acceleration calls (4 per RK4 step) after which the compiled rollout has repaid its
compilation. ``lnn_torch.perf.AUTO_COMPILE_CALLS`` is set from it.

Training: for film_lnn 64 x 64 (its default) and 128 x 128 (the configs), one training step of the
quickstart's batch (64 chunks of 8 points of data/quickstart.h5: loss, backward, gradient clipping,
AdamW), eagerly and through the compiled pass (forward and backward), the first compiled step on a
cold and a warm cache, and the break-even in optimiser steps. ``lnn_torch.perf.AUTO_COMPILE_TRAIN_STEPS``
is set from it.

    python benchmarks/benchmark_compile_rule.py     # writes results/compile_rule.{json,md} (~10 min)
    python benchmarks/benchmark_compile_rule.py --only training    # re-measure one part
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from timing import ROOT, HelpFormatter, add_output_dir, machine_header, wrote

BATCHES = (1, 20, 64, 512)

CHILD = r"""
import json, statistics, sys, time
import torch
torch.set_num_threads(1)
from lnn_torch import load_model
B = int(sys.argv[1])
model = load_model("pretrained:double_pendulum").model
g = torch.Generator().manual_seed(0)
q, qd = (torch.rand(B, 2, generator=g) - 0.5) * 3, (torch.rand(B, 2, generator=g) - 0.5) * 4
p = torch.tensor([1.0, 0.6, 1.2, 1.1]).expand(B, -1)
def steps(n):
    with torch.no_grad():
        model.rollout(q, qd, p, 0.005, n)
def per_step(n=50, repeats=7):
    steps(5)
    ts = []
    for _ in range(repeats):
        t = time.perf_counter(); steps(n); ts.append((time.perf_counter() - t) / n)
    return statistics.median(ts)
model.compile_dynamics(False)
eager = per_step()
model.compile_dynamics(True)
t = time.perf_counter(); steps(1); first = time.perf_counter() - t
compiled = per_step()
print(json.dumps({"eager_step_s": eager, "compiled_step_s": compiled, "first_call_s": first}))
"""

TRAIN_CHILD = r"""
import json, statistics, sys, time
import torch
torch.set_num_threads(1)
from lnn_torch import LNNModule, TrajectoryDataModule
from lnn_torch.perf import adamw
from lnn_torch.training import TrainingPass
width = int(sys.argv[1])
dm = TrajectoryDataModule(path="data/quickstart.h5", spec=dict(scene="double_pendulum", num_trajectories=200,
                          duration=20.0, dt=0.005, seed=0), chunk_len=8, chunks_per_batch=64, seed=0)
dm.prepare_data()
dm.setup("fit")
batch = dm.train_set[0]
module = LNNModule(hidden_dims=[width, width], val_rollouts=0, compile=False)
module.model.fit_normalizer(dm.normalization_data())
opt = adamw(module.parameters(), lr=1e-6)
def step(pass_fn):
    loss, _ = module.batch_loss(batch, pass_fn)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(module.parameters(), 1.0)
    opt.step()
    opt.zero_grad(set_to_none=True)
def per_step(pass_fn, n=20, repeats=7):
    step(pass_fn)
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        for _ in range(n):
            step(pass_fn)
        ts.append((time.perf_counter() - t) / n)
    return statistics.median(ts)
eager = per_step(module.training_terms)
fn = TrainingPass(module.training_terms, True).function(0, module.device)
t = time.perf_counter(); step(fn); first = time.perf_counter() - t
compiled = per_step(fn)
print(json.dumps({"eager_step_s": eager, "compiled_step_s": compiled, "first_call_s": first}))
"""


def run(arg: int, cache: str, child: str = CHILD) -> dict:
    env = {**os.environ, "TORCHINDUCTOR_CACHE_DIR": cache, "TORCHINDUCTOR_COMPILE_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", child, str(arg)], env=env, cwd=ROOT, capture_output=True, text=True,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def cold_and_warm(key: str, arg: int, child: str, calls_per_step: int) -> dict:
    """One row: ``child`` run in two fresh processes sharing a new inductor cache (cold, then warm);
    step times, compilation times and the break-even in calls (``calls_per_step`` per timed step)."""
    with tempfile.TemporaryDirectory() as cache:
        cold = run(arg, cache, child)
        warm = run(arg, cache, child)
    saved = (statistics.mean([cold["eager_step_s"], warm["eager_step_s"]])
             - statistics.mean([cold["compiled_step_s"], warm["compiled_step_s"]])) / calls_per_step
    compile_cold = cold["first_call_s"] - cold["compiled_step_s"]
    compile_warm = warm["first_call_s"] - warm["compiled_step_s"]
    row = {key: arg, "eager_ms": 1e3 * warm["eager_step_s"], "compiled_ms": 1e3 * warm["compiled_step_s"],
           "compile_cold_s": compile_cold, "compile_warm_s": compile_warm,
           "break_even_cold": compile_cold / saved if saved > 0 else float("inf"),
           "break_even_warm": compile_warm / saved if saved > 0 else float("inf")}
    print(row, flush=True)
    return row


def training_rows() -> list[dict]:
    """Break-even in optimiser steps, per network width."""
    return [cold_and_warm("width", width, TRAIN_CHILD, 1) for width in (64, 128)]


def rollout_rows() -> list[dict]:
    """Break-even in acceleration calls (4 per RK4 step), per batch size."""
    return [cold_and_warm("batch", batch, CHILD, 4) for batch in BATCHES]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--only", choices=("rollouts", "training"), help="measure one part, keep the other's last result")
    ap.add_argument("--report", action="store_true", help="only write the report from the last measurements")
    add_output_dir(ap, str(ROOT / "results"), "the folder of compile_rule.json and compile_rule.md", old=())
    args = ap.parse_args()
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    store = out / "compile_rule.json"
    measured = json.loads(store.read_text()) if store.exists() else {}
    if args.only != "training" and not args.report:
        measured["rollouts"] = rollout_rows()
    if args.only != "rollouts" and not args.report:
        measured["training"] = training_rows()
    if not args.report:
        measured["machine"] = machine_header()
    store.write_text(json.dumps(measured, indent=1))
    rows, train = measured.get("rollouts", []), measured.get("training", [])
    from lnn_torch.evaluation import table_header, table_row
    from lnn_torch.perf import AUTO_COMPILE_CALLS, AUTO_COMPILE_TRAIN_STEPS

    lines = ["# When a compiled rollout pays", "",
             "Command: `python benchmarks/benchmark_compile_rule.py`. The shipped model (film_lnn 64 x 64, "
             "float32), one thread, no autograd; each batch size in two fresh processes sharing a new inductor cache "
             "directory (cold: empty cache, a user's first run; warm: the second process). Step times are medians of "
             "7 x 50 RK4 steps.", *(["", f"Machine: {measured['machine']}."] if "machine" in measured else []),
             "", *table_header(["batch", "RK4 step eager (ms)", "RK4 step compiled (ms)",
                                "compilation, cold cache (s)", "compilation, warm cache (s)",
                                "break-even, cold (acceleration calls)", "break-even, warm (calls)"])]
    for r in rows:
        lines.append(table_row([r["batch"], f"{r['eager_ms']:.2f}", f"{r['compiled_ms']:.2f}",
                                f"{r['compile_cold_s']:.1f}", f"{r['compile_warm_s']:.1f}",
                                f"{r['break_even_cold']:,.0f}", f"{r['break_even_warm']:,.0f}"]))
    lines += ["", f"The rule in the library: a rollout compiles its integrator step when it makes at least "
              f"`lnn_torch.perf.AUTO_COMPILE_CALLS` = {AUTO_COMPILE_CALLS:,} acceleration calls (default mode "
              "`compile_dynamics(\"auto\")`; `LNN_TORCH_COMPILE=0` or `compile_dynamics(False)` switch it off). "
              f"It sits between the warm-cache break-even ({min(r['break_even_warm'] for r in rows):,.0f}–"
              f"{max(r['break_even_warm'] for r in rows):,.0f} calls) and the cold one "
              f"({min(r['break_even_cold'] for r in rows):,.0f}–{max(r['break_even_cold'] for r in rows):,.0f})."]
    lines += ["", "## When a compiled training pass pays", "",
              "film_lnn on the quickstart's training batch (64 chunks of 8 points), float32, one thread; a step is "
              "the loss, its backward, gradient clipping and AdamW. Step times: medians of 7 x 20 steps (warm "
              "process). On a machine shared with other jobs the absolute times grow, the break-even (a ratio of "
              "times) much less.",
              "", *table_header(["widths", "step eager (ms)", "step compiled (ms)", "compilation, cold cache (s)",
                                 "compilation, warm cache (s)", "break-even, cold (steps)",
                                 "break-even, warm (steps)"])]
    for r in train:
        lines.append(table_row([f"{r['width']} x {r['width']}", f"{r['eager_ms']:.2f}", f"{r['compiled_ms']:.2f}",
                                f"{r['compile_cold_s']:.1f}", f"{r['compile_warm_s']:.1f}",
                                f"{r['break_even_cold']:,.0f}", f"{r['break_even_warm']:,.0f}"]))
    lines += ["", "The rule in the library: training compiles its pass when the run is planned for at least "
              f"`lnn_torch.perf.AUTO_COMPILE_TRAIN_STEPS` = {AUTO_COMPILE_TRAIN_STEPS:,} optimiser steps (the "
              "trainer's `estimated_stepping_batches`; default `compile: auto`, `--model.compile false` or "
              "`LNN_TORCH_COMPILE=0` switch it off): about the cold-cache break-even "
              f"({min(r['break_even_cold'] for r in train):,.0f}–"
              f"{max(r['break_even_cold'] for r in train):,.0f} steps), "
              "so that a first run about breaks even and later runs (warm cache) gain."]
    text = "\n".join(lines) + "\n"
    (out / "compile_rule.md").write_text(text)
    print(text)
    wrote(store, out / "compile_rule.md")


if __name__ == "__main__":
    main()
