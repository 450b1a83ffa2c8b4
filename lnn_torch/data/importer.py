"""Import measured recordings (one CSV per recording) into the project's HDF5 schema.

Each recording is a text table (``.csv``, ``.tsv``, ``.txt`` or ``.dat``, or any of them gzip-compressed,
``.csv.gz``), named by its file name without those extensions (``exp_2024.05.01_a.csv``:
``exp_2024.05.01_a``): a header row naming the columns (after comment lines starting with ``#`` and
blank lines; a UTF-8 byte-order mark, as Excel writes, is dropped), then one row per sample. The
delimiter is the header's: ``;`` if it holds one, else a tab if it holds one, else ``,`` (or
``delimiter``); with a ``;`` or tab delimiter, numbers may have decimal commas (``decimal``).

Each recording is resampled onto a uniform grid: every column (coordinates, velocities, inputs) is
linearly interpolated at ``t_0 + k dt`` from the first time stamp to the last (``dt`` defaults to
the median sampling interval, rounded to 0.1 ms; recordings whose median intervals differ by more
than 2 % and round to different intervals need ``dt`` set). Irregular stamps and gaps are repaired
this way and reported (``resampling_report``: the intervals, the gaps above twice the median, the
largest); only a gap longer than ``max_gap`` (default 25 median intervals) is refused, with the number
and size of such gaps. Units are converted to SI (time stamps in ``time_units`` to s; degrees to radians for angle
coordinates and their velocities; lengths in ``length_units`` to m for the other coordinates and
their velocities; motor currents times known drive gains to N m). Recordings keep their own lengths:
the file pads them with NaN and records ``lengths``.

The split is by recording (named by the user, or seeded fractions) or by time window inside a
recording (``"run[0.5:10.5]"``: its samples 0.5 s <= t - t_0 < 10.5 s, seconds from the recording's
first sample ``t_0``, whatever its time column's values): each window is an entry of its own, stored
with up to ``window_context`` s of the recording on each side for the derivative filters and its own
span in ``windows`` (the DataModule cuts each entry to its window after estimating derivatives).
Windows of different splits may not overlap.

Known parameters per recording (``parameters``: e.g. the payload a robot arm carried in each, or a
named tool) are stored with each entry, and a robot arm's description (``robot``) with the scene:
models condition on the parameters as on a simulated scene's, a grey box reads the description.

Refused, with one line naming the file and the line of the file (and the column), before anything
is written: a missing column or a named column that the header holds twice, a time that does not
increase (or repeats), an empty, unreadable, NaN or Inf value, a gap longer than ``max_gap``, an
entry (recording or window) of fewer than 16 samples after resampling, an existing output (unless
``overwrite``). The file records the provenance: source names, SHA-256 checksums, the resampling
report and every setting.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from .._version import __version__
from ..errors import InputError
from .hdf5 import check_writable, write_dataset
from .import_spec import ANGLE_UNITS, DT_SPREAD, LENGTH_UNITS, MIN_SAMPLES, TIME_UNITS, ImportSpec
from .resampling import checked_time, resample
from .splits import split_entries
from .tables import EXTENSIONS, read_csv_table, recording_name


def import_recordings(files, output: str | Path, spec: ImportSpec, overwrite: bool = False) -> Path:
    """Read, check and resample the recordings, and write the dataset file (atomically).

    ``files``: CSV paths, one recording each (its name: ``recording_name``). Returns the path written.
    """
    files = [Path(f) for f in files]
    if not files:
        raise InputError("import: no recordings given")
    stems = [recording_name(f) for f in files]  # run.csv and run.csv.gz are both "run"
    if len(set(stems)) != len(stems):
        raise InputError(f"import: recording names (file names without .gz and {', '.join(EXTENSIONS)}) must be "
                         f"unique: {stems}")
    output = check_writable(output, overwrite)  # before any work
    decl, param_table = spec.parameter_table(stems)
    system = spec.system(decl)
    columns = [spec.time, *spec.coordinates, *(spec.velocities or []), *spec.input_columns]
    records, timing = [], []
    for f in files:
        raw, lines = read_csv_table(f, columns, spec.delimiter, spec.decimal)
        if spec.time_units != "s":
            raw[:, 0] = raw[:, 0] / TIME_UNITS[spec.time_units]
        timing.append(checked_time(f, raw[:, 0], spec.max_gap, lines))
        records.append(raw)
    dt = _interval(files, timing, spec.dt)
    resampled = [resample(raw, dt) for raw in records]
    entries, splits = split_entries(stems, spec.split, spec.seed, [len(r) * dt for r in resampled])
    pieces, windows = _pieces(entries, resampled, records, stems, dt, int(round(spec.window_context / dt)))
    arrays = _arrays(system, spec, resampled, pieces, windows, param_table, dt)
    settings = {**asdict(spec), "dt": dt}
    provenance = {"sources": [{"file": f.name, "sha256": hashlib.sha256(f.read_bytes()).hexdigest(), "rows": len(r),
                               "resampled_points": len(res), "timing": tm}
                              for f, r, res, tm in zip(files, records, resampled, timing, strict=True)],
                  "resampling": f"every column linearly interpolated onto t_0 + k dt, dt = {dt:g} s (median interval "
                                f"of the first recording {timing[0]['median_interval_s']:.4g} s)", "settings": settings,
                  "entries": [{"name": name, "recording": stems[i], "from_s": lo * dt, "to_s": (hi - 1) * dt,
                               "window": list(w)} for (i, _, _, name), (_, lo, hi), w
                              in zip(entries, pieces, windows, strict=True)]}
    if spec.currents:
        provenance["inputs"] = {"from": "motor currents (A) times drive_gains (N m per A)", "columns": spec.currents,
                                "drive_gains": [float(g) for g in spec.drive_gains]}
    return write_dataset(output, arrays, splits, _attributes(system, spec, entries, provenance), overwrite=overwrite)


def _interval(files: list[Path], timing: list[dict], dt: float | None) -> float:
    """The resampling interval: ``dt``, else the first recording's median interval rounded to 0.1 ms;
    refused where the recordings' medians differ by more than ``DT_SPREAD`` and round apart."""
    medians = [tm["median_interval_s"] for tm in timing]
    own = [round(m, 4) or m for m in medians]  # each recording's default dt alone (jitter moves a median by ~1 %)
    if dt is None and max(medians) > (1 + DT_SPREAD) * min(medians) and len(set(own)) > 1:
        listing = ", ".join(f"{f.name} {1e3 * m:.4g} ms" for f, m in zip(files, medians, strict=True))
        raise InputError(f"import: the recordings' median sampling intervals differ by more than "
                         f"{100 * DT_SPREAD:g} % ({listing}): set dt, the resampling interval in s (--dt; e.g. "
                         f"{min(medians):.4g} for the fastest), rather than thin the faster recordings")
    return dt or own[0]


def _pieces(entries, resampled, records, stems, dt: float, context: int) -> tuple[list, list]:
    """Each entry's stored span ``(recording, lo, hi)`` (a window with up to ``context`` samples on each
    side) and its window ``(start, end)`` within that span; too short an entry is refused."""
    pieces, windows = [], []
    for i, start, end, name in entries:
        L = len(resampled[i])
        if start is None and end is None:
            if L < MIN_SAMPLES:
                raise InputError(f"import: recording {name!r} holds {L} samples at dt = {dt:g} s, fewer than "
                                 f"{MIN_SAMPLES}: too short to train or evaluate on")
            pieces.append((i, 0, L))
            windows.append((0, L))
            continue
        a = 0 if start is None else max(0, int(np.ceil(start / dt - 1e-9)))  # seconds from the first sample
        b = L if end is None else min(L, int(np.ceil(end / dt - 1e-9)))  # [start, end): no sample in two windows
        if b <= a:
            t0 = float(records[i][0, 0])
            origin = (f"; windows count seconds from the recording's first sample, t = {t0:.6g} s" if abs(t0) > dt
                      else "")
            raise InputError(f"split: window {name!r} holds no sample of {stems[i]} ({L * dt:.4g} s long){origin}")
        if b - a < MIN_SAMPLES:
            raise InputError(f"split: window {name!r} holds {b - a} samples of {stems[i]} at dt = {dt:g} s, fewer "
                             f"than {MIN_SAMPLES}: too short to train or evaluate on")
        lo, hi = max(0, a - context), min(L, b + context)
        pieces.append((i, lo, hi))
        windows.append((a - lo, b - lo))
    return pieces, windows


def _arrays(system, spec: ImportSpec, resampled, pieces, windows, param_table, dt: float) -> dict:
    """The dataset's arrays in SI, NaN-padded to the longest entry: ``t, q, qd, params, lengths``, and
    ``windows``, ``tau`` where there are any."""
    dof, n_u = system.dof, system.num_inputs
    unit = np.where(np.array(system.angle_mask), ANGLE_UNITS[spec.angle_units], LENGTH_UNITS[spec.length_units])
    gains = np.asarray(spec.drive_gains, dtype=np.float64) if spec.currents else np.ones(n_u)
    lengths = [hi - lo for _, lo, hi in pieces]
    T, N = max(lengths), len(pieces)
    q, qd = np.full((N, T, dof), np.nan), np.full((N, T, dof), np.nan)
    tau = np.full((N, T, n_u), np.nan) if n_u else None
    for k, (i, lo, hi) in enumerate(pieces):
        cols = resampled[i][lo:hi]
        L = hi - lo
        q[k, :L] = cols[:, :dof] * unit
        c = dof
        if spec.velocities:
            qd[k, :L] = cols[:, c:c + dof] * unit
            c += dof
        if n_u:
            tau[k, :L] = cols[:, c:c + n_u] * gains
    arrays = {"t": dt * np.arange(T), "q": q, "qd": qd, "params": param_table[[i for i, _, _ in pieces]],
              "lengths": np.asarray(lengths, dtype=np.int64)}
    if any(w != (0, n) for w, n in zip(windows, lengths, strict=True)):
        arrays["windows"] = np.asarray(windows, dtype=np.int64)
    if n_u:
        arrays["tau"] = tau
    return arrays


def _attributes(system, spec: ImportSpec, entries, provenance: dict) -> dict:
    """The dataset file's attributes: the measured scene, its conventions and units, the provenance."""
    input_units = list(system.input_units)
    units = {"t": "s", "q": list(system.coord_units), "qd": [u + "/s" for u in system.coord_units],
             "params": list(system.param_units), "tau": input_units}
    attrs = {"scene": system.name, "scene_json": json.dumps(system.describe(), sort_keys=True),
             "conventions": system.conventions, "units": json.dumps(units), "gravity": float("nan"),
             "param_names": json.dumps(list(system.param_names)), "measured": True,
             "velocities_measured": bool(spec.velocities), "recordings": json.dumps([e[3] for e in entries]),
             "provenance": json.dumps(provenance), "targets": "none (measured)",
             "package_version": __version__, "created": datetime.now(timezone.utc).isoformat(timespec="seconds")}
    if system.num_inputs:
        attrs["inputs"] = json.dumps({"names": list(system.input_names), "units": input_units,
                                      "input_matrix": system.input_matrix().tolist(),
                                      "hold": "measured; linearly interpolated onto the grid, held over each step"})
    return attrs
