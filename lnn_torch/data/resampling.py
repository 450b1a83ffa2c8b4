"""A recording's time stamps checked (increasing, gaps up to ``max_gap``) and reported, and its columns
resampled onto a uniform grid by linear interpolation."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError

MAX_GAP_INTERVALS = 25  # the default max_gap, in median sampling intervals


def checked_time(path: Path, t: np.ndarray, max_gap: float | None, lines: np.ndarray | None = None) -> dict:
    """Raise for a time that does not increase, naming the line of the file (``lines``: each sample's; default:
    the header on line 1, one sample a line); else the recording's timing: samples, duration, median, smallest
    and largest interval, the gaps above twice the median (count, largest, their total), which resampling
    interpolates across, and those beyond ``max_gap`` (default ``MAX_GAP_INTERVALS`` median intervals;
    ``long_gaps``: ``[t before, t after, line]`` each), which the data in use must not cross (the importer's
    ``_gaps_in_use``)."""
    if lines is None:
        lines = np.arange(len(t)) + 2
    steps = np.diff(t)
    bad = np.nonzero(steps <= 0)[0]
    if bad.size:
        i = int(bad[0])
        what = "repeats" if steps[i] == 0 else "decreases"
        raise InputError(f"{path}: line {lines[i + 1]}: time {what} (t = {t[i + 1]:.6g} s after {t[i]:.6g} s)")
    median = float(np.median(steps))
    limit = max_gap if max_gap is not None else MAX_GAP_INTERVALS * median
    long = steps[steps > 2 * median]
    return {"samples": len(t), "duration_s": float(t[-1] - t[0]), "median_interval_s": median,
            "min_interval_s": float(steps.min()), "max_interval_s": float(steps.max()),
            "gaps": int(long.size), "largest_gap_s": float(long.max()) if long.size else 0.0,
            "gap_seconds": float(long.sum()), "max_gap_s": float(limit),
            "long_gaps": [[float(t[i]), float(t[i + 1]), int(lines[i + 1])] for i in np.nonzero(steps > limit)[0]]}


def resampling_report(provenance: dict) -> list[str]:
    """One line per recording of what the import did to its timing (from the file's ``provenance``)."""
    lines = []
    for src in provenance.get("sources", []):
        timing = src.get("timing")
        if not timing:
            continue
        long = timing.get("long_gaps") or []
        gaps = (f"{timing['gaps']} gap{'s' if timing['gaps'] > 1 else ''} over twice the median interval (largest "
                f"{1e3 * timing['largest_gap_s']:.3g} ms, {1e3 * timing['gap_seconds']:.3g} ms in all) interpolated "
                "across" + (f", but for {len(long)} beyond max_gap ({1e3 * timing['max_gap_s']:.3g} ms), which no "
                            "window in use crosses" if long else "") if timing["gaps"]
                else "no gaps")
        lines.append(f"{src['file']}: {timing['samples']} samples over {timing['duration_s']:.4g} s, intervals "
                     f"{1e3 * timing['min_interval_s']:.3g}-{1e3 * timing['max_interval_s']:.3g} ms (median "
                     f"{1e3 * timing['median_interval_s']:.3g} ms); {gaps}; resampled to "
                     f"{src['resampled_points']} points")
    return lines


def resample(raw: np.ndarray, dt: float) -> np.ndarray:
    """A table ``(n, 1 + k)`` whose first column is time (s) resampled onto ``t_0 + j dt`` from its first
    stamp to its last: its other ``k`` columns linearly interpolated, ``(m, k)``."""
    t = raw[:, 0]
    grid = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1)
    return np.stack([np.interp(grid, t, raw[:, j]) for j in range(1, raw.shape[1])], -1)
