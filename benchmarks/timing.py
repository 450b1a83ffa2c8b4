"""What every benchmark shares: timing candidates in turn over rounds, the machine header, and the
scripts' command-line conventions.

* Timing in turn: ``in_turn(candidates, rounds, measure)`` measures every candidate once per round, in
  order, so that a load on the machine that changes over minutes (timings on a shared machine drift by
  tens of percent) falls on all candidates alike; ``median_ratio`` of two candidates' per-round values
  is then the comparable quantity, and ``statistics.median`` of one candidate's its typical time.
  ``measure`` is what one round does with one candidate: ``median_ms`` (a median of calls after
  warm-up), ``run_seconds`` (runs of many calls in a row, for calls of microseconds) or
  ``lnn_torch.perf.median_seconds(fn, 1, warmup=1)`` (one call after an untimed one).
* The machine header: ``machine()`` (a dict for the JSON results: CPU, cores, threads, the versions of
  Python, torch, Lightning, MuJoCo and jax, the inductor cache's state, the load average) and
  ``header(machine())`` (one line for the reports); ``CpuShare`` measures the share of a core the timed
  code had (1: a core to itself).
* ``ROOT``, ``HelpFormatter``, ``add_output_dir``, ``add_output_file``, ``wrote``: the conventions of
  ``scripts/_cli.py`` (one module for the scripts and the benchmarks; imported here so that a benchmark
  imports one module).

Not a benchmark: the others import it (``python benchmarks/X.py`` puts this folder on ``sys.path``).
"""

from __future__ import annotations

import gc
import importlib.metadata
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from lnn_torch.perf import median_seconds

_SCRIPTS = str(Path(__file__).resolve().parents[1] / "scripts")
if _SCRIPTS not in sys.path:
    sys.path.append(_SCRIPTS)

from _cli import ROOT, HelpFormatter, add_output_dir, add_output_file, wrote  # noqa: E402

__all__ = ["ROOT", "HelpFormatter", "add_output_dir", "add_output_file", "wrote", "median_ms", "run_seconds",
           "calls_per_run", "in_turn", "median_ratio", "CpuShare", "machine", "header", "load_average"]


# ---------------------------------------------------------------------------- one candidate
def median_ms(fn: Callable[[], object], repeats: int, warmup: int = 5) -> float:
    """The median of ``repeats`` timed calls of ``fn`` after ``warmup`` untimed ones, in ms; garbage is
    collected first (a compilation leaves much of it: collected before the timings, not during them)."""
    gc.collect()
    return 1e3 * median_seconds(fn, repeats, warmup)


def run_seconds(fn: Callable[[], object], calls: int, repeats: int, warmup_calls: int = 0) -> float:
    """Seconds per call: the median over ``repeats`` runs of ``calls`` calls of ``fn`` in a row (a run's
    time divided by ``calls``), after ``warmup_calls`` untimed calls. For calls too short to time alone."""
    for _ in range(warmup_calls):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        times.append((time.perf_counter() - start) / calls)
    return statistics.median(times)


def calls_per_run(fn: Callable[[], object], seconds: float = 0.02) -> int:
    """How many calls of ``fn`` in a row take about ``seconds`` (at least one), from one timed call after
    an untimed one."""
    fn()
    start = time.perf_counter()
    fn()
    return max(1, int(seconds / max(time.perf_counter() - start, 1e-7)))


# ---------------------------------------------------------------------------- candidates in turn
def in_turn(candidates: dict, rounds: int, measure: Callable[[Callable[[], object]], object],
            progress: Callable[[int], object] | None = None, values: dict | None = None) -> dict:
    """``{name: [measure(fn) of each round]}`` for ``candidates`` ``{name: fn}``: each of ``rounds`` rounds
    measures every candidate once, in the dict's order. ``progress(r)`` is called after round ``r``
    (1-based), e.g. to print it; when it returns True no further round starts (a time budget).
    ``values``: the dict to fill (``progress`` may read the rounds so far from it)."""
    values = {name: [] for name in candidates} if values is None else values
    for r in range(rounds):
        for name, fn in candidates.items():
            values[name].append(measure(fn))
        if progress is not None and progress(r + 1) is True:
            break
    return values


def median_ratio(values, reference) -> float:
    """The median over rounds of the per-round ratio ``values[r] / reference[r]`` (two candidates'
    values from the same ``in_turn``)."""
    return statistics.median(a / b for a, b in zip(values, reference, strict=True))


class CpuShare:
    """The process's CPU time over the wall time of what ran inside ``with share:`` blocks (summed over
    blocks): 1 for one busy thread that had a core to itself, less when other processes took turns on
    it (the timings are then that much noisier), more when the code ran several threads."""

    def __init__(self) -> None:
        self.cpu_seconds = self.seconds = 0.0

    def __enter__(self) -> CpuShare:
        self._cpu, self._wall = time.process_time(), time.perf_counter()
        return self

    def __exit__(self, *exc) -> None:
        self.cpu_seconds += time.process_time() - self._cpu
        self.seconds += time.perf_counter() - self._wall

    @property
    def share(self) -> float:
        return self.cpu_seconds / max(self.seconds, 1e-12)


# ---------------------------------------------------------------------------- the machine
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


def header(m: dict | None = None) -> str:
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
