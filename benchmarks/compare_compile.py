"""Eager against torch.compile's two wrappers, timed in turn in one process (same load for all).

The film_lnn structured accelerations of 512 float32 states under ``torch.no_grad()`` (default
network 2 x 128, default initialisation, one thread), three ways: eager; ``torch.compile`` with
inductor's default Python wrapper; and ``lnn_torch.perf.compile_fn`` (static shapes, the C++
wrapper on the CPU: what ``compile_dynamics()``, the training pass and the benchmarks use). Each
round times each candidate (median of ``--repeats`` calls after warm-up); the script prints
every candidate's median and range over the rounds and the median per-round ratio to eager.

    python benchmarks/compare_compile.py          # 12 rounds, ~1 min plus compilation
"""

from __future__ import annotations

import argparse
import os
import statistics
from pathlib import Path

os.environ.setdefault("TORCHINDUCTOR_COMPILE_THREADS", "1")  # no compile workers beside the timings

import numpy as np  # noqa: E402
import torch  # noqa: E402
from timing import HelpFormatter, add_output_file, in_turn, machine_header, median_ratio, wrote  # noqa: E402

from lnn_torch.evaluation import markdown_table  # noqa: E402
from lnn_torch.networks import build_model  # noqa: E402
from lnn_torch.perf import compile_fn, configure_cpu, median_seconds  # noqa: E402
from lnn_torch.systems import get_system  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--rounds", type=int, default=12, help="rounds, each timing every candidate in turn")
    ap.add_argument("--repeats", type=int, default=30, help="timed calls per median")
    ap.add_argument("--batch", type=int, default=512, help="states per call")
    add_output_file(ap, None, "also write the report (with the machine header) to this Markdown file")
    args = ap.parse_args()
    configure_cpu(1)
    system = get_system("double_pendulum")
    rng = np.random.default_rng(0)
    params = torch.tensor(system.sample_params(rng, args.batch)).float()
    q, qd = (torch.tensor(x).float() for x in system.sample_state(rng, args.batch))
    torch.manual_seed(0)
    model = build_model("film_lnn", system, hidden_dims=(128, 128)).float()
    model.normalizer.fit(q, qd, system.acceleration(q, qd, params), params)
    inputs = model.normalize(q, qd, params)
    candidates = {
        "eager": model.acceleration_norm,
        "torch.compile, Python wrapper": torch.compile(model.acceleration_norm, dynamic=False),
        "compile_fn (C++ wrapper)": compile_fn(model.acceleration_norm),
    }
    lines = []
    with torch.no_grad():
        reference = model.acceleration_norm(*inputs)
        for name, fn in candidates.items():  # compiles
            err = (fn(*inputs) - reference).abs().max().item()
            lines.append(f"{name}: max |difference| to eager {err:.1e}")
            print(lines[-1], flush=True)

    def timed(fn):
        def call():
            with torch.no_grad():
                fn(*inputs)
        return call

    times = in_turn({name: timed(fn) for name, fn in candidates.items()}, args.rounds,
                    lambda call: 1e3 * median_seconds(call, args.repeats, 5))
    cpp, py = times["compile_fn (C++ wrapper)"], times["torch.compile, Python wrapper"]
    lines += ["", f"{machine_header()}; float32, {args.batch} states, {args.rounds} rounds in turn, "
              f"medians of {args.repeats} "
              "calls per round",
              markdown_table(["path", "median (ms)", "range over rounds (ms)", "median per-round ratio to eager"],
                             [[name, f"{statistics.median(t):.3f}", f"{min(t):.3f} – {max(t):.3f}",
                               f"{median_ratio(t, times['eager']):.3f}"] for name, t in times.items()]),
              "", f"C++ / Python wrapper, median per-round ratio: {median_ratio(cpp, py):.3f}"]
    print("\n".join(lines[len(candidates):]))
    if args.output:
        Path(args.output).parent.mkdir(parents=True, exist_ok=True)
        Path(args.output).write_text("\n".join(lines) + "\n")
        wrote(args.output)

if __name__ == "__main__":
    main()
