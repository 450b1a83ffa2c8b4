"""The GPU path: the shipped models' accelerations, training steps and rollouts on a CUDA device,
beside the original JAX FiLM-LNN on the same GPU and the same machine's CPU, in one process.

Candidates (float32), timed in turn over ``--rounds`` rounds (per round and call: one untimed call,
then the median of ``--calls`` timed calls, each ended by a device synchronisation):

* ``pretrained:double_pendulum`` (film_lnn, 128 x 128) and ``pretrained:robot_arm_film_lnn`` (the
  Panda's, 128 x 128, 7 joints, actuated): on the GPU eagerly and compiled (``compile_dynamics()``, the
  compiled training pass), and eagerly on the CPU with all its cores;
* the released original (``benchmarks/jax_original.py``, 128 x 128, its own model call and jitted
  ``train_step``) on the same GPU, for the double pendulum.

Calls: ``accel B`` (B accelerations, no autograd; the arm's with random torques), ``train step B``
(loss, backward, gradient clipping, AdamW step on B states: the double pendulum's as chunks of 8
points, the arm's as single points, as their configs train; the original's on B consecutive points),
``rollout`` (RK4, 1024 trajectories, 100 steps of 5 ms).

    python benchmarks/benchmark_gpu.py                       # needs a CUDA device; results/gpu/benchmark_gpu.md
    LNN_JAX_ORIGINAL_SRC=../jax_original/src_checkout/src python benchmarks/benchmark_gpu.py ...

Writes the Markdown table and, beside it, the JSON of every round.
"""

from __future__ import annotations

import os
import sys

os.environ.setdefault("JAX_HARNESS_THREADS", "all")  # the harness leaves JAX's platform and threads alone
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")  # JAX shares the GPU with torch

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

from timing import HelpFormatter, add_output_file, in_turn, machine, machine_header, wrote  # noqa: E402

ACCEL_BATCHES = (512, 8192, 131072)
TRAIN_BATCHES = (512, 8192)
ROLLOUT = (1024, 100, 0.005)  # trajectories, steps, step (s)
# the compiled candidates' calls (each batch size is its own compilation: a minute or less each)
COMPILED = {"double_pendulum": ("accel 512", "accel 131072", "train step 512", "train step 8192", "rollout"),
            "robot_arm_film_lnn": ("accel 131072", "train step 512", "train step 8192")}


def gpu_info() -> dict:
    import torch

    p = torch.cuda.get_device_properties(0)
    return {"gpu": p.name, "memory_gib": round(p.total_memory / 2**30, 1), "multiprocessors": p.multi_processor_count,
            "cuda": torch.version.cuda}


def synced(fn, device):
    """``fn`` followed by a device synchronisation on a GPU (``fn`` itself elsewhere)."""
    import torch

    def call():
        fn()
        torch.cuda.synchronize()

    return call if device.type == "cuda" else fn


def states(system, n: int, seed: int):
    """``n`` sampled states and parameters of a scene (float32), with random torques for an actuated one."""
    import numpy as np
    import torch

    rng = np.random.default_rng(seed)
    q, qd = (torch.tensor(x, dtype=torch.float32) for x in system.sample_state(rng, n))
    params = torch.tensor(system.sample_params(rng, n), dtype=torch.float32)
    tau = (torch.tensor(rng.uniform(-2.0, 2.0, (n, system.num_inputs)), dtype=torch.float32)
           if system.num_inputs else None)
    return q, qd, params, tau


def torch_calls(name: str, device, compiled: bool, only=None) -> dict:
    """``{call: fn}`` of the shipped model ``name`` on ``device`` (``only``: these calls alone)."""
    import torch

    from lnn_torch import load_pretrained
    from lnn_torch.perf import adamw
    from lnn_torch.training import TrainingPass

    module = load_pretrained(name).to(device)
    module.train()
    model, system = module.model, module.system
    if compiled:
        model.compile_dynamics(True)
    calls = {}
    for b in ACCEL_BATCHES:
        q, qd, params, tau = (None if x is None else x.to(device) for x in states(system, b, 0))

        def accel(q=q, qd=qd, params=params, tau=tau):
            with torch.no_grad():
                model.acceleration(q, qd, params, tau, check=False)

        calls[f"accel {b}"] = accel
    opt = adamw(module.parameters(), lr=1e-7)
    pass_fn = TrainingPass(module.training_terms, compiled).function(0, device)
    chunk = 8 if system.num_inputs == 0 else 1
    for b in TRAIN_BATCHES:
        q, qd, params, tau = states(system, b, 1)
        with torch.no_grad():
            qdd = system.acceleration(q.double(), qd.double(), params.double(),
                                      *(() if tau is None else (tau.double(),))).float()
        batch = {"q": q, "qd": qd, "qdd": qdd, "params": params}
        if tau is not None:
            batch["tau"] = tau
        batch = {k: v.reshape(b // chunk, chunk, -1).to(device) for k, v in batch.items()}

        def step(batch=batch):
            loss, _ = module.batch_loss(batch, pass_fn)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(module.parameters(), 1.0)
            opt.step()
            opt.zero_grad(set_to_none=True)

        calls[f"train step {b}"] = step
    n, steps, dt = ROLLOUT
    q, qd, params, tau = (None if x is None else x.to(device) for x in states(system, n, 2))
    held = None if tau is None else tau[:, None].expand(-1, steps, -1)

    def rollout():
        with torch.no_grad():
            model.rollout(q, qd, params, dt, steps, tau=held)

    calls["rollout"] = rollout
    model.eval()
    out = {k: synced(v, torch.device(device)) for k, v in calls.items() if only is None or k in only}
    for k, fn in out.items():  # after a failed compilation the library runs the call eagerly: say so
        fn.fell_back = (lambda pass_fn=pass_fn: bool(getattr(pass_fn, "failed", False))) if k.startswith("train") \
            else (lambda: getattr(model, "_compile", None) == "failed")
    return out


def original_calls() -> tuple[dict, object]:
    """The released original's accelerations and training step on JAX's default device (the GPU)."""
    import jax_original as harness

    from lnn_torch.systems import get_system

    m = harness.load("float32")
    step = harness.train_step_fn("float32")
    system = get_system("double_pendulum")
    calls = {}
    for b in ACCEL_BATCHES:
        q, qd, params, _ = states(system, b, 0)
        dq, dqd, dp = m.to_device(q.numpy(), qd.numpy(), params.numpy())
        calls[f"accel {b}"] = lambda dq=dq, dqd=dqd, dp=dp: m.accel_device(dq, dqd, dp).block_until_ready()
    for b in TRAIN_BATCHES:  # its step takes B points of one trajectory: the parameters of the first state
        q, qd, params, _ = states(system, b, 1)
        params = params[:1].expand(b, -1)
        qdd = system.acceleration(q.double(), qd.double(), params.double()).float()
        x, y = step.to_device(*step.normalise(q.numpy(), qd.numpy(), qdd.numpy(), params[0].numpy()))
        calls[f"train step {b}"] = lambda x=x, y=y: step.step_normalised(x, y)
    import jax

    return calls, jax.devices()[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    add_output_file(ap, "results/gpu/benchmark_gpu.md", "the Markdown report (the JSON beside it)")
    ap.add_argument("--rounds", type=int, default=5, help="rounds, each timing every candidate in turn")
    ap.add_argument("--calls", type=int, default=5, help="timed calls per candidate, call and round")
    ap.add_argument("--no-original", action="store_true", help="without the JAX original")
    ap.add_argument("--no-compile", action="store_true", help="without the compiled candidates")
    ap.add_argument("--budget", type=float, default=600.0,
                    help="seconds: no further round starts after this (the rounds done are reported)")
    ap.add_argument("--no-cpu", action="store_true", help="without the CPU candidates")
    ap.add_argument("--cuda-graphs", action="store_true",
                    help="compile with mode='reduce-overhead' (CUDA graphs) instead of the library's compile_fn; "
                         "no compiled rollout")
    ap.add_argument("--profile", action="store_true",
                    help="instead of timing: the kernels each GPU call launches and their busy time (torch.profiler)")
    ap.add_argument("--device", default="cuda", help="the accelerator's torch device (cpu: a dry run)")
    args = ap.parse_args()
    import torch

    from lnn_torch.perf import median_seconds

    device = torch.device(args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise SystemExit("no CUDA device: this benchmark times the GPU path")
    if args.cuda_graphs:
        use_cuda_graphs()
    candidates = {}
    start = time.perf_counter()
    for name, label in (("double_pendulum", "double pendulum"), ("robot_arm_film_lnn", "arm")):
        candidates[(label, "lnn_torch", f"{device.type} eager")] = torch_calls(name, device, False)
        if not args.no_compile:
            only = [c for c in COMPILED[name] if not (args.cuda_graphs and c == "rollout")]
            path = "compiled, CUDA graphs" if args.cuda_graphs else "compiled"
            candidates[(label, "lnn_torch", f"{device.type} {path}")] = torch_calls(name, device, True, only)
        if not args.no_cpu:
            candidates[(label, "lnn_torch", f"cpu eager, {torch.get_num_threads()} threads")] = torch_calls(
                name, "cpu", False)
    jax_device = None
    if not args.no_original and not args.profile:
        calls, jax_device = original_calls()
        candidates[("double pendulum", "JAX original (released)", "jit")] = calls
    flat = {(*key, call): fn for key, calls in candidates.items() for call, fn in calls.items()}
    fell_back = {}  # a compiled call whose compilation failed runs eagerly (the library warns): reported so
    for key, fn in flat.items():  # warm-up: compilation (torch and XLA), autotuning, caches
        t = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            for _ in range(3):
                fn()
        if getattr(fn, "fell_back", lambda: False)():
            fell_back[key] = next((str(w.message) for w in caught if "failed" in str(w.message)), "an earlier call's")
            print(f"{' / '.join(key)}: compilation failed, eager: {fell_back[key]}", flush=True)
        print(f"warm-up {' / '.join(key)}: {time.perf_counter() - t:.1f} s", flush=True)
    warm = time.perf_counter() - start
    print(f"set-up, warm-up and compilation: {warm:.0f} s", flush=True)
    if args.profile:
        for key, fn in flat.items():
            if key[2].startswith(device.type):
                print(" / ".join(key) + ": " + kernels(fn, device), flush=True)
        return
    times = {key: [] for key in flat}

    def after(r: int) -> bool:  # the report is rewritten after each round; no round starts past the budget
        print(f"round {r}/{args.rounds}", flush=True)
        save(args, times, warm, jax_device, device, r, fell_back)
        over = time.perf_counter() - start > args.budget
        if over and r < args.rounds:
            print(f"stopped after round {r}: over the budget of {args.budget:.0f} s", flush=True)
        return over

    in_turn(flat, args.rounds, lambda fn: median_seconds(fn, args.calls, warmup=1), after, values=times)
    print(Path(args.output).read_text())
    wrote([Path(args.output), Path(args.output).with_suffix(".json")])


def use_cuda_graphs() -> None:
    """The library's compiled calls through ``torch.compile(mode="reduce-overhead")`` (CUDA graphs)."""
    import torch

    import lnn_torch.perf as perf
    from lnn_torch.networks import compiled

    def compile_fn(fn, device="cpu"):
        return torch.compile(fn, dynamic=False, mode="reduce-overhead")

    perf.compile_fn = compiled.compile_fn = compile_fn


def kernels(fn, device) -> str:
    """What one call of ``fn`` launches on the device (the mean of 5 profiled calls): kernels and copies,
    the device's busy time, and the wall time."""
    import torch
    from torch.profiler import ProfilerActivity, profile

    fn()
    calls = 5
    with profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
        t = time.perf_counter()
        for _ in range(calls):
            fn()
        wall = (time.perf_counter() - t) / calls
    events = [e for e in prof.key_averages() if e.device_type == torch.autograd.DeviceType.CUDA]
    launches = sum(e.count for e in events) / calls
    busy = sum(e.self_device_time_total for e in events) / calls / 1e3
    return f"{launches:.0f} kernels and copies per call, device busy {busy:.3f} ms, wall {1e3 * wall:.3f} ms (profiled)"


def save(args, times: dict, warm: float, jax_device, device, rounds: int, fell_back: dict) -> None:
    rows = [{"scene": k[0], "model": k[1], "path": k[2], "call": k[3], "ms": 1e3 * statistics.median(v),
             "ms per round": [1e3 * x for x in v], "fell_back_to_eager": fell_back.get(k)} for k, v in times.items()]
    head = {"machine": machine(), "gpu": gpu_info() if device.type == "cuda" else None,
            "jax_device": str(jax_device), "rounds": rounds, "calls": args.calls,
            "command": " ".join(["python", *sys.argv]), "warm_up_s": warm}
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps({"header": head, "rows": rows}, indent=1))
    out.write_text(report(head, rows))


def report(head: dict, rows: list) -> str:
    """The Markdown table: one line per scene and call, one column per model and path (median ms)."""
    from lnn_torch.evaluation import table_row

    columns = list(dict.fromkeys((r["model"], r["path"]) for r in rows))
    lines = ["# The GPU path", "", f"`{head['command']}`", ""]
    if head["gpu"]:
        g = head["gpu"]
        lines.append(f"GPU: {g['gpu']} ({g['memory_gib']} GiB, {g['multiprocessors']} multiprocessors, CUDA "
                     f"{g['cuda']}); JAX device: {head['jax_device']}.")
    lines += [f"Machine: {machine_header(head['machine'])}.", "",
              f"Median ms per call over {head['rounds']} rounds (each: the median of {head['calls']} calls after "
              "one untimed call, synchronised), float32, every candidate timed in turn in one process.", ""]
    for scene in dict.fromkeys(r["scene"] for r in rows):
        cols = [c for c in columns if any(r["scene"] == scene and (r["model"], r["path"]) == c for r in rows)]
        lines += [f"## {scene}", "", table_row(["call", *(f"{m}, {p}" for m, p in cols)]),
                  table_row(["---", *["---:"] * len(cols)])]  # the times right-aligned
        for call in dict.fromkeys(r["call"] for r in rows if r["scene"] == scene):
            cells = []
            for m, p in cols:
                hit = [r for r in rows if (r["scene"], r["model"], r["path"], r["call"]) == (scene, m, p, call)]
                cells.append("" if not hit else f"{hit[0]['ms']:.3g}" + (" (fell back to eager)"
                                                                      if hit[0].get("fell_back_to_eager") else ""))
            lines.append(table_row([call, *cells]))
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
