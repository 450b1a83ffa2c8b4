"""What ``lnn-torch import`` reads from recordings and how (``ImportSpec``): the columns, units, the
measured system, the split, the known parameters per recording; the units' tables and the limits of
an import (the importer, ``lnn_torch.data.importer``, states the format)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..systems import get_system
from .tables import DECIMALS, separator

ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180}
LENGTH_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}  # metres per unit
TIME_UNITS = {"s": 1, "ms": 1_000, "us": 1_000_000, "ns": 1_000_000_000}  # stamps per second (divided by)
ARM_PARAMS = ("payload_mass", "payload_x", "payload_y", "payload_z", "payload_ixx", "payload_iyy", "payload_izz",
              "payload_ixy", "payload_ixz", "payload_iyz")
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
            sep = separator(self.delimiter)
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
