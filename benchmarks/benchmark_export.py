"""Latency of the exported dynamics (``lnn-torch export``) against the eager model, batch 1 and 4096.

One CPU thread. Per function and batch: the model's own method as a user calls it (``LNNModule``,
inputs checked), the same computation without the checks (eager, unchecked), the ``torch.export``
program (``torch.export.load(...).module()``), its AOTInductor package (where a C++ compiler is
found; ``--no-aoti`` skips the ~20 s compilation per function) and ONNX Runtime (where ``onnx``,
``onnxscript`` and ``onnxruntime`` are installed). Each cell is the median over ``--repeats`` runs of
the time per call, a run being many calls in a row (batch 1: 200); inputs are ready tensors (numpy
arrays for ONNX Runtime), so the time is the call's alone.

By default the model is the architecture of ``configs/actuated_double_pendulum.yaml`` (``film_lnn``
64 x 64, FiLM networks 64 wide, eleven parameters), untrained with its normaliser fitted: the time
of a call does not depend on the weights, and no trained actuated model ships with the package.
``--checkpoint`` times a trained one instead (``pretrained:double_pendulum``: forward dynamics and
the mass matrix only, it has no inputs).

    python benchmarks/benchmark_export.py -o results/export.md
"""

from __future__ import annotations

import argparse
import os
import shlex
import shutil
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("TORCHINDUCTOR_COMPILE_THREADS", "1")  # compile in this process, not a pool
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402
from timing import HelpFormatter, add_output_file, machine_header, run_seconds, wrote  # noqa: E402

from lnn_torch.evaluation import table_row  # noqa: E402
from lnn_torch.export import programs as ex  # noqa: E402
from lnn_torch.perf import configure_cpu  # noqa: E402

BATCHES = (1, 4096)


def configured_module(seed: int = 0):
    """The architecture of configs/actuated_double_pendulum.yaml, untrained, its normaliser fitted on
    the scene's distribution (inputs included)."""
    from lnn_torch import LNNModule

    torch.manual_seed(seed)
    module = LNNModule(scene="actuated_double_pendulum", variant="film_lnn", hidden_dims=[64, 64],
                       model_options={"film_hidden": 64})
    system = module.system
    rng = np.random.default_rng(seed)
    params = torch.tensor(system.sample_params(rng, 512))
    q, qd = (torch.tensor(x) for x in system.sample_state(rng, 512))
    tau = torch.tensor(rng.uniform(-1, 1, (512, system.num_inputs)))
    module.model.fit_normalizer({"q": q, "qd": qd, "qdd": system.acceleration(q, qd, params, tau), "params": params,
                                 "params_points": params, "tau": tau})
    return module.eval()


def inputs(module, function: str, batch: int, dtype, seed: int = 0) -> tuple[torch.Tensor, ...]:
    system = module.system
    rng = np.random.default_rng(seed)
    params = torch.tensor(system.sample_params(rng, batch), dtype=dtype)
    q, qd = (torch.tensor(x, dtype=dtype) for x in system.sample_state(rng, batch))
    qdd = torch.tensor(rng.normal(0, 5, (batch, system.dof)), dtype=dtype)
    tau = torch.tensor(rng.uniform(-1, 1, (batch, system.num_inputs)), dtype=dtype) if system.num_inputs else None
    return {"forward_dynamics": (q, qd, params) + (() if tau is None else (tau,)),
            "inverse_dynamics": (q, qd, qdd, params), "mass_matrix": (q, params),
            "bias_force": (q, qd, params), "gravity_force": (q, params)}[function]


def checked_call(module, function: str):
    """The ``LNNModule``'s own method (inputs checked) for ``function``."""
    if function == "forward_dynamics":
        return module.acceleration
    if function == "inverse_dynamics":
        return module.inverse
    if function == "mass_matrix":
        return module.mass_matrix
    return None


def per_call_seconds(fn, batch: int, repeats: int) -> float:
    """Median over ``repeats`` runs of the time per call, a run being ``n`` calls in a row (batch 1: 200,
    else 3), after ``max(3, n // 10)`` untimed calls."""
    n = 200 if batch == 1 else 3
    return run_seconds(fn, n, repeats, warmup_calls=max(3, n // 10))


def ort_session(path: Path):
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def cell(seconds: float | None) -> str:
    if seconds is None:
        return "-"
    return f"{seconds * 1e6:.1f} µs" if seconds < 1e-3 else f"{seconds * 1e3:.2f} ms"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--checkpoint", default=None,
                    help="a trained checkpoint or pretrained:NAME (default: the actuated architecture, untrained)")
    ap.add_argument("--functions", nargs="+", default=["forward_dynamics", "inverse_dynamics", "mass_matrix"],
                    choices=ex.FUNCTIONS)
    ap.add_argument("--dtype", default="float32", choices=sorted(ex.DTYPES))
    ap.add_argument("--repeats", type=int, default=15, help="timed runs per cell (the median is reported)")
    ap.add_argument("--no-aoti", action="store_true", help="skip AOTInductor (its compilation takes ~20 s a function)")
    ap.add_argument("--no-onnx", action="store_true", help="skip ONNX Runtime even where it is installed")
    add_output_file(ap, None, "also write the Markdown table (and the command) to this file")
    args = ap.parse_args()
    configure_cpu(1)
    torch.set_num_threads(1)
    dtype = ex.DTYPES[args.dtype]
    if args.checkpoint:
        from lnn_torch import load_model

        module, label = load_model(args.checkpoint), args.checkpoint
    else:
        module = configured_module()
        label = ("film_lnn 64 x 64 (FiLM 64) on actuated_double_pendulum, untrained "
                 "(configs/actuated_double_pendulum.yaml)")
    functions = [f for f in args.functions if ex.refusal(module, f) is None]
    skipped = [f for f in args.functions if f not in functions]
    has_aoti = not args.no_aoti and (shutil.which("g++") or shutil.which("clang++") or os.environ.get("CXX"))
    has_onnx = not args.no_onnx and not ex.onnx_requirement()
    if has_onnx:
        try:
            import onnxruntime  # noqa: F401
        except ImportError:
            has_onnx = False
    columns = ["LNNModule (checked)", "eager, unchecked", "torch.export .pt2"]
    columns += ["AOTInductor"] * bool(has_aoti) + ["ONNX Runtime"] * bool(has_onnx)
    rows, export_seconds, aoti_seconds = [], {}, {}
    eager_model = module if dtype == module.model.dtype else None
    with tempfile.TemporaryDirectory() as tmp, torch.no_grad():
        tmp = Path(tmp)
        for function in functions:
            fn = ex.wrap(module, function, dtype)
            start = time.perf_counter()
            program = ex.export_program(fn)
            torch.export.save(program, tmp / f"{function}.pt2")
            export_seconds[function] = time.perf_counter() - start
            runners = {"eager, unchecked": fn, "torch.export .pt2": ex.load_program(tmp / f"{function}.pt2")}
            if has_aoti:
                start = time.perf_counter()
                path = ex.compile_aoti(program, fn, tmp / f"{function}.aoti.pt2")
                aoti_seconds[function] = time.perf_counter() - start
                runners["AOTInductor"] = ex.load_program(path)
            if has_onnx:
                session = ort_session(ex.export_onnx(program, fn, tmp / f"{function}.onnx"))
            for batch in BATCHES:
                x = inputs(module, function, batch, dtype)
                row = {}
                checked = checked_call(module, function) if eager_model is not None else None
                row["LNNModule (checked)"] = None if checked is None else per_call_seconds(
                    lambda checked=checked, x=x: checked(*x), batch, args.repeats)
                for name, runner in runners.items():
                    row[name] = per_call_seconds(lambda runner=runner, x=x: runner(*x), batch, args.repeats)
                if has_onnx:
                    # the graph's inputs in order (an input the program does not use may be left out of it)
                    feed = {i.name: a.numpy() for i, a in zip(session.get_inputs(), x, strict=False)}
                    row["ONNX Runtime"] = per_call_seconds(lambda session=session, feed=feed: session.run(None, feed),
                                                           batch, args.repeats)
                rows.append((function, batch, row))
                print(f"{function} batch {batch}: " + ", ".join(f"{k} {cell(v)}" for k, v in row.items()),
                      file=sys.stderr, flush=True)
    command = "python " + " ".join(shlex.quote(a) for a in ["benchmarks/benchmark_export.py", *sys.argv[1:]])
    lines = ["# Exported dynamics: latency per call (lnn-torch export)", "",
             f"Model: {label}; {args.dtype}; one CPU thread: {machine_header()} (at the end).", "",
             "Median time per call over " f"{args.repeats} runs (batch 1: 200 calls a run; batch 4096: 3).", "",
             table_row(["function", "batch", *columns]),
             table_row(["---", "---:", *["---:"] * len(columns)])]  # the numbers right-aligned
    for function, batch, row in rows:
        lines.append(table_row([function, batch, *(cell(row.get(c)) for c in columns)]))
    lines += ["", "torch.export per function: " + ", ".join(f"{f} {s:.1f} s" for f, s in export_seconds.items())
              + (("; AOTInductor compilation: " + ", ".join(f"{f} {s:.0f} s" for f, s in aoti_seconds.items()))
                 if aoti_seconds else "") + "."]
    if skipped:
        lines.append("Not exported (the model lacks them): " + ", ".join(skipped) + ".")
    if has_onnx:
        import onnx
        import onnxruntime
        import onnxscript

        lines.append(f"ONNX Runtime {onnxruntime.__version__} (onnx {onnx.__version__}, onnxscript "
                     f"{onnxscript.__version__}), one intra-op thread, sequential execution.")
    if not has_onnx and not args.no_onnx:
        lines.append("ONNX Runtime: not installed here (pip install 'lnn-torch[export]').")
    lines += ["", "Command:", "", f"    {command}"]
    table = "\n".join(lines) + "\n"
    print(table)
    if args.output:
        Path(args.output).parent.mkdir(parents=True, exist_ok=True)
        Path(args.output).write_text(table)
        wrote(args.output)


if __name__ == "__main__":
    main()
