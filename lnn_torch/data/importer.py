"""Import measured recordings (one CSV per recording) into the project's HDF5 schema.

Each recording is resampled onto a uniform grid: every column (coordinates, velocities, inputs) is
linearly interpolated at ``t_0 + k dt`` from the first time stamp to the last (``dt`` defaults to
the median sampling interval, rounded to 0.1 ms). Units are converted to SI (degrees to radians
for angle coordinates and their velocities). Recordings keep their own lengths: the file pads them
with NaN and records ``lengths``. The split is by recording: named by the user, or seeded fractions.

Refused, with one line naming the file and the line of the CSV, before anything is written: a
missing column, a time that does not increase (or repeats), a NaN or unreadable value, a gap longer
than ``max_gap``, an existing output (unless ``overwrite``). The file records the provenance:
source names, SHA-256 checksums and every setting.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from .. import __version__
from ..errors import InputError
from ..systems import get_system
from .hdf5 import check_writable, write_dataset

ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180}


@dataclass
class ImportSpec:
    """How to read the recordings (every field is recorded in the file).

    Attributes:
        coordinates: the columns of the generalised coordinates, in order.
        time: the column of time stamps, s.
        velocities: the columns of measured velocities (None: not measured).
        inputs: the columns of the inputs, e.g. measured motor torques in N m (None: unactuated).
        coord_names, input_names: names (default ``q1..``, ``tau1..``).
        angle_mask: which coordinates are angles (default all).
        angle_units: ``rad`` or ``deg`` for the angle coordinates and their velocities.
        conventions: the angle convention in words (recorded; e.g. joint-relative angles).
        angle_combinations: further feature angles as rows of coefficients (e.g. ``[[1, 1]]``: the
            absolute angle of link 2 of a chain measured in joint angles).
        input_matrix: ``(dof, n_u)`` (default: input ``j`` acts on coordinate ``j``).
        friction: models of the system learn joint friction; ``joint_map``: the joint rates
            ``D qd`` it acts on (default identity); ``coulomb_velocity``: its smoothing, rad/s.
        dt: resampling interval, s (default: the median interval of the first recording, rounded).
        max_gap: the longest interval between two time stamps accepted, s (default 5 x the median).
        split: ``{"train": [...], "val": [...], "test": [...]}`` recording names (file stems), or
            three fractions (seeded by ``seed``).
        label: the system's name (recorded).
    """

    coordinates: list[str]
    time: str = "time"
    velocities: list[str] | None = None
    inputs: list[str] | None = None
    coord_names: list[str] | None = None
    input_names: list[str] | None = None
    angle_mask: list[bool] | None = None
    angle_units: str = "rad"
    conventions: str = ""
    angle_combinations: list[list[float]] | None = None
    input_matrix: list[list[float]] | None = None
    friction: bool = True
    joint_map: list[list[float]] | None = None
    coulomb_velocity: float = 0.02
    dt: float | None = None
    max_gap: float | None = None
    split: dict | list = field(default_factory=lambda: [0.7, 0.15, 0.15])
    seed: int = 0
    label: str = "measured"

    def __post_init__(self) -> None:
        dof = len(self.coordinates)
        if dof == 0:
            raise InputError("import: name at least one coordinate column")
        for name, cols in (("velocities", self.velocities), ("coord_names", self.coord_names)):
            if cols is not None and len(cols) != dof:
                raise InputError(f"import: {name} needs {dof} entries (one per coordinate), got {len(cols)}")
        if self.inputs is not None and self.input_names is not None and len(self.input_names) != len(self.inputs):
            raise InputError(f"import: input_names needs {len(self.inputs)} entries, got {len(self.input_names)}")
        if self.angle_units not in ANGLE_UNITS:
            raise InputError(f"import: angle_units must be one of {', '.join(ANGLE_UNITS)}, got '{self.angle_units}'")
        for name in ("dt", "max_gap"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise InputError(f"import: {name} must be positive, got {value}")

    def system(self):
        """The ``MeasuredSystem`` these recordings declare."""
        dof = len(self.coordinates)
        n_u = len(self.inputs or [])
        return get_system("measured", dof=dof, angle_mask=self.angle_mask, coord_names=self.coord_names,
                          input_names=self.input_names or [f"tau{i + 1}" for i in range(n_u)],
                          input_matrix=self.input_matrix, friction=self.friction, joint_map=self.joint_map,
                          coulomb_velocity=self.coulomb_velocity, angle_combinations=self.angle_combinations,
                          conventions=self.conventions, label=self.label)


def read_csv_columns(path: Path, columns: list[str]) -> np.ndarray:
    """The named columns of a CSV file (``.csv``, or gzip-compressed ``.csv.gz``; comment lines starting
    with ``#`` before the header) as float64 ``(rows, len(columns))``; errors name the file and line."""
    if not path.exists():
        raise InputError(f"{path}: no such file")
    import gzip

    opener = gzip.open if path.suffix == ".gz" else open
    try:
        return _parse_csv(path, opener, columns)
    except EOFError:
        raise InputError(f"{path}: truncated (the compressed file ends early)") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text CSV file (undecodable bytes)") from None
    except OSError as err:  # gzip.BadGzipFile, ...
        raise InputError(f"{path}: cannot read it ({err})") from None


_read_csv = read_csv_columns  # the former private name, kept for callers


def _parse_csv(path: Path, opener, columns: list[str]) -> np.ndarray:
    with opener(path, "rt", newline="") as fh:
        reader = csv.reader(fh)
        try:
            header = [h.strip() for h in next(reader)]
            while header and header[0].startswith("#"):  # comment lines before the header
                header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise InputError(f"{path}: the file is empty") from None
        missing = [c for c in columns if c not in header]
        if missing:
            raise InputError(f"{path}: no column {', '.join(repr(c) for c in missing)} (columns: {', '.join(header)})")
        index = [header.index(c) for c in columns]
        rows = []
        for line, row in enumerate(reader, start=2):
            if not row or not "".join(row).strip():
                continue
            try:
                values = [float(row[i]) for i in index]
            except (ValueError, IndexError):
                raise InputError(f"{path}: line {line}: a value of {', '.join(columns)} is missing or not a "
                                 "number") from None
            bad = [c for c, v in zip(columns, values, strict=True) if not math.isfinite(v)]
            if bad:
                raise InputError(f"{path}: line {line}: NaN or Inf in column {bad[0]!r}")
            rows.append(values)
    if len(rows) < 2:
        raise InputError(f"{path}: fewer than two data rows")
    return np.asarray(rows, dtype=np.float64)


def _checked_time(path: Path, t: np.ndarray, max_gap: float | None) -> float:
    """Raise for a time that does not increase or a gap beyond ``max_gap``; returns the median interval."""
    steps = np.diff(t)
    bad = np.nonzero(steps <= 0)[0]
    if bad.size:
        i = int(bad[0])
        what = "repeats" if steps[i] == 0 else "decreases"
        raise InputError(f"{path}: line {i + 3}: time {what} (t = {t[i + 1]:.6g} s after {t[i]:.6g} s)")
    median = float(np.median(steps))
    limit = max_gap if max_gap is not None else 5 * median
    gaps = np.nonzero(steps > limit)[0]
    if gaps.size:
        i = int(gaps[0])
        raise InputError(f"{path}: line {i + 3}: a gap of {steps[i]:.4g} s after t = {t[i]:.6g} s exceeds max_gap "
                         f"{limit:.4g} s")
    return median


def _split(names: list[str], split, seed: int) -> dict:
    if isinstance(split, dict):
        known = set(names)
        out = {}
        for part in ("train", "val", "test"):
            chosen = list(split.get(part, []))
            unknown = [n for n in chosen if n not in known]
            if unknown:
                raise InputError(f"split: unknown recording(s) {', '.join(unknown)} (recordings: {', '.join(names)})")
            out[part] = np.array(sorted(names.index(n) for n in chosen), dtype=np.int64)
        used = np.concatenate(list(out.values()))
        if len(np.unique(used)) != len(used):
            raise InputError("split: a recording is named in more than one split")
        if not len(out["train"]):
            raise InputError("split: no training recording")
        return out
    fractions = [float(x) for x in split]
    if len(fractions) != 3 or any(f < 0 for f in fractions) or abs(sum(fractions) - 1) > 1e-9:
        raise InputError(f"split must be three fractions summing to 1 or a dict of recording names, got {split!r}")
    n = len(names)
    perm = np.random.default_rng(np.random.SeedSequence(int(seed))).permutation(n)
    n_val, n_test = int(round(fractions[1] * n)), int(round(fractions[2] * n))
    n_train = n - n_val - n_test
    if n_train < 1:
        raise InputError(f"split: {n} recordings leave none for training with fractions {fractions}")
    return {"train": np.sort(perm[:n_train]), "val": np.sort(perm[n_train:n_train + n_val]),
            "test": np.sort(perm[n_train + n_val:])}


def import_recordings(files, output: str | Path, spec: ImportSpec, overwrite: bool = False) -> Path:
    """Read, check and resample the recordings, and write the dataset file (atomically).

    ``files``: CSV paths, one recording each (its name is the file's stem). Returns the path written.
    """
    files = [Path(f) for f in files]
    if not files:
        raise InputError("import: no recordings given")
    stems = [f.name.split(".")[0] for f in files]  # run.csv and run.csv.gz are both "run"
    if len(set(stems)) != len(stems):
        raise InputError(f"import: recording names (file names before the first dot) must be unique: {stems}")
    output = check_writable(output, overwrite)  # before any work
    system = spec.system()
    dof, n_u = system.dof, system.num_inputs
    columns = [spec.time, *spec.coordinates, *(spec.velocities or []), *(spec.inputs or [])]
    angle = np.array(system.angle_mask)
    unit = np.where(angle, ANGLE_UNITS[spec.angle_units], 1.0)
    records, medians = [], []
    for f in files:
        raw = read_csv_columns(f, columns)
        t = raw[:, 0]
        medians.append(_checked_time(f, t, spec.max_gap))
        records.append(raw)
    dt = spec.dt or round(medians[0], 4) or medians[0]
    resampled, lengths = [], []
    for raw in records:
        t = raw[:, 0]
        grid = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1)
        cols = np.stack([np.interp(grid, t, raw[:, j]) for j in range(1, raw.shape[1])], -1)
        resampled.append(cols)
        lengths.append(len(grid))
    T = max(lengths)
    N = len(files)
    q = np.full((N, T, dof), np.nan)
    qd = np.full((N, T, dof), np.nan)
    tau = np.full((N, T, n_u), np.nan) if n_u else None
    for i, cols in enumerate(resampled):
        L = lengths[i]
        q[i, :L] = cols[:, :dof] * unit
        k = dof
        if spec.velocities:
            qd[i, :L] = cols[:, k:k + dof] * unit
            k += dof
        if n_u:
            tau[i, :L] = cols[:, k:k + n_u]
    arrays = {"t": dt * np.arange(T), "q": q, "qd": qd, "params": np.zeros((N, 0)),
              "lengths": np.asarray(lengths, dtype=np.int64)}
    if n_u:
        arrays["tau"] = tau
    settings = {k: v for k, v in asdict(spec).items()}
    settings["dt"] = dt
    provenance = {"sources": [{"file": f.name, "sha256": hashlib.sha256(f.read_bytes()).hexdigest(), "rows": len(r),
                               "resampled_points": L} for f, r, L in zip(files, records, lengths, strict=True)],
                  "resampling": f"every column linearly interpolated onto t_0 + k dt, dt = {dt:g} s (median interval "
                                f"of the first recording {medians[0]:.4g} s)", "settings": settings}
    units = {"t": "s", "q": list(system.coord_units), "qd": [u + "/s" for u in system.coord_units],
             "params": [], "tau": ["N m"] * n_u}
    attrs = {"scene": system.name, "scene_json": json.dumps(system.describe(), sort_keys=True),
             "conventions": system.conventions, "units": json.dumps(units), "gravity": float("nan"),
             "param_names": json.dumps([]), "measured": True, "velocities_measured": bool(spec.velocities),
             "recordings": json.dumps(stems), "provenance": json.dumps(provenance), "targets": "none (measured)",
             "package_version": __version__, "created": datetime.now(timezone.utc).isoformat(timespec="seconds")}
    if n_u:
        attrs["inputs"] = json.dumps({"names": list(system.input_names), "units": ["N m"] * n_u,
                                      "input_matrix": system.input_matrix().tolist(),
                                      "hold": "measured; linearly interpolated onto the grid, held over each step"})
    return write_dataset(output, arrays, _split(stems, spec.split, spec.seed), attrs, overwrite=overwrite)
