"""The cost of one MPPI step (``lnn_torch.control.MPPI``): ``--samples`` input sequences of
``--horizon`` steps rolled out in one batch on a plant, median wall time of ``--repeats`` calls after
a warm-up, for the learned model given and the real pendulum's identified lab model, at 1 and 2 CPU
threads. A 500 Hz control loop has 2 ms per step.

    python benchmarks/benchmark_mppi.py LAST_CKPT  # a model of the real pendulum (configs/real_double_pendulum.yaml)
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import torch
from timing import ROOT, HelpFormatter, add_output_file, machine_header, wrote

from lnn_torch import load_model
from lnn_torch.control import MPPI, plant_of
from lnn_torch.evaluation import markdown_table
from lnn_torch.identification import RigidArmModel
from lnn_torch.perf import median_seconds

LAB = ROOT / "lnn_torch" / "datasets" / "real_double_pendulum" / "identified_parameters.yml"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("checkpoint", help="a model of the real double pendulum (path or pretrained:NAME)")
    ap.add_argument("--samples", type=int, default=1000)
    ap.add_argument("--horizon", type=int, default=50)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--compile", action="store_true",
                    help="also the learned model's accelerations through torch.compile")
    add_output_file(ap, str(ROOT / "results" / "control" / "mppi.md"), "the table (Markdown)")
    args = ap.parse_args(argv)
    plants = {"learned model (film_lnn, float32)": plant_of(load_model(args.checkpoint))}
    if args.compile:
        compiled = load_model(args.checkpoint)
        compiled.model.compile_dynamics(True)
        plants["learned model, compiled"] = plant_of(compiled)
    plants["lab model (closed form)"] = plant_of(RigidArmModel.from_yaml(LAB))
    machine = machine_header()  # before the loop sets the thread counts it times
    goal = torch.tensor([[math.pi, 0.0]], dtype=torch.float64)
    q, qd = goal + 0.05, torch.zeros(1, 2, dtype=torch.float64)
    rows = []
    for name, plant in plants.items():
        for threads in (1, 2):
            torch.set_num_threads(threads)
            ctrl = MPPI(plant, goal, None, samples=args.samples, horizon=args.horizon, dt=0.01,
                        torque_limit=[10.0, 10.0])
            step = median_seconds(lambda ctrl=ctrl: ctrl(0.0, q, qd), args.repeats, warmup=1)
            rows.append((name, threads, f"{1e3 * step:.1f}"))
    lines = [f"# One MPPI step: {args.samples} samples x {args.horizon}-step horizon", "",
             f"`python benchmarks/benchmark_mppi.py {args.checkpoint}{' --compile' if args.compile else ''}` (median "
             f"of {args.repeats} calls after a warm-up; a 500 Hz loop has 2 ms). {machine}.", "",
             markdown_table(["plant rolled out", "CPU threads", "ms per step"], rows)]
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    wrote(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
