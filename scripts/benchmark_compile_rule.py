"""Where compiling a rollout pays: compilation time against the time it saves per acceleration call.

For the shipped double-pendulum model (film_lnn 128 x 128, float32, one thread, no autograd) and
batch sizes 1, 20, 64 and 512: the time of one RK4 step eagerly and compiled (the whole step, as a rollout runs it)
(medians), the first compiled call's time on an empty inductor cache (a fresh cache directory: what
a user's first run pays) and again in a new process with that cache filled, and the break-even: the
number of acceleration calls (4 per RK4 step) after which the compiled rollout has repaid its
compilation. ``lnn_torch.perf.AUTO_COMPILE_CALLS`` is set from it.

    python scripts/benchmark_compile_rule.py        # writes results/compile_rule.md (~5 min)
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BATCHES = (1, 20, 64, 512)

CHILD = r"""
import json, statistics, sys, time
import torch
torch.set_num_threads(1)
from lnn_torch.checkpoints import load_model
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


def run(batch: int, cache: str) -> dict:
    env = {**os.environ, "TORCHINDUCTOR_CACHE_DIR": cache, "TORCHINDUCTOR_COMPILE_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", CHILD, str(batch)], env=env, cwd=ROOT, capture_output=True, text=True,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    rows = []
    for batch in BATCHES:
        with tempfile.TemporaryDirectory() as cache:
            cold = run(batch, cache)
            warm = run(batch, cache)
        saved_per_call = (statistics.mean([cold["eager_step_s"], warm["eager_step_s"]])
                          - statistics.mean([cold["compiled_step_s"], warm["compiled_step_s"]])) / 4
        compile_cold = cold["first_call_s"] - cold["compiled_step_s"]
        compile_warm = warm["first_call_s"] - warm["compiled_step_s"]
        rows.append({"batch": batch, "eager_ms": 1e3 * warm["eager_step_s"], "compiled_ms": 1e3 * warm["compiled_step_s"],
                     "compile_cold_s": compile_cold, "compile_warm_s": compile_warm,
                     "break_even_cold": compile_cold / saved_per_call if saved_per_call > 0 else float("inf"),
                     "break_even_warm": compile_warm / saved_per_call if saved_per_call > 0 else float("inf")})
        print(rows[-1], flush=True)
    from lnn_torch.perf import AUTO_COMPILE_CALLS

    lines = ["# When a compiled rollout pays", "",
             "Command: `python scripts/benchmark_compile_rule.py`. The shipped model (film_lnn 128 x 128, float32), one "
             "thread, no autograd; each batch size in two fresh processes sharing a new inductor cache directory (cold: "
             "empty cache, a user's first run; warm: the second process). Step times are medians of 7 x 50 RK4 steps.",
             "", "| batch | RK4 step eager (ms) | RK4 step compiled (ms) | compilation, cold cache (s) | "
             "compilation, warm cache (s) | break-even, cold (acceleration calls) | break-even, warm (calls) |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['batch']} | {r['eager_ms']:.2f} | {r['compiled_ms']:.2f} | {r['compile_cold_s']:.1f} | "
                     f"{r['compile_warm_s']:.1f} | {r['break_even_cold']:,.0f} | {r['break_even_warm']:,.0f} |")
    lines += ["", f"The rule in the library: a rollout compiles its integrator step when it makes at least "
              f"`lnn_torch.perf.AUTO_COMPILE_CALLS` = {AUTO_COMPILE_CALLS:,} acceleration calls (default mode "
              "`compile_dynamics(\"auto\")`; `LNN_TORCH_COMPILE=0` or `compile_dynamics(False)` switch it off). "
              f"It sits between the warm-cache break-even ({min(r['break_even_warm'] for r in rows):,.0f}–"
              f"{max(r['break_even_warm'] for r in rows):,.0f} calls) and the cold one "
              f"({min(r['break_even_cold'] for r in rows):,.0f}–{max(r['break_even_cold'] for r in rows):,.0f})."]
    text = "\n".join(lines) + "\n"
    (ROOT / "results" / "compile_rule.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
