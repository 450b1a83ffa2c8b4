"""A library user's plain path, timed in fresh processes: import, load the shipped model, call it.

Each measurement is a new Python process (so nothing is warm or configured that a user would not
have): ``import lnn_torch`` -> ``load_model("pretrained:double_pendulum")`` -> 512 float32
accelerations (first call, then the median of 30) and a 1000-step RK4 rollout of 64 trajectories,
on one thread. Variants, run alternately (``--repeats`` processes each):

* ``plain``: exactly that, nothing else called (the library applies its CPU settings itself when it
  builds the model: ``lnn_torch.perf.apply_cpu_defaults``);
* ``configure_cpu``: the same after an explicit ``lnn_torch.perf.configure_cpu()``;
* ``LNN_TORCH_CPU_TUNING=0``: the plain path with the library's own CPU settings switched off.

    python benchmarks/benchmark_first_call.py             # writes results/first_call.md (-o FILE: elsewhere)
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

from timing import ROOT, HelpFormatter, add_output_file, in_turn, machine_header, wrote

from lnn_torch.evaluation import markdown_table

CHILD = r"""
import json, statistics, sys, time
t0 = time.perf_counter()
import torch
torch.set_num_threads(1)
import lnn_torch.perf
from lnn_torch import load_model
if sys.argv[1] == "configure_cpu":
    lnn_torch.perf.configure_cpu()
t_import = time.perf_counter() - t0
model = load_model("pretrained:double_pendulum")
t_load = time.perf_counter() - t0 - t_import
g = torch.Generator().manual_seed(0)
q = (torch.rand(512, 2, generator=g) - 0.5) * 3
qd = (torch.rand(512, 2, generator=g) - 0.5) * 4
p = torch.tensor([1.0, 0.6, 1.2, 1.1]).expand(512, -1)
def accel():
    with torch.no_grad():
        return model.acceleration(q, qd, p)
t = time.perf_counter(); accel(); first = time.perf_counter() - t
for _ in range(5): accel()
samples = []
for _ in range(30):
    t = time.perf_counter(); accel(); samples.append(time.perf_counter() - t)
def roll():
    with torch.no_grad():
        return model.rollout(q[:64], qd[:64], p[:64], 0.005, 1000)
t = time.perf_counter(); roll(); roll_first = time.perf_counter() - t
t = time.perf_counter(); roll(); roll_second = time.perf_counter() - t
print(json.dumps({"import_s": t_import, "load_s": t_load, "accel_first_ms": 1e3 * first,
                  "accel_median_ms": 1e3 * statistics.median(samples), "rollout_first_s": roll_first,
                  "rollout_second_s": roll_second}))
"""

VARIANTS = {"plain": ({}, "plain"), "configure_cpu": ({}, "configure_cpu"),
            "LNN_TORCH_CPU_TUNING=0": ({"LNN_TORCH_CPU_TUNING": "0"}, "plain")}


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--repeats", type=int, default=7, help="fresh processes per variant")
    add_output_file(ap, str(ROOT / "results" / "first_call.md"), "the Markdown file of the table (one file)",
                    old=("--out",))
    return ap


def fresh_process(env: dict, arg: str) -> dict:
    """One run of ``CHILD`` in a new Python process: its measurements."""
    out = subprocess.run([sys.executable, "-c", CHILD, arg], env={**os.environ, **env}, cwd=ROOT,
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    args = parser().parse_args()
    variants = {name: (lambda env=env, arg=arg: fresh_process(env, arg)) for name, (env, arg) in VARIANTS.items()}
    runs = in_turn(variants, args.repeats, lambda run: run())
    keys = ("import_s", "load_s", "accel_first_ms", "accel_median_ms", "rollout_first_s", "rollout_second_s")
    lines = ["# A library user's first calls, in fresh processes", "",
             f"Command: `python benchmarks/benchmark_first_call.py --repeats {args.repeats}`; torch threads 1; "
             f"medians over {args.repeats} fresh processes per variant, run alternately. {machine_header()}.", "",
             markdown_table(["variant", "import (s)", "load model (s)", "512 accel, first call (ms)",
                             "512 accel, median of 30 (ms)", "rollout 64 x 1000 RK4 steps, first (s)", "second (s)"],
                            [[name, *(f"{statistics.median(r[k] for r in rs):.3g}" for k in keys)]
                             for name, rs in runs.items()])]
    text = "\n".join(lines) + "\n"
    Path(args.output).write_text(text)
    print(text)
    wrote(args.output)


if __name__ == "__main__":
    main()
