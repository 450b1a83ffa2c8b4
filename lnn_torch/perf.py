"""CPU performance settings for small-network workloads (the ``lnn-torch`` command applies them).

Lagrangian networks on a CPU run many small tensor operations on arrays of a few hundred KB. Two
process-wide defaults cost more time than the arithmetic there:

* glibc's allocator returns freed blocks above its mmap/trim thresholds to the operating system,
  so the next allocation of the same size page-faults it back in. Raising both thresholds keeps
  those blocks in the heap (measured in ``results/README.md``).
* tanh/softplus tails produce denormal floats, which slow CPU arithmetic by up to 30x.

``configure_cpu`` applies both; on platforms without glibc the allocator part is a no-op. They are
process-wide, so the library sets them only where a process is its own: the ``lnn-torch`` command at
its entry point (``lnn_torch.cli.main``) and each command that takes ``--threads``, and a training run
when it starts (``LNNModule.on_fit_start``). Building or loading a model changes nothing; a Python user
who wants them calls ``configure_cpu()`` or ``apply_cpu_defaults()`` (once per process;
``LNN_TORCH_CPU_TUNING=0`` opts out).
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import importlib.metadata
import os
import platform
import statistics
import sys
import tempfile
import time
import warnings

import torch

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_ALLOCATOR_TUNED = False


def tune_allocator(threshold_bytes: int = 1 << 30) -> bool:
    """Raise glibc's mmap and trim thresholds (Linux only). Returns True if applied."""
    global _ALLOCATOR_TUNED
    if _ALLOCATOR_TUNED:
        return True
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    # glibc caps M_MMAP_THRESHOLD at HEAP_MAX (32 MiB on 64-bit); mallopt returns 1 on success
    mmap_ok = mallopt(_M_MMAP_THRESHOLD, min(threshold_bytes, 32 << 20)) == 1
    trim_ok = mallopt(_M_TRIM_THRESHOLD, threshold_bytes) == 1
    _ALLOCATOR_TUNED = mmap_ok and trim_ok
    return _ALLOCATOR_TUNED


def configure_cpu(num_threads: int | None = None) -> None:
    """Flush denormals, tune the allocator and (if given) set the number of torch threads."""
    torch.set_flush_denormal(True)
    tune_allocator()
    if num_threads:
        torch.set_num_threads(int(num_threads))


_DEFAULTS_APPLIED = False


def apply_cpu_defaults() -> bool:
    """The library's CPU defaults, once per process, for an entry point that owns its process (a
    script, a service): ``configure_cpu()`` without changing the thread count, i.e. denormal floats
    flushed to zero on the calling thread (values below 1.2e-38 in float32 become 0; torch's
    ``set_flush_denormal``) and glibc's allocator thresholds raised (freed blocks up to 32 MiB stay in
    the heap instead of going back to the OS). Building a model does not call it (it would change
    process-wide state behind its caller). Set the environment variable ``LNN_TORCH_CPU_TUNING=0`` to
    leave the process untouched. Returns whether it applied them now."""
    global _DEFAULTS_APPLIED
    if _DEFAULTS_APPLIED or os.environ.get("LNN_TORCH_CPU_TUNING", "").strip() == "0":
        return False
    _DEFAULTS_APPLIED = True
    configure_cpu()
    return True


def median_seconds(fn, repeats: int = 7, warmup: int = 2) -> float:
    """Median wall time of ``fn()`` over ``repeats`` calls after ``warmup`` calls, in seconds."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


# A rollout compiles its integrator step (``DynamicsModel.compile_dynamics("auto")``, the default)
# when it makes at least this many acceleration calls (RK4: 4 per step). Measured break-even
# (``benchmarks/benchmark_compile_rule.py``, ``results/compile_rule.md``): compilation costs about as much
# as the eager calls it saves after roughly this many calls on a cold cache.
AUTO_COMPILE_CALLS = 20_000


def compile_pays(calls: int) -> bool:
    """Whether ``calls`` acceleration calls repay a compilation: ``calls >= AUTO_COMPILE_CALLS``, unless
    the environment variable ``LNN_TORCH_COMPILE`` is ``0`` (never compile automatically)."""
    if os.environ.get("LNN_TORCH_COMPILE", "").strip() == "0":
        return False
    return calls >= AUTO_COMPILE_CALLS


# Training compiles its pass (``LNNModule(compile="auto")``, the default) when the run is planned for at
# least this many optimiser steps. Measured break-even (``benchmarks/benchmark_compile_rule.py``,
# ``results/compile_rule.md``): the compilation of the training pass (forward and backward) costs as
# much as the eager steps it saves after 4,500-5,200 steps on a cold cache, 300-600 on a warm one.
AUTO_COMPILE_TRAIN_STEPS = 5_000


# a run limited in time (``--trainer.max_time``) to less than this many seconds is not compiled: the compilation
# itself (about 30 s on two cores, a cold cache) would take a share of it that its faster steps cannot repay
AUTO_COMPILE_MIN_SECONDS = 300.0


def compile_pays_training(steps: float, seconds: float | None = None) -> bool:
    """Whether a training run of ``steps`` optimiser steps repays compiling its pass: ``steps >=
    AUTO_COMPILE_TRAIN_STEPS`` (a run of unknown length does not) and, where it is limited in time to
    ``seconds``, at least ``AUTO_COMPILE_MIN_SECONDS``; never where ``LNN_TORCH_COMPILE`` is ``0``."""
    if os.environ.get("LNN_TORCH_COMPILE", "").strip() == "0":
        return False
    if seconds is not None and seconds < AUTO_COMPILE_MIN_SECONDS:
        return False
    return steps is not None and steps == steps and steps != float("inf") and steps >= AUTO_COMPILE_TRAIN_STEPS


# dynamo's cache entries per compiled code object that ``compile_fn`` allows at least (see there)
RECOMPILE_LIMIT = 64


def compile_fn(fn, device: torch.device | str = "cpu"):
    """``torch.compile(fn)`` as lnn_torch compiles its dynamics: static shapes (one graph per batch
    shape, dtype and grad mode) and, on the CPU, inductor's C++ wrapper (the generated code calls
    its kernels and matrix products from C++, not Python; ``benchmarks/compare_compile.py`` times
    both wrappers against eager: ``results/compare_compile.md``)."""
    # inductor's own call of a deprecated torch helper (torch 2.13) warns on every compilation
    warnings.filterwarnings("ignore", category=FutureWarning, module=r"torch\._inductor")
    # every compiled model of a class shares its methods' code: each model (and batch shape) takes one
    # of dynamo's per-code cache entries, and past the limit (8 by default) calls run eagerly behind
    # every cached guard (slower than plain eager). Allow several models per process.
    import torch._dynamo.config as dynamo_config

    dynamo_config.recompile_limit = max(dynamo_config.recompile_limit, RECOMPILE_LIMIT)
    options = {"cpp_wrapper": True} if torch.device(device).type == "cpu" else None
    return torch.compile(fn, dynamic=False, options=options)


def warn_compile_failure(what: str, err: Exception, then: str = "continuing eagerly", stacklevel: int = 2) -> None:
    """The warning of a failed compilation or compiled call: ``compiled {what} failed (Error: its first
    line); {then}``."""
    first = str(err).splitlines()[0][:200] if str(err) else ""
    warnings.warn(f"compiled {what} failed ({type(err).__name__}: {first}); {then}", RuntimeWarning,
                  stacklevel=stacklevel + 1)


class CompiledFallback:
    """``fn`` through ``compile_fn`` with the eager fallback: the library's one compile-with-fallback
    (the model's compiled dynamics, ``DynamicsModel.compile_dynamics``, and the compiled training pass,
    ``LNNModule(compile=...)``).

    ``fn`` is compiled on the first call (``compiler(fn, device)``, default ``compile_fn``). If compiling
    or a compiled call raises anything but ``passthrough`` (the caller's own errors, not compilation
    failures), ``on_failure(err)`` is called once (its owner warns, ``warn_compile_failure``, and
    continues eagerly) and this call and every later one run ``fn`` eagerly; with ``eager=False`` they
    return None instead, for a caller that redoes more than this one call eagerly.
    """

    def __init__(self, fn, device: torch.device | str = "cpu", on_failure=None, passthrough: tuple = (),
                 eager: bool = True, compiler=None) -> None:
        self.fn, self.device, self.on_failure = fn, device, on_failure
        self.passthrough, self.eager = tuple(passthrough), eager
        self.compiler = compiler or compile_fn
        self.compiled = None  # built on the first call
        self.failed = False

    def __call__(self, *args):
        if not self.failed:
            try:
                if self.compiled is None:
                    self.compiled = self.compiler(self.fn, self.device)
                return self.compiled(*args)
            except self.passthrough:
                raise
            except Exception as err:  # noqa: BLE001 - any failure of the compiler or compiled code
                self.fail(err)
        return self.fn(*args) if self.eager else None

    def fail(self, err: Exception) -> None:
        """Run eagerly from now on; ``on_failure(err)`` the first time."""
        if not self.failed:
            self.failed, self.compiled = True, None
            if self.on_failure is not None:
                self.on_failure(err)


def adamw(parameters, fused: bool = True, **kwargs) -> torch.optim.AdamW:
    """AdamW with the fused kernel where torch has one for the device (CPU and GPU), else the loop.
    The fused kernel is faster than the per-parameter loop for these small networks; ``fused`` False: the
    loop (mixed precision: Lightning cannot clip the gradients a fused optimiser unscales itself)."""
    parameters = list(parameters)
    if not fused:
        return torch.optim.AdamW(parameters, **kwargs)
    try:
        return torch.optim.AdamW(parameters, fused=True, **kwargs)
    except (RuntimeError, TypeError, ValueError):
        return torch.optim.AdamW(parameters, **kwargs)


@contextlib.contextmanager
def quiet_compilation():
    """Warnings and inductor's log lines the user cannot act on, silenced while AOTInductor compiles
    (e.g. "aten.linalg_cholesky_ex.default is missing a c-shim implementation, using proxy executor as
    fallback": correct, a slower call of that one operator)."""
    import logging

    log = logging.getLogger("torch._inductor.ir")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        log.setLevel(level)


def quiet_compile_logs() -> None:
    """Silence inductor's log lines that the user cannot act on, for the package's commands (process-wide,
    as ``lightning_cli.quiet_third_parties`` does for training): a compiled operator without a native C++
    kernel, e.g. ``aten.linalg_cholesky_ex``, runs through a fallback ("... is missing a c-shim
    implementation, using proxy executor as fallback"): correct, nothing to act on."""
    import logging

    logging.getLogger("torch._inductor.ir").setLevel(logging.ERROR)


# ---------------------------------------------------------------------------- the machine a timing ran on
def _version(package: str) -> str | None:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            return next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        return platform.processor() or platform.machine()


def load_average() -> list[float] | None:
    """The load average over 1, 5 and 15 minutes (None where the system has none)."""
    return [round(x, 2) for x in os.getloadavg()] if hasattr(os, "getloadavg") else None


def inductor_cache() -> dict:
    """The folder of inductor's on-disk cache of compiled kernels (``TORCHINDUCTOR_CACHE_DIR``, else its
    default) and its state: ``absent``, ``empty`` or ``N entries`` (top-level). A compilation on a
    cold cache costs several times one on a warm cache."""
    path = os.environ.get("TORCHINDUCTOR_CACHE_DIR") or os.path.join(
        tempfile.gettempdir(), "torchinductor_" + "".join(c if c.isalnum() else "_" for c in _user()))
    try:
        entries = len(os.listdir(path))
    except FileNotFoundError:
        return {"path": path, "state": "absent"}
    except OSError:
        return {"path": path, "state": "unreadable"}
    return {"path": path, "state": f"{entries} entries" if entries else "empty"}


def _user() -> str:
    try:
        import getpass

        return getpass.getuser()
    except Exception:  # noqa: BLE001 - no user name (a container without one): inductor falls back alike
        return "unknown"


def machine() -> dict:
    """The machine and the software a benchmark ran on, for its JSON result: CPU model, cores, torch
    threads and ``OMP_NUM_THREADS``, the versions of Python, torch, Lightning, MuJoCo and jax (None where
    not installed), the inductor cache (``inductor_cache``) and the load average now."""
    torch = sys.modules.get("torch")
    return {"cpu": _cpu_model(), "machine": platform.machine(), "cores": os.cpu_count(),
            "torch_threads": torch.get_num_threads() if torch is not None else None,
            "omp_num_threads": os.environ.get("OMP_NUM_THREADS"), "python": platform.python_version(),
            "torch": _version("torch"), "lightning": _version("lightning"), "mujoco": _version("mujoco"),
            "jax": _version("jax"), "inductor_cache": inductor_cache(), "load_average": load_average()}


def machine_header(m: dict | None = None) -> str:
    """One line for a report: ``machine()``'s CPU, threads, versions, cache and load."""
    m = machine() if m is None else m
    versions = ", ".join(f"{name} {m[key]}" for name, key in (("Python", "python"), ("torch", "torch"),
                                                               ("lightning", "lightning"), ("mujoco", "mujoco"),
                                                               ("jax", "jax")) if m.get(key))
    cache = m.get("inductor_cache") or {}
    load = ", ".join(str(x) for x in m["load_average"]) if m.get("load_average") else "n/a"
    return (f"{m['cpu']} ({m['cores']} cores), torch threads {m['torch_threads']}, OMP_NUM_THREADS="
            f"{m['omp_num_threads']}; {versions}; inductor cache {cache.get('path')} ({cache.get('state')}); "
            f"load average (1, 5, 15 min) {load}")
