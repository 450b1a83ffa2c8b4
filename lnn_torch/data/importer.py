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

import csv
import hashlib
import itertools
import json
import math
import re
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from .._version import __version__
from ..errors import InputError
from ..systems import get_system
from .hdf5 import check_writable, write_dataset

ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180}
LENGTH_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}  # metres per unit
TIME_UNITS = {"s": 1, "ms": 1_000, "us": 1_000_000, "ns": 1_000_000_000}  # stamps per second (divided by)
DECIMALS = ("auto", ".", ",")
EXTENSIONS = (".csv", ".tsv", ".txt", ".dat")  # removed (after .gz) from a file's name to name its recording
ARM_PARAMS = ("payload_mass", "payload_x", "payload_y", "payload_z", "payload_ixx", "payload_iyy", "payload_izz",
              "payload_ixy", "payload_ixz", "payload_iyz")
MAX_GAP_INTERVALS = 25  # the default max_gap, in median sampling intervals
MIN_SAMPLES = 16  # the fewest samples of an entry (a recording or a window) after resampling
DT_SPREAD = 0.02  # the relative spread of median intervals beyond which the default dt needs them to round alike


@dataclass
class ImportSpec:
    """How to read the recordings (every field is recorded in the file).

    Attributes:
        coordinates: the columns of the generalised coordinates, in order.
        time: the column of time stamps, in ``time_units``.
        time_units: the time column's unit: ``s`` (default), ``ms``, ``us`` or ``ns`` (velocities are per
            second whatever it is).
        velocities: the columns of measured velocities (None: not measured).
        inputs: the columns of the inputs, e.g. measured motor torques in N m (None: unactuated).
        currents: instead of ``inputs``, motor current columns (A), turned into torques by ``drive_gains``
            (N m per A, one per input: the motor constant times the gear ratio).
        coord_names, input_names: names (default ``q1..``, ``tau1..``; a robot arm's: its joints').
        angle_mask: which coordinates are angles (default all).
        angle_units: ``rad`` or ``deg`` for the angle coordinates and their velocities.
        length_units: ``m`` (default), ``cm`` or ``mm`` for the other coordinates (lengths) and their
            velocities.
        delimiter: the files' delimiter, one character (``tab`` for a tab); default (None): each file's
            header's, ``;`` if it holds one, else a tab if it holds one, else ``,``.
        decimal: the decimal mark: ``auto`` (default: ``.``, and ``,`` too where the delimiter is not
            ``,``), ``.`` or ``,``.
        conventions: the angle convention in words (recorded; e.g. joint-relative angles).
        angle_combinations: further feature angles as rows of coefficients (e.g. ``[[1, 1]]``: the
            absolute angle of link 2 of a chain measured in joint angles).
        input_matrix: ``(dof, n_u)`` (default: input ``j`` acts on coordinate ``j``); an input acting
            only on lengths is a force, N (``length_units`` do not apply to it), otherwise a torque, N m.
        friction: models of the system learn joint friction; ``joint_map``: the joint rates
            ``D qd`` it acts on (default identity); ``coulomb_velocity``: its smoothing, rad/s.
        robot: a robot arm's description as the robot it is (``lnn_torch.robots.description``: a shipped
            name, an MJCF/URDF path, or ``{source, flange, remove, tool, armature, damping}``); the
            coordinates are then its joints in its order (``coord_names`` its joint names).
        parameters: known parameters per recording: ``{"names": [...], "units": [...], "kinds": [...],
            "values": {recording: [...] or a tool's name}, "tools": {name: [...]}}``; for a robot arm
            the names default to the payload at its flange, ``payload_mass, payload_x, payload_y,
            payload_z`` (kg, m; ten values with the inertia about the centre of mass). A recording
            without values carries zeros (no payload).
        dt: resampling interval, s (default: the median interval of the first recording, rounded to 0.1
            ms; refused, asking for ``dt``, where the recordings' median intervals differ by over 2 % and
            round to different intervals).
        max_gap: the longest interval between two time stamps accepted, s (default 25 x the median).
        split: ``{"train": [...], "val": [...], "test": [...]}`` of recording names (file names without
            ``.gz`` and ``.csv``/``.tsv``/``.txt``/``.dat``) or time windows ``"name[start:end]"``
            (seconds from the recording's first sample, not values of its time column; an end may be
            left out), or three fractions of the recordings (seeded by ``seed``): ``[0.7, 0.15, 0.15]``
            or ``{"train": 0.7, "val": 0.15, "test": 0.15}``. Every entry needs 16 samples or more.
        window_context: seconds of the recording kept on each side of a time window (for filters).
        label: the system's name (recorded).
    """

    coordinates: list[str]
    time: str = "time"
    time_units: str = "s"
    velocities: list[str] | None = None
    inputs: list[str] | None = None
    currents: list[str] | None = None
    drive_gains: list[float] | None = None
    coord_names: list[str] | None = None
    input_names: list[str] | None = None
    angle_mask: list[bool] | None = None
    angle_units: str = "rad"
    length_units: str = "m"
    delimiter: str | None = None
    decimal: str = "auto"
    conventions: str = ""
    angle_combinations: list[list[float]] | None = None
    input_matrix: list[list[float]] | None = None
    friction: bool = True
    joint_map: list[list[float]] | None = None
    coulomb_velocity: float = 0.02
    robot: dict | str | None = None
    parameters: dict | None = None
    dt: float | None = None
    max_gap: float | None = None
    split: dict | list = field(default_factory=lambda: [0.7, 0.15, 0.15])
    window_context: float = 0.5
    seed: int = 0
    label: str = "measured"

    def __post_init__(self) -> None:
        dof = len(self.coordinates)
        if dof == 0:
            raise InputError("import: name at least one coordinate column")
        for name, cols in (("velocities", self.velocities), ("coord_names", self.coord_names)):
            if cols is not None and len(cols) != dof:
                raise InputError(f"import: {name} needs {dof} entries (one per coordinate), got {len(cols)}")
        if self.inputs is not None and self.currents is not None:
            raise InputError("import: give inputs (torques) or currents (with drive_gains), not both")
        if self.currents is not None:
            gains = self.drive_gains
            if gains is None or len(gains) != len(self.currents):
                raise InputError(f"import: currents need drive_gains, one per current column ({len(self.currents)}; "
                                 "N m per A)")
            if not all(math.isfinite(float(g)) and float(g) != 0 for g in gains):
                raise InputError(f"import: drive_gains must be finite and non-zero, got {list(gains)}")
        elif self.drive_gains is not None:
            raise InputError("import: drive_gains go with currents (motor current columns)")
        n_u = len(self.input_columns)
        if self.input_names is not None and len(self.input_names) != n_u:
            raise InputError(f"import: input_names needs {n_u} entries, got {len(self.input_names)}")
        if not (math.isfinite(self.window_context) and self.window_context >= 0):
            raise InputError(f"import: window_context must be >= 0 s, got {self.window_context}")
        if self.robot is not None:
            self._arm_joints()
        if self.angle_units not in ANGLE_UNITS:
            raise InputError(f"import: angle_units must be one of {', '.join(ANGLE_UNITS)}, got '{self.angle_units}'")
        for name, known in (("time_units", TIME_UNITS), ("length_units", LENGTH_UNITS), ("decimal", DECIMALS)):
            if getattr(self, name) not in known:
                raise InputError(f"import: {name} must be one of {', '.join(known)}, got {getattr(self, name)!r}")
        if self.delimiter is not None:
            sep = _separator(self.delimiter)
            if sep is None:
                raise InputError(f"import: delimiter must be one character (or 'tab'), not a quote, '#' or a line "
                                 f"break; got {self.delimiter!r}")
            if sep == "," and self.decimal == ",":
                raise InputError("import: decimal ',' needs a delimiter other than ','")
        for name in ("dt", "max_gap"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise InputError(f"import: {name} must be positive, got {value}")

    @property
    def input_columns(self) -> list[str]:
        return list(self.inputs or self.currents or [])

    def _arm_joints(self) -> tuple[str, ...]:
        """The joint names of the ``robot`` description (its coordinates, in order), checked against the
        coordinate columns and names."""
        from ..robots.mujoco_arm import MujocoArm

        joints = MujocoArm(self.robot).joint_names
        if len(joints) != len(self.coordinates):
            raise InputError(f"import: robot {self.robot} has {len(joints)} joints ({', '.join(joints)}); "
                             f"{len(self.coordinates)} coordinate columns are named")
        if self.coord_names is not None and tuple(self.coord_names) != joints:
            raise InputError(f"import: coord_names {list(self.coord_names)} are not the joints of robot "
                             f"{self.robot} in its order ({', '.join(joints)}): list the coordinate columns in "
                             "the joints' order and name them so")
        return joints

    def parameter_table(self, names: list[str]) -> tuple[dict, np.ndarray]:
        """``(declaration, values (N, P))``: the parameters' names, units and kinds, and each recording's
        values (a tool's by its name; zeros for a recording without values)."""
        if not self.parameters:
            return {"names": [], "units": [], "kinds": []}, np.zeros((len(names), 0))
        spec = dict(self.parameters)
        unknown = sorted(set(spec) - {"names", "units", "kinds", "values", "tools"})
        if unknown:
            raise InputError(f"import: parameters take names, units, kinds, values and tools, got {', '.join(unknown)}")
        values, tools = dict(spec.get("values") or {}), dict(spec.get("tools") or {})
        rows = {}
        for rec, value in values.items():
            if rec not in names:
                raise InputError(f"import: parameters given for an unknown recording {rec!r} (recordings: "
                                 f"{', '.join(names)})")
            if isinstance(value, str):
                if value not in tools:
                    raise InputError(f"import: recording {rec!r} names tool {value!r}, which parameters.tools does "
                                     f"not define ({', '.join(tools) or 'none'})")
                value = tools[value]
            rows[rec] = [float(v) for v in value]
        width = {len(r) for r in rows.values()}
        if len(width) > 1:
            raise InputError(f"import: every recording's parameters need the same number of values, got "
                             f"{sorted(width)}")
        if self.robot is not None:
            P = width.pop() if width else 4
            default = list(ARM_PARAMS[:P]) if P in (4, 10) else None
            units = ["kg", "m", "m", "m"] + ["kg m^2"] * 6
            kinds = ["nonnegative", "real", "real", "real"] + ["real"] * 6
            names_p = spec.get("names", default)
            if names_p is None:
                raise InputError(f"import: a robot arm's parameters are its payload: 4 values (mass, centre of "
                                 f"mass) or 10 (and the inertia); got {P}")
            decl = {"names": list(names_p), "units": list(spec.get("units", units[:P])),
                    "kinds": list(spec.get("kinds", kinds[:P]))}
        else:
            P = width.pop() if width else len(spec.get("names", []))
            decl = {"names": list(spec.get("names", [f"p{i + 1}" for i in range(P)])),
                    "units": list(spec.get("units", [""] * P)), "kinds": list(spec.get("kinds", ["real"] * P))}
        if any(len(decl[k]) != P for k in decl):
            raise InputError(f"import: parameters names, units and kinds need {P} entries each (the values' count)")
        table = np.zeros((len(names), P))
        for i, rec in enumerate(names):
            if rec in rows:
                table[i] = rows[rec]
        if not np.isfinite(table).all():
            raise InputError("import: a parameter value is NaN or Inf")
        return decl, table

    def system(self, parameters: dict | None = None):
        """The ``MeasuredSystem`` these recordings declare (``parameters``: the declaration of
        ``parameter_table``)."""
        dof = len(self.coordinates)
        n_u = len(self.input_columns)
        coord_names = self.coord_names
        description = None
        if self.robot is not None:
            from ..robots.description import ArmDescription

            coord_names = list(self._arm_joints())
            description = ArmDescription.of(self.robot).config()
        decl = parameters or {}
        return get_system("measured", dof=dof, angle_mask=self.angle_mask, coord_names=coord_names,
                          input_names=self.input_names or [f"tau{i + 1}" for i in range(n_u)],
                          input_matrix=self.input_matrix, friction=self.friction, joint_map=self.joint_map,
                          coulomb_velocity=self.coulomb_velocity, angle_combinations=self.angle_combinations,
                          conventions=self.conventions, label=self.label, param_names=decl.get("names", ()),
                          param_units=decl.get("units"), param_kinds=decl.get("kinds"), description=description)


def recording_name(path: str | Path) -> str:
    """A recording's name: its file's name without ``.gz``, then without ``.csv``, ``.tsv``, ``.txt`` or
    ``.dat`` (``run.csv.gz`` and ``run.csv``: ``run``; ``exp_2024.05.01_a.csv``: ``exp_2024.05.01_a``)."""
    name = Path(path).name
    if name.lower().endswith(".gz") and len(name) > 3:
        name = name[:-3]
    ext = next((e for e in EXTENSIONS if name.lower().endswith(e)), None)
    return name[:-len(ext)] if ext is not None and len(name) > len(ext) else name


def _separator(delimiter: str | None) -> str | None:
    """A ``delimiter`` setting as the character it is (``tab``: a tab; None: detected per file), or None
    if it cannot be one."""
    sep = "\t" if delimiter in ("tab", "\\t") else delimiter
    return sep if isinstance(sep, str) and len(sep) == 1 and sep not in "\"#\r\n" else None


def _shown(sep: str) -> str:
    return "tab" if sep == "\t" else repr(sep)


def read_csv_columns(path: Path, columns: list[str], delimiter: str | None = None, decimal: str = "auto") -> np.ndarray:
    """The named columns of a CSV file (``.csv``, or gzip-compressed ``.csv.gz``; comment lines starting
    with ``#`` before the header) as float64 ``(rows, len(columns))``; errors name the file and line
    (``read_csv_table`` says which; ``delimiter``, ``decimal``: as ``ImportSpec``'s)."""
    return read_csv_table(path, columns, delimiter, decimal)[0]


_read_csv = read_csv_columns  # the former private name, kept for callers


def read_csv_table(path: Path, columns: list[str], delimiter: str | None = None,
                   decimal: str = "auto") -> tuple[np.ndarray, np.ndarray]:
    """``(values (rows, len(columns)) float64, lines (rows,) int64)``: the named columns of a CSV file
    and the line of the file each data row ends on. The delimiter is ``delimiter`` (one character or
    ``tab``), or else the header's: ``;`` if it holds one, else a tab if it holds one, else ``,``;
    ``decimal`` (``auto``, ``.``, ``,``): ``auto`` reads decimal commas where the delimiter is not ``,``.
    Text is UTF-8 (a byte-order mark is dropped), gzip-compressed where the name ends in ``.gz``."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    import gzip

    opener = gzip.open if path.suffix == ".gz" else open
    try:
        return _parse_csv(path, opener, columns, delimiter, decimal)
    except EOFError:
        raise InputError(f"{path}: truncated (the compressed file ends early)") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text CSV file (undecodable bytes)") from None
    except csv.Error as err:
        raise InputError(f"{path}: not a readable CSV file ({err})") from None
    except OSError as err:  # gzip.BadGzipFile, ...
        raise InputError(f"{path}: cannot read it ({err})") from None


def _parse_csv(path: Path, opener, columns: list[str], delimiter: str | None,
               decimal: str) -> tuple[np.ndarray, np.ndarray]:
    with opener(path, "rt", encoding="utf-8-sig", newline="") as fh:
        before = 0  # comment and blank lines before the header
        for header_line in fh:
            if header_line.strip() and not header_line.lstrip().startswith("#"):
                break
            before += 1
        else:
            raise InputError(f"{path}: the file is empty" if not before else
                             f"{path}: no header row (only comment or blank lines)")
        sep = _separator(delimiter) if delimiter is not None else (
            ";" if ";" in header_line else "\t" if "\t" in header_line else ",")
        if sep is None:
            raise InputError(f"{path}: delimiter must be one character (or 'tab'), got {delimiter!r}")
        if decimal not in DECIMALS:
            raise InputError(f"{path}: decimal must be one of {', '.join(DECIMALS)}, got {decimal!r}")
        if decimal == "," and sep == ",":
            raise InputError(f"{path}: decimal ',' needs a delimiter other than ',' (the header is read with ',')")
        commas = decimal == "," or (decimal == "auto" and sep != ",")
        reader = csv.reader(itertools.chain([header_line], fh), delimiter=sep)
        header = [h.strip() for h in next(reader)]
        at = before + 1
        missing = [c for c in dict.fromkeys(columns) if c not in header]
        if missing:
            hint = "; set delimiter if the file uses another" if len(header) == 1 else ""
            raise InputError(f"{path}: no column {', '.join(repr(c) for c in missing)} in the header on line {at} "
                             f"(delimiter {_shown(sep)}; columns: {', '.join(header)}){hint}")
        twice = [c for c in dict.fromkeys(columns) if header.count(c) > 1]
        if twice:
            raise InputError(f"{path}: line {at}: the header names column {twice[0]!r} {header.count(twice[0])} times "
                             "(which one is meant?): rename the others")
        index = [header.index(c) for c in columns]
        rows, lines = [], []
        for row in reader:
            if not row or not "".join(row).strip():
                continue
            line = before + reader.line_num  # the file's line (the row's last, if a quoted cell spans lines)
            try:
                values = [float(row[i].replace(",", ".")) if commas else float(row[i]) for i in index]
            except (ValueError, IndexError):
                raise InputError(_cell_error(path, line, row, header, columns, index, commas)) from None
            bad = [c for c, v in zip(columns, values, strict=True) if not math.isfinite(v)]
            if bad:
                raise InputError(f"{path}: line {line}: NaN or Inf in column {bad[0]!r}")
            rows.append(values)
            lines.append(line)
    if len(rows) < 2:
        raise InputError(f"{path}: fewer than two data rows")
    return np.asarray(rows, dtype=np.float64), np.asarray(lines, dtype=np.int64)


def _cell_error(path: Path, line: int, row: list[str], header: list[str], columns: list[str], index: list[int],
                commas: bool) -> str:
    """The one line that names the first cell of ``row`` (of the named ``columns``) that is not a number."""
    for c, i in zip(columns, index, strict=True):
        if i >= len(row):
            return (f"{path}: line {line}: no value in column {c!r} (the row has {len(row)} cells, the header "
                    f"{len(header)})")
        cell = row[i].strip()
        try:
            float(cell.replace(",", ".") if commas else cell)
        except ValueError:
            if not cell:
                return f"{path}: line {line}: column {c!r} is empty"
            hint = (" (decimal commas are read with decimal ',' or 'auto' and a delimiter other than ',')"
                    if "," in cell and not commas else "")
            return f"{path}: line {line}: column {c!r}: {cell!r} is not a number{hint}"
    return f"{path}: line {line}: a value of {', '.join(columns)} is missing or not a number"


def _checked_time(path: Path, t: np.ndarray, max_gap: float | None, lines: np.ndarray | None = None) -> dict:
    """Raise for a time that does not increase or gaps beyond ``max_gap`` (default ``MAX_GAP_INTERVALS``
    median intervals; the count and the largest named), naming the line of the file (``lines``: each
    sample's; default: the header on line 1, one sample a line); else the recording's timing: samples,
    duration, median, smallest and largest interval, and the gaps above twice the median (count,
    largest, their total), which resampling interpolates across."""
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
    gaps = np.nonzero(steps > limit)[0]
    if gaps.size:
        i = int(gaps[0])
        more = f" ({gaps.size} such gaps, the largest {steps.max():.4g} s)" if gaps.size > 1 else ""
        raise InputError(f"{path}: line {lines[i + 1]}: a gap of {steps[i]:.4g} s after t = {t[i]:.6g} s exceeds "
                         f"max_gap {limit:.4g} s{more}: too long to interpolate across (split the recording there, or "
                         "raise max_gap)")
    long = steps[steps > 2 * median]
    return {"samples": len(t), "duration_s": float(t[-1] - t[0]), "median_interval_s": median,
            "min_interval_s": float(steps.min()), "max_interval_s": float(steps.max()),
            "gaps": int(long.size), "largest_gap_s": float(long.max()) if long.size else 0.0,
            "gap_seconds": float(long.sum()), "max_gap_s": float(limit)}


def resampling_report(provenance: dict) -> list[str]:
    """One line per recording of what the import did to its timing (from the file's ``provenance``)."""
    lines = []
    for src in provenance.get("sources", []):
        timing = src.get("timing")
        if not timing:
            continue
        gaps = (f"{timing['gaps']} gaps over twice the median interval (largest {1e3 * timing['largest_gap_s']:.3g} "
                f"ms, {1e3 * timing['gap_seconds']:.3g} ms in all) interpolated across" if timing["gaps"]
                else "no gaps")
        lines.append(f"{src['file']}: {timing['samples']} samples over {timing['duration_s']:.4g} s, intervals "
                     f"{1e3 * timing['min_interval_s']:.3g}-{1e3 * timing['max_interval_s']:.3g} ms (median "
                     f"{1e3 * timing['median_interval_s']:.3g} ms); {gaps}; resampled to "
                     f"{src['resampled_points']} points")
    return lines


WINDOW = re.compile(r"^(?P<name>[^\[\]]+)\[(?P<start>[^:\]]*):(?P<end>[^\]]*)\]$")


def _entries(names: list[str], split, seed: int, durations: list[float]) -> tuple[list[tuple], dict]:
    """The dataset's entries ``(recording index, start s or None, end s or None, name)`` and the split
    over them: whole recordings (named, or seeded fractions), or time windows ``name[start:end]``."""
    split = _split_form(split)
    if not isinstance(split, dict) or not any(WINDOW.match(str(item).strip()) for items in split.values()
                                              for item in (items or [])):
        entries = [(i, None, None, n) for i, n in enumerate(names)]  # every recording, in the files' order
        return entries, _by_name(names, split) if isinstance(split, dict) else _fractions(names, split, seed)
    entries, out = [], {}
    for part in ("train", "val", "test"):
        out[part] = []
        for item in split.get(part, []) or []:
            m = WINDOW.match(str(item).strip())
            name = m["name"].strip() if m else str(item)
            if name not in names:
                raise InputError(f"split: unknown recording {name!r} (recordings: {', '.join(names)})")
            i = names.index(name)
            start = end = None
            if m:
                try:
                    start = float(m["start"]) if m["start"].strip() else None
                    end = float(m["end"]) if m["end"].strip() else None
                except ValueError:
                    raise InputError(f"split: window {item!r}: start and end must be seconds") from None
                if start is not None and end is not None and end <= start:
                    raise InputError(f"split: window {item!r} ends before it starts")
            entry = (i, start, end, str(item).strip() if m else name)
            if entry in entries:
                raise InputError(f"split: {entry[3]!r} is named twice")
            out[part].append(len(entries))
            entries.append(entry)
    if not out["train"]:
        raise InputError("split: no training recording")
    for a in range(len(entries)):  # entries of different splits may not share any time of a recording
        for b in range(a + 1, len(entries)):
            (i, s0, e0, n0), (j, s1, e1, n1) = entries[a], entries[b]
            part_a = next(p for p, idx in out.items() if a in idx)
            part_b = next(p for p, idx in out.items() if b in idx)
            lo0, hi0 = s0 or 0.0, durations[i] if e0 is None else e0
            lo1, hi1 = s1 or 0.0, durations[j] if e1 is None else e1
            if i == j and part_a != part_b and lo0 < hi1 and lo1 < hi0:
                raise InputError(f"split: {n0!r} ({part_a}) and {n1!r} ({part_b}) overlap: a held-out window must "
                                 "not share samples with training")
    return entries, {k: np.asarray(v, dtype=np.int64) for k, v in out.items()}


def _by_name(names: list[str], split: dict) -> dict:
    known = set(names)
    out = {}
    for part in ("train", "val", "test"):
        chosen = list(split.get(part, []) or [])
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


def _split_form(split):
    """``split`` as ``_entries`` reads it: a dict of fractions (``{train: 0.7, val: 0.15, test: 0.15}``)
    becomes the list of three; a dict's values must be lists (or one name); anything else is refused."""
    if not isinstance(split, dict):
        return split
    unknown = sorted(set(split) - {"train", "val", "test"})
    if unknown:
        raise InputError(f"split: unknown part(s) {', '.join(map(repr, unknown))} (train, val, test)")
    if split and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in split.values()):
        return [float(split.get(part, 0.0)) for part in ("train", "val", "test")]
    out = {}
    for part, items in split.items():
        if isinstance(items, str):
            items = [items]
        if items is not None and not isinstance(items, (list, tuple)):
            raise InputError(f"split: {part} must be a list of recording names or windows (or every part a "
                             f"fraction), got {items!r}")
        out[part] = items
    return out


def _fractions(names: list[str], split, seed: int) -> dict:
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
    dof, n_u = system.dof, system.num_inputs
    columns = [spec.time, *spec.coordinates, *(spec.velocities or []), *spec.input_columns]
    angle = np.array(system.angle_mask)
    unit = np.where(angle, ANGLE_UNITS[spec.angle_units], LENGTH_UNITS[spec.length_units])
    gains = np.asarray(spec.drive_gains, dtype=np.float64) if spec.currents else np.ones(n_u)
    records, timing = [], []
    for f in files:
        raw, lines = read_csv_table(f, columns, spec.delimiter, spec.decimal)
        if spec.time_units != "s":
            raw[:, 0] = raw[:, 0] / TIME_UNITS[spec.time_units]
        timing.append(_checked_time(f, raw[:, 0], spec.max_gap, lines))
        records.append(raw)
    medians = [tm["median_interval_s"] for tm in timing]
    own = [round(m, 4) or m for m in medians]  # each recording's default dt alone (jitter moves a median by ~1 %)
    if spec.dt is None and max(medians) > (1 + DT_SPREAD) * min(medians) and len(set(own)) > 1:
        listing = ", ".join(f"{f.name} {1e3 * m:.4g} ms" for f, m in zip(files, medians, strict=True))
        raise InputError(f"import: the recordings' median sampling intervals differ by more than "
                         f"{100 * DT_SPREAD:g} % ({listing}): set dt, the resampling interval in s (--dt; e.g. "
                         f"{min(medians):.4g} for the fastest), rather than thin the faster recordings")
    dt = spec.dt or own[0]
    resampled = []
    for raw in records:
        t = raw[:, 0]
        grid = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1)
        resampled.append(np.stack([np.interp(grid, t, raw[:, j]) for j in range(1, raw.shape[1])], -1))
    entries, splits = _entries(stems, spec.split, spec.seed, [len(r) * dt for r in resampled])
    pieces, windows = [], []
    context = int(round(spec.window_context / dt))
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
    settings = {k: v for k, v in asdict(spec).items()}
    settings["dt"] = dt
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
                                "drive_gains": [float(g) for g in gains]}
    input_units = list(system.input_units)
    units = {"t": "s", "q": list(system.coord_units), "qd": [u + "/s" for u in system.coord_units],
             "params": list(system.param_units), "tau": input_units}
    attrs = {"scene": system.name, "scene_json": json.dumps(system.describe(), sort_keys=True),
             "conventions": system.conventions, "units": json.dumps(units), "gravity": float("nan"),
             "param_names": json.dumps(list(system.param_names)), "measured": True,
             "velocities_measured": bool(spec.velocities), "recordings": json.dumps([e[3] for e in entries]),
             "provenance": json.dumps(provenance), "targets": "none (measured)",
             "package_version": __version__, "created": datetime.now(timezone.utc).isoformat(timespec="seconds")}
    if n_u:
        attrs["inputs"] = json.dumps({"names": list(system.input_names), "units": input_units,
                                      "input_matrix": system.input_matrix().tolist(),
                                      "hold": "measured; linearly interpolated onto the grid, held over each step"})
    return write_dataset(output, arrays, splits, attrs, overwrite=overwrite)
