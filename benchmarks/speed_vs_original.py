"""Accelerations per call against the released JAX original, at batch 1, 512 and 4096, in every mode.

One process, one CPU thread. The original (``jax_original``: its own model call, jitted, float32) and
each lnn_torch model in each mode are timed in turn over ``--rounds`` rounds; a cell is the median over
rounds of the per-round ratio to the original's time (and the median time per call). The modes:

* ``eager``: ``model.acceleration(q, qd, params, check=False)`` under ``torch.no_grad()`` (for ``film_lnn``'s
  default composition the two networks stacked into one, ``lnn_torch.networks.fused``);
* ``eager, part by part``: the same with ``fuse_inference`` off (each network on its own, as under a gradient);
* ``compiled``: the same after ``model.compile_dynamics(True)``: up to ``networks.fused.COMPILED_MAX_ROWS``
  rows the stacked network as an AOTInductor program called without dynamo (``networks.fused_aot``), above
  it the networks part by part through ``torch.compile`` (C++ wrapper);
* ``compiled, part by part``: compiled with ``fuse_inference`` off (the program of each network on its own);
* ``AOTInductor``: the exported forward dynamics (``lnn-torch export --format aoti``), loaded and called
  as ``lnn_torch.export.programs.load_program`` gives it (where a C++ compiler is found; ``--no-aoti``).

The states are seeded draws of the default scene's distribution (the same arrays for every candidate).
By default the models are the two shipped double-pendulum models. The inductor cache is used as it
is: compilation is outside the timings (``results/compile_rule.md`` measures what it costs).

    python benchmarks/speed_vs_original.py -o results/speed

Needs the original and jax (``benchmarks/jax_original.py`` says how to set them up).
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import shlex
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("TORCHINDUCTOR_COMPILE_THREADS", "1")  # compile in this process, not a pool
os.environ.setdefault("OMP_NUM_THREADS", "1")

import jax_original as harness  # noqa: E402  (before jax starts: one XLA thread)
import numpy as np  # noqa: E402
import torch  # noqa: E402
from timing import HelpFormatter, add_output_dir, calls_per_run, in_turn, machine_header, run_seconds, wrote  # noqa: E402

from lnn_torch import load_model  # noqa: E402
from lnn_torch.evaluation import markdown_table  # noqa: E402
from lnn_torch.export import programs as ex  # noqa: E402
from lnn_torch.networks import fusable  # noqa: E402
from lnn_torch.perf import configure_cpu  # noqa: E402
from lnn_torch.systems import get_system  # noqa: E402

BATCHES = (1, 512, 4096)
MODELS = ("pretrained:double_pendulum", "pretrained:double_pendulum_control")
ORIGINAL = "JAX original (released, jit)"
MODES = ("eager", "eager, part by part", "compiled", "compiled, part by part", "AOTInductor")


def states(batch: int, seed: int = 0):
    """``batch`` seeded states and parameters of the default scene, float32 numpy."""
    system = get_system("double_pendulum")
    rng = np.random.default_rng(seed + batch)
    q, qd = system.sample_state(rng, batch)
    params = system.sample_params(rng, batch)
    return tuple(np.ascontiguousarray(x, dtype=np.float32) for x in (q, qd, params))


def model_calls(name: str, batches, aoti_dir: Path | None) -> tuple[dict, dict]:
    """``{(name, mode, batch): fn}`` for one model, and the seconds its compilations took."""
    module = load_model(name).float().eval()
    eager = module.model
    parts = copy.deepcopy(eager)
    parts.fuse_inference = False
    compiled = copy.deepcopy(eager).compile_dynamics(True)
    compiled_parts = copy.deepcopy(parts).compile_dynamics(True) if fusable(eager) else None
    aoti, seconds = None, {}
    if aoti_dir is not None:
        fn = ex.wrap(module, "forward_dynamics", torch.float32)
        start = time.perf_counter()
        slug = name.replace(":", "_").replace("/", "_")
        path = ex.compile_aoti(ex.export_program(fn), fn, aoti_dir / f"{slug}.aoti.pt2")
        seconds["AOTInductor"] = time.perf_counter() - start
        aoti = ex.load_program(path)
    calls = {}
    for batch in batches:
        q, qd, params = (torch.from_numpy(x) for x in states(batch))

        def run(model, q=q, qd=qd, params=params):
            with torch.no_grad():
                return model.acceleration(q, qd, params, check=False)

        calls[(name, "eager", batch)] = lambda run=run: run(eager)
        if fusable(eager):  # the same call part by part, where eager runs fused
            calls[(name, "eager, part by part", batch)] = lambda run=run: run(parts)
        start = time.perf_counter()
        run(compiled)  # compiles this batch shape
        seconds[f"compiled, batch {batch}"] = time.perf_counter() - start
        calls[(name, "compiled", batch)] = lambda run=run: run(compiled)
        if compiled_parts is not None:
            run(compiled_parts)
            calls[(name, "compiled, part by part", batch)] = lambda run=run: run(compiled_parts)
        if aoti is not None:
            calls[(name, "AOTInductor", batch)] = lambda q=q, qd=qd, params=params: aoti(q, qd, params)
        reference = run(eager)
        for key in [k for k in calls if k[2] == batch and k[1] != "eager"]:
            got = calls[key]()
            if not torch.allclose(got, reference, rtol=1e-3, atol=1e-3 * float(reference.abs().max())):
                raise SystemExit(f"{key}: its accelerations differ from eager's")
    return calls, seconds


def original_calls(batches) -> dict:
    m = harness.load("float32")
    calls = {}
    for batch in batches:
        q, qd, params = m.to_device(*states(batch))
        calls[(ORIGINAL, "jit", batch)] = lambda q=q, qd=qd, p=params: m.accel_device(q, qd, p).block_until_ready()
    return calls


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--models", nargs="+", default=list(MODELS), help="checkpoints or pretrained:<name>")
    ap.add_argument("--batches", nargs="+", type=int, default=list(BATCHES))
    ap.add_argument("--rounds", type=int, default=15, help="rounds, each timing every candidate once")
    ap.add_argument("--no-aoti", action="store_true", help="leave out the AOTInductor export (~20 s a model)")
    ap.add_argument("--compiled-max-rows", type=int, default=None,
                    help="the largest batch whose compiled call runs the stacked network "
                         "(default lnn_torch.networks.fused.COMPILED_MAX_ROWS)")
    add_output_dir(ap, None, "write README.md and speed.json there")
    args = ap.parse_args()
    configure_cpu(1)
    if args.compiled_max_rows is not None:
        from lnn_torch.networks import fused

        fused.COMPILED_MAX_ROWS = args.compiled_max_rows
    torch.set_num_threads(1)
    has_aoti = not args.no_aoti and bool(shutil.which("g++") or shutil.which("clang++") or os.environ.get("CXX"))
    candidates = original_calls(args.batches)
    compile_seconds = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.models:
            calls, seconds = model_calls(name, args.batches, Path(tmp) if has_aoti else None)
            candidates.update(calls)
            compile_seconds[name] = seconds
            print(f"{name}: built ({', '.join(f'{k} {v:.0f} s' for k, v in seconds.items())})", file=sys.stderr,
                  flush=True)
        # each candidate's round: one untimed call, then about 20 ms of calls in a row
        runs = {key: calls_per_run(fn, 0.02) for key, fn in candidates.items()}
        timed = {key: (lambda fn=fn, n=runs[key]: run_seconds(fn, n, 1, warmup_calls=1))
                 for key, fn in candidates.items()}

        def progress(r):
            if r % 5 == 0:
                print(f"round {r}/{args.rounds}", file=sys.stderr, flush=True)

        values = in_turn(timed, args.rounds, lambda measure: measure(), progress)
    rows = []
    for key, own in values.items():
        name, mode, batch = key
        base = values[(ORIGINAL, "jit", batch)]
        rows.append({"model": name, "mode": mode, "batch": batch, "ms": 1e3 * statistics.median(own),
                     "ratio": statistics.median(a / b for a, b in zip(own, base, strict=True))})
    command = "python " + " ".join(shlex.quote(a) for a in ["benchmarks/speed_vs_original.py", *sys.argv[1:]])
    head = ["model", "mode", *(f"batch {b}" for b in args.batches)]
    table = []
    for name in [ORIGINAL, *args.models]:
        for mode in ("jit",) if name == ORIGINAL else MODES:
            cells = [r for r in rows if r["model"] == name and r["mode"] == mode]
            if not cells:
                continue
            by_batch = {r["batch"]: r for r in cells}
            table.append([name, mode, *(f"{by_batch[b]['ms']:.3g} ms" if name == ORIGINAL else
                                        f"{by_batch[b]['ratio']:.2f}× ({by_batch[b]['ms']:.3g} ms)"
                                        for b in args.batches)])
    lines = ["# Accelerations per call against the JAX original", "",
             f"One CPU thread, one process held to one core (`os.sched_setaffinity`: jaxlib otherwise spreads the "
             f"original over every core): {machine_header()} (at the end).", "",
             f"Each cell: the median over {args.rounds} rounds of the per-round ratio of the call's time to the "
             "original's at the same batch (in brackets the median time per call); the original's row gives its "
             "time. A round times every candidate in turn, each over about 20 ms of calls in a row.", "",
             markdown_table(head, table), "",
             "Compilation (outside the timings): " + "; ".join(
                 f"{n}: " + ", ".join(f"{k} {v:.0f} s" for k, v in s.items())
                 for n, s in compile_seconds.items()) + ".",
             "", "Command:", "", f"    {command}", ""]
    text = "\n".join(lines)
    print(text)
    if args.output_dir:
        out = Path(args.output_dir)
        out.mkdir(parents=True, exist_ok=True)
        (out / "README.md").write_text(text)
        head = {"machine": machine_header(), "command": command, "rounds": args.rounds,
                "compile_seconds": compile_seconds}
        (out / "speed.json").write_text(json.dumps({"header": head, "rows": rows}, indent=1))
        wrote(out / "README.md")


if __name__ == "__main__":
    main()
