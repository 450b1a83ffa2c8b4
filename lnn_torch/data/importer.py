"""Import measured recordings (one CSV per recording) into the project's HDF5 schema.

Each recording is a text table (``.csv``, ``.tsv``, ``.txt`` or ``.dat``, or any of them gzip-compressed,
``.csv.gz``), named by its file name without those extensions (``exp_2024.05.01_a.csv``:
``exp_2024.05.01_a``): a header row naming the columns (after comment lines starting with ``#`` and
blank lines; a UTF-8 byte-order mark, as Excel writes, is dropped), then one row per sample. The
delimiter is the header's: ``;`` if it holds one, else a tab if it holds one, else ``,`` (or
``delimiter``: ``whitespace`` for columns aligned by runs of spaces); with a ``;`` or tab delimiter,
numbers may have decimal commas (``decimal``).

Each recording is resampled onto a uniform grid: every column (coordinates, velocities, inputs) is
linearly interpolated at ``t_0 + k dt`` from the first time stamp to the last (``dt`` defaults to
the median sampling interval, rounded to 0.1 ms; recordings whose median intervals differ by more
than 2 % and round to different intervals need ``dt`` set). Irregular stamps and gaps are repaired
this way and reported (``resampling_report``: the intervals, the gaps above twice the median, the
largest); a gap longer than ``max_gap`` (default 25 median intervals) is refused where a window in use
crosses it (a whole recording, or a time window of the split), naming the times a window must end by or start
from; beside a window the filters' context stops at such a gap. Units are converted to SI (time stamps in
``time_units`` to s; degrees to radians for angle coordinates and their velocities; lengths in
``length_units`` to m for the other coordinates and their velocities; motor currents times known drive
gains to N m). Recordings keep their own lengths: the file pads them with NaN and records ``lengths``.

The split is by recording (named by the user, or seeded fractions) or by time window inside a
recording (``"run[0.5:10.5]"``: its samples 0.5 s <= t - t_0 < 10.5 s, seconds from the recording's
first sample ``t_0``, whatever its time column's values): each window is an entry of its own, stored
with up to ``window_context`` s of the recording on each side for the derivative filters and its own
span in ``windows`` (the DataModule cuts each entry to its window after estimating derivatives).
Windows of different splits may not overlap.

Known parameters per recording (``parameters``: e.g. the payload a robot arm carried in each, or a
named tool, whose unknown entries are identified here: ``lnn_torch.data.import_tools``) are stored with
each entry, and a robot arm's description (``robot``) with the scene:
models condition on the parameters as on a simulated scene's, a grey box reads the description.

Refused, with one line naming the file and the line of the file (and the column), before anything
is written: a missing column or a named column that the header holds twice, a time that does not
increase (or repeats), an empty, unreadable, NaN or Inf value, a gap longer than ``max_gap``, an
entry (recording or window) of fewer than 16 samples after resampling, an existing output (unless
``overwrite``). The file records the provenance: source names, SHA-256 checksums, the resampling
report and every setting.

ROS bags of ``sensor_msgs/JointState`` (``.db3``, ``.mcap``, ``.bag``, a rosbag2 folder) are read into the
same table (``lnn_torch.data.bags``: ``read_table`` chooses the reader by the file), and everything after
the table is shared. Rows that repeat the previous one while the joints move (stale messages) are
dropped from bags (``repeated_rows``; counted in a CSV and kept unless asked), and the delay of the input
(torque) columns behind the positions is estimated and reported, applied where ``torque_delay`` says so
(``bags.torque_delay``); the provenance records both per recording.
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
from .bags import BAG_SUFFIXES, bag_name, is_bag, read_bag_table, repeated_rows, shift_inputs, torque_delay
from .hdf5 import check_writable, write_dataset
from .import_spec import ANGLE_UNITS, ARM_PARAMS, DT_SPREAD, LENGTH_UNITS, MIN_SAMPLES, TIME_UNITS, ImportSpec
from .resampling import checked_time, resample
from .splits import split_entries
from .tables import EXTENSIONS, read_csv_table, recording_name


def read_table(path: Path, spec: ImportSpec) -> tuple[np.ndarray, np.ndarray, dict]:
    """``(table (rows, 1 + k), lines (rows,), info)``: one recording as numbers, time in s first, then the
    coordinates, velocities and inputs in the spec's order, whatever the file: a ROS bag
    (``bags.read_bag_table``; ``lines`` its message numbers, ``info`` what was read) or a CSV table."""
    if is_bag(path):
        return read_bag_table(path, spec)
    columns = [spec.time, *spec.coordinates, *(spec.velocities or []), *spec.input_columns]
    raw, lines = read_csv_table(path, columns, spec.delimiter, spec.decimal)
    if spec.time_units != "s":
        raw[:, 0] = raw[:, 0] / TIME_UNITS[spec.time_units]
    return raw, lines, {}


def _name(path: Path) -> str:
    return bag_name(path) if is_bag(path) else recording_name(path)


def _checksum(path: Path) -> str:
    """SHA-256 of a file, or of a folder's files (names and contents, in order of name)."""
    digest = hashlib.sha256()
    if not path.is_dir():
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                digest.update(block)
        return digest.hexdigest()
    for f in sorted(p for p in path.rglob("*") if p.is_file()):
        digest.update(str(f.relative_to(path)).encode() + b"\0" + bytes.fromhex(_checksum(f)))
    return digest.hexdigest()


def import_recordings(files, output: str | Path, spec: ImportSpec, overwrite: bool = False) -> Path:
    """Read, check and resample the recordings, and write the dataset file (atomically).

    ``files``: CSV paths or ROS bags, one recording each (its name: ``recording_name``, ``bags.bag_name``).
    Returns the path written.
    """
    files = [Path(f) for f in files]
    if not files:
        raise InputError("import: no recordings given")
    bags = [is_bag(f) for f in files]
    if any(bags) and not all(bags):
        raise InputError("import: give CSV recordings or ROS bags, not both (their columns are named differently)")
    if all(bags):
        spec = spec.for_bags()
    elif spec.joints is not None:
        raise InputError("import: joints maps a ROS bag's joint names; a CSV's columns are named in coordinates")
    elif spec.input_names is not None and not spec.input_columns:
        raise InputError(f"import: input_names names {len(spec.input_names)} inputs, but no input columns are given "
                         "(inputs, or currents)")
    stems = [_name(f) for f in files]  # run.csv and run.csv.gz are both "run"
    if len(set(stems)) != len(stems):
        raise InputError(f"import: recording names (file names without .gz and {', '.join(EXTENSIONS)}, or "
                         f"{', '.join(BAG_SUFFIXES)}) must be unique: {stems}")
    if any(Path(output).resolve() == f.resolve() for f in files):  # (--overwrite replaced a recording with the file)
        raise InputError(f"import: the output {output} is one of the recordings read")
    output = check_writable(output, overwrite)  # before any work
    decl, param_table = spec.parameter_table(stems)
    system = spec.system(decl)
    records, lines_of, timing, infos = _read(files, spec, system.dof, system.angle_mask)
    dt = _interval(files, timing, spec.dt)
    resampled = [resample(raw, dt) for raw in records]
    # the delay's fit reads each recording's longest stretch clear of gaps beyond max_gap (no interpolated stretch)
    clear = [_longest_clear(r, tm, float(raw[0, 0]), dt) for r, tm, raw in zip(resampled, timing, records, strict=True)]
    delay, applied = _delay(system, spec, stems, clear, param_table, decl, dt)
    if applied:  # the inputs shifted on the recorded stamps, then every column resampled again
        for i, f in enumerate(files):
            records[i], lines_of[i] = shift_inputs(records[i], lines_of[i], system.num_inputs, applied)
            if len(records[i]) < 2:
                raise InputError(f"{f}: a torque delay of {applied:g} s leaves fewer than two samples")
            timing[i] = _checked_time(f, records[i][:, 0], spec.max_gap, lines_of[i], bool(infos[i].get("format")))
        resampled = [resample(raw, dt) for raw in records]
    entries, splits = split_entries(stems, spec.split, spec.seed, [len(r) * dt for r in resampled])
    pieces, windows = _pieces(entries, resampled, records, stems, dt, int(round(spec.window_context / dt)))
    pieces, windows = _gaps_in_use(files, timing, records, entries, pieces, windows, dt, bags)
    arrays = _arrays(system, spec, resampled, pieces, windows, param_table, dt)
    tools = spec.tools(stems)
    tools_report = None
    if any(tool.unknown for tool in tools.values()):
        from .import_tools import identify_at_import

        if not system.num_inputs:
            raise InputError("import: identifying a tool needs the joint torques (inputs)")
        arrays["params"], tools_report = identify_at_import(system, spec, tools, spec.tool_of(stems), stems, entries,
                                                            splits, arrays, dt)
    settings = {**asdict(spec), "dt": dt}
    provenance = {"sources": [{"file": f.name, "sha256": _checksum(f), "rows": len(r), "t0_s": float(r[0, 0]),
                               "resampled_points": len(res), "timing": tm, **info}
                              for f, r, res, tm, info in zip(files, records, resampled, timing, infos, strict=True)],
                  "resampling": f"every column linearly interpolated onto t_0 + k dt, dt = {dt:g} s (median interval "
                                f"of the first recording {timing[0]['median_interval_s']:.4g} s)", "settings": settings,
                  "entries": [{"name": name, "recording": stems[i], "from_s": lo * dt, "to_s": (hi - 1) * dt,
                               "window": list(w)} for (i, _, _, name), (_, lo, hi), w
                              in zip(entries, pieces, windows, strict=True)]}
    if tools_report is not None:
        provenance["tools"] = tools_report
    if delay:
        provenance["torque_delay"] = {**delay, "mode": spec.delay_mode, "applied_s": applied or 0.0}
    if spec.currents:
        provenance["inputs"] = {"from": "motor currents (A) times drive_gains (N m per A)", "columns": spec.currents,
                                "drive_gains": [float(g) for g in spec.drive_gains]}
    return write_dataset(output, arrays, splits, _attributes(system, spec, entries, provenance), overwrite=overwrite)


def unwrap_angles(raw: np.ndarray, columns, period: float) -> dict:
    """Angles an encoder or logger wrapped into one turn (``-180..180`` deg, ``0..2 pi``), made continuous in
    place: where an angle column of ``raw`` jumps between two rows by about a whole ``period`` (within a quarter
    of it; no motion moves an angle by half a turn between two samples), the rest of the column moves by the
    period. Returns ``{column: jumps}`` for the columns changed."""
    changed = {}
    for c in columns:
        step = np.diff(raw[:, c])
        wraps = (np.abs(step) > period / 2) & (np.abs(np.abs(step) - period) < period / 4)
        if wraps.any():
            raw[1:, c] -= period * np.cumsum(np.where(wraps, np.sign(step), 0.0))
            changed[c] = int(wraps.sum())
    return changed


def _read(files: list[Path], spec: ImportSpec, dof: int, angle_mask) -> tuple[list, list, list, list]:
    """Each recording's table (repeated rows dropped where ``repeated_rows`` says so; angles wrapped into one
    turn made continuous, ``unwrap_angles``), its lines (or messages), its timing (checked) and what was read
    (with the repeated rows' count and the wrapped angles)."""
    records, lines_of, timing, infos = [], [], [], []
    drop = (spec.repeated_rows or "keep") == "drop"
    period = 2 * np.pi / ANGLE_UNITS[spec.angle_units]
    angles = [1 + j for j in range(dof) if angle_mask[j]]
    for f in files:
        raw, lines, info = read_table(f, spec)
        wrapped = unwrap_angles(raw, angles, period)
        if wrapped:
            info["wrapped"] = {spec.coordinates[c - 1] if spec.coordinates else f"q{c}": n for c, n in wrapped.items()}
        interval = np.diff(raw[:, 0])
        if angles and (interval > 0).any():  # how fast the angles move, in rad/s (a unit read wrong shows here)
            moving = interval > 0
            speed = (np.abs(np.diff(raw[:, angles], axis=0))[moving] / interval[moving, None]
                     * ANGLE_UNITS[spec.angle_units])
            info["angle_speed_p95_rad_s"] = float(np.percentile(speed, 95, axis=0).max())
        # (efforts of another topic, interpolated to these times, never repeat: a stale message is its positions')
        own = raw[:, :1 + dof * (1 + bool(spec.velocities))] if info.get("effort_topic") else raw
        repeated = repeated_rows(own, dof, bool(spec.velocities))
        duplicates = repeated & np.r_[False, raw[1:, 0] == raw[:-1, 0]]  # the time stamp repeated too
        info["repeated_rows"] = {"count": int(repeated.sum()), "dropped": drop,
                                 "first": [int(x) for x in lines[repeated][:5]], "duplicates": int(duplicates.sum())}
        if drop and repeated.any():
            raw, lines = raw[~repeated], lines[~repeated]
        try:
            timing.append(_checked_time(f, raw[:, 0], spec.max_gap, lines, bool(info.get("format"))))
        except InputError as err:
            back = np.nonzero(np.diff(raw[:, 0]) <= 0)[0]  # the row refused: an exact duplicate of the one before?
            if drop or not back.size or not duplicates[back[0] + 1]:
                raise
            n = int(duplicates.sum())
            what = "message" if info.get("format") else "row"
            raise InputError(f"{err} (an exact duplicate of the {what} before, as are {n - 1} more: repeated_rows: "
                             "drop, or --repeated-rows drop, leaves them out)" if n > 1 else
                             f"{err} (an exact duplicate of the {what} before: repeated_rows: drop, or "
                             "--repeated-rows drop, leaves it out)") from None
        records.append(raw)
        lines_of.append(lines)
        infos.append(info)
    return records, lines_of, timing, infos


def _delay(system, spec: ImportSpec, stems, resampled, param_table, decl: dict, dt: float) -> tuple[dict, float]:
    """``(report, applied s)``: the inputs' delay estimated (``_torque_delay``; none without inputs or with
    ``torque_delay: off``) and the delay to apply: the estimate (``auto``: refused where it is not
    determined or lies at the edge of the range searched), the given one, or 0."""
    delay = {}
    if system.num_inputs and spec.delay_mode != "off":
        delay = _torque_delay(system, spec, stems, resampled, param_table, decl, dt)
    if spec.delay_mode in ("fixed", "auto") and not system.num_inputs and spec.torque_delay:
        raise InputError("import: torque_delay shifts the inputs (torques): these recordings have none")
    if spec.delay_mode == "fixed":
        return delay, float(spec.torque_delay)
    if spec.delay_mode != "auto" or not system.num_inputs:
        return delay, 0.0
    if "delay_s" not in delay:
        why = "; ".join(f"{r['name']}: {r['skipped']}" for r in delay.get("recordings", []) if "skipped" in r)
        raise InputError(f"import: torque_delay auto: no recording gives an estimate of the delay ({why}); set "
                         "torque_delay (s)")
    if not delay["consistent"]:
        halves = ", ".join(f"{1e3 * x:+.3g}" for r in delay["recordings"] for x in r.get("halves_s", []))
        raise InputError(f"import: torque_delay auto: the delay is not determined (the recordings' halves give "
                         f"{halves} ms, beyond their errors: Birge ratio {delay['birge']:.2g}); set torque_delay (s)")
    if delay["at_edge"]:
        raise InputError(f"import: torque_delay auto: the estimate {1e3 * delay['delay_s']:+.3g} ms lies at the edge "
                         f"of the delays searched (+-{1e3 * delay['searched_s']:.3g} ms): widen torque_delay_range, or "
                         "set torque_delay (s)")
    if not delay.get("significant", True):  # (within its errors of none: exact simulated torques got -11 ms)
        return delay, 0.0
    return delay, delay["delay_s"]


def _checked_time(path: Path, t: np.ndarray, max_gap, lines: np.ndarray, bag: bool) -> dict:
    """``resampling.checked_time``, the gaps beyond ``max_gap`` listed (``_gaps_in_use`` refuses those the dataset's
    windows use); a bag's refusals name its message (its ``lines``) rather than a line."""
    try:
        return checked_time(path, t, max_gap, lines)
    except InputError as err:
        if not bag:
            raise
        raise InputError(str(err).replace(f"{path}: line ", f"{path}: message ", 1)) from None


def _gaps_in_use(files, timing, records, entries, pieces, windows, dt: float, bags) -> tuple[list, list]:
    """The entries' spans and windows (``_pieces``) clear of the gaps beyond ``max_gap``: a gap a window crosses is
    refused, naming the window and the times it must end by or start from; the filters' context beside a window
    ends at a gap (as at a recording's end); a gap no span reaches is interpolated across like any other (no data
    in use comes from it)."""
    out_pieces, out_windows = [], []
    for (i, start, end, name), (_, lo, hi), (wa, wb) in zip(entries, pieces, windows, strict=True):
        a, b = lo + wa, lo + wb  # the window, in samples of the recording
        for first, last, before, after, line in gap_samples(timing[i], float(records[i][0, 0]), dt):
            if a < last and b - 1 > first:  # a sample of the window inside the gap
                at = "message" if bags[i] else "line"
                end_by, start_from = _seconds(first * dt, dt), _seconds(last * dt, dt)
                where = (f"split the recording there with windows, e.g. {name}[0:{end_by}] and {name}[{start_from}:]"
                         if start is None and end is None else
                         f"the window {name!r} crosses it: end it by {end_by} s or start it from {start_from} s")
                raise InputError(f"{files[i]}: {at} {line}: a gap of {after - before:.4g} s after t = "
                                 f"{before:.6g} s exceeds max_gap {timing[i]['max_gap_s']:.4g} s: too long to "
                                 f"interpolate across; {where} (s from the recording's first sample), or raise max_gap")
            if b - 1 <= first:  # the gap after the window: the context stops at it
                hi = min(hi, first + 1)
            else:  # before the window
                lo = max(lo, last)
        out_pieces.append((i, lo, hi))
        out_windows.append((a - lo, b - lo))
    return out_pieces, out_windows


def gap_samples(timing: dict, t0: float, dt: float) -> list[tuple[int, int, float, float, int]]:
    """The recording's gaps beyond ``max_gap`` (``timing["long_gaps"]``) on its resampled grid ``t0 + k dt``:
    ``(first, last, t before, t after, line)`` each, ``first`` the last sample at or before the gap's start and ``last``
    the first at or after its end (the samples between are interpolated). A thousandth of a sample of slack:
    epoch time stamps carry rounding of that order."""
    out = []
    for before, after, line in timing.get("long_gaps", []):
        first = int(np.floor((before - t0) / dt + 1e-3))
        last = int(np.ceil((after - t0) / dt - 1e-3))
        out.append((first, last, before, after, line))
    return out


def _longest_clear(resampled: np.ndarray, timing: dict, t0: float, dt: float) -> np.ndarray:
    """The longest stretch of a resampled recording that crosses no gap beyond ``max_gap`` (the whole recording
    where it has none)."""
    cuts = [(0, 0)] + [(first + 1, last) for first, last, *_ in gap_samples(timing, t0, dt)] + [(len(resampled),) * 2]
    spans = [(cuts[k][1], cuts[k + 1][0]) for k in range(len(cuts) - 1)]
    lo, hi = max(spans, key=lambda s: s[1] - s[0])
    return resampled[lo:hi]


def _seconds(x: float, dt: float) -> str:
    """``x`` s on a grid of ``dt`` s, written with the decimals that grid needs (a window bound that holds)."""
    decimals = max(0, int(np.ceil(-np.log10(dt) - 1e-9))) + 1
    return f"{x:.{decimals}f}".rstrip("0").rstrip(".")


def _torque_delay(system, spec: ImportSpec, stems, resampled, param_table, decl: dict, dt: float) -> dict:
    """The input columns' delay behind the positions (``bags.torque_delay``) on the resampled recordings:
    by a robot arm's regressor where the inputs are its joint torques, else by the generic basis."""
    series = []
    for i, name in enumerate(stems):
        q, qd, tau = _si(system, spec, resampled[i])
        series.append({"name": name, "q": q, "qd": qd, "tau": tau, "params": param_table[i]})
    chain, payload = None, False
    description = system.config().get("description")
    if description is not None and np.allclose(system.input_matrix(), np.eye(system.dof)):
        from ..robots.kinematics import read_chain
        from ..robots.mujoco_arm import load_description

        chain = read_chain(load_description(description))
        names = list(decl.get("names", ()))
        payload = len(names) in (4, 10) and names == list(ARM_PARAMS[:len(names)])
    report = torque_delay(series, dt, chain=chain, payload=payload, angle_mask=system.angle_mask,
                          combinations=spec.angle_combinations, coulomb_velocity=spec.coulomb_velocity,
                          span=spec.torque_delay_range)
    units = set(system.input_units)
    report["units"] = units.pop() if len(units) == 1 else ""
    return report


# a resampling interval below the recordings' median interval by more than this factor is refused (dt = 1e-7 s
# on 2 ms recordings asked for 100 million samples)
UPSAMPLING = 20


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
    if dt is not None and dt < min(medians) / UPSAMPLING:
        raise InputError(f"import: dt = {dt:g} s is under 1/{UPSAMPLING} of the recordings' shortest median sampling "
                         f"interval ({min(medians):.4g} s): interpolation adds no information, only samples (set dt "
                         "near the sampling interval)")
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
    lengths = [hi - lo for _, lo, hi in pieces]
    T, N = max(lengths), len(pieces)
    q, qd = np.full((N, T, dof), np.nan), np.full((N, T, dof), np.nan)
    tau = np.full((N, T, n_u), np.nan) if n_u else None
    for k, (i, lo, hi) in enumerate(pieces):
        L = hi - lo
        q_i, qd_i, tau_i = _si(system, spec, resampled[i][lo:hi])
        q[k, :L] = q_i
        if qd_i is not None:
            qd[k, :L] = qd_i
        if n_u:
            tau[k, :L] = tau_i
    arrays = {"t": dt * np.arange(T), "q": q, "qd": qd, "params": param_table[[i for i, _, _ in pieces]],
              "lengths": np.asarray(lengths, dtype=np.int64)}
    if any(w != (0, n) for w, n in zip(windows, lengths, strict=True)):
        arrays["windows"] = np.asarray(windows, dtype=np.int64)
    if n_u:
        arrays["tau"] = tau
    return arrays


def _si(system, spec: ImportSpec, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """``(q, qd or None, inputs)`` in SI from resampled columns ``(T, k)`` (coordinates, [velocities],
    inputs in the spec's units)."""
    dof, n_u = system.dof, system.num_inputs
    unit = np.where(np.array(system.angle_mask), ANGLE_UNITS[spec.angle_units], LENGTH_UNITS[spec.length_units])
    gains = np.asarray(spec.drive_gains, dtype=np.float64) if spec.currents else np.ones(n_u)
    q = cols[:, :dof] * unit
    qd = cols[:, dof:2 * dof] * unit if spec.velocities else None
    c = 2 * dof if spec.velocities else dof
    return q, qd, cols[:, c:c + n_u] * gains


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
