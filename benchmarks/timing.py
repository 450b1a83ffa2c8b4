"""What every benchmark shares: timing candidates in turn over rounds, the machine header, and the
command-line conventions. The one helper module of ``benchmarks/`` (with ``jax_original.py``, the wrapper
of the JAX original that some benchmarks time).

* Timing in turn: ``in_turn(candidates, rounds, measure)`` measures every candidate once per round, in
  order, so that a load on the machine that changes over minutes (timings on a shared machine drift by
  tens of percent) falls on all candidates alike; ``median_ratio`` of two candidates' per-round values
  is then the comparable quantity, and ``statistics.median`` of one candidate's its typical time.
  ``measure`` is what one round does with one candidate: ``median_ms`` (a median of calls after
  warm-up), ``run_seconds`` (runs of many calls in a row, for calls of microseconds) or
  ``lnn_torch.perf.median_seconds(fn, 1, warmup=1)`` (one call after an untimed one).
* The machine header: ``machine()`` (a dict for the JSON results: CPU, cores, threads, the versions of
  Python, torch, Lightning, MuJoCo and jax, the inductor cache's state, the load average) and
  ``machine_header(machine())`` (one line for the reports); ``CpuShare`` measures the share of a core the timed
  code had (1: a core to itself).
* ``ROOT``, ``HelpFormatter``, ``add_output_dir``, ``add_output_file``, ``wrote``: the command-line
  conventions of the scripts and the package's commands. A folder of results is ``--output-dir`` / ``-o``,
  a single file ``--output`` / ``-o`` (an old spelling keeps working, hidden, with one line on stderr); a
  benchmark ends by printing every path it wrote (``wrote PATH, PATH, ...``); the help states each
  default once. The scripts' helper (``scripts/_common.py``) holds the same conventions: each folder
  imports only its own helper (``tests/test_scripts_conventions.py`` holds the two alike).

Not a benchmark: the others import it (``python benchmarks/X.py`` puts this folder on ``sys.path``).
"""

from __future__ import annotations

import gc
import statistics
import time
from collections.abc import Callable
from pathlib import Path

from lnn_torch.cli import HelpFormatter, add_output_dir, add_output_file, wrote
from lnn_torch.perf import machine, machine_header, median_seconds

ROOT = Path(__file__).resolve().parents[1]

__all__ = ["ROOT", "HelpFormatter", "add_output_dir", "add_output_file", "wrote", "median_ms", "run_seconds",
           "calls_per_run", "in_turn", "median_ratio", "CpuShare", "machine", "machine_header"]


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


