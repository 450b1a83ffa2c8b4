"""What ``lnn-torch import`` reads from recordings and how (``ImportSpec``): the columns, units, the
measured system, the split, the known parameters per recording; the units' tables and the limits of
an import (the importer, ``lnn_torch.data.importer``, states the format)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError, as_number, is_number
from ..systems import get_system
from .tables import DECIMALS, separator

ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180}
LENGTH_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}  # metres per unit
TIME_UNITS = {"s": 1, "ms": 1_000, "us": 1_000_000, "ns": 1_000_000_000}  # stamps per second (divided by)
ARM_PARAMS = ("payload_mass", "payload_x", "payload_y", "payload_z", "payload_ixx", "payload_iyy", "payload_izz",
              "payload_ixy", "payload_ixz", "payload_iyz")
MIN_SAMPLES = 16  # the fewest samples of an entry (a recording or a window) after resampling
DT_SPREAD = 0.02  # the relative spread of median intervals beyond which the default dt needs them to round alike
STREAMS = ("position", "velocity", "effort")  # the fields of a sensor_msgs/JointState message
STAMPS = ("auto", "header", "receive", "sequence")
REPEATED_ROWS = ("drop", "keep")


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
        delimiter: the files' delimiter, one character (``tab`` for a tab; ``whitespace`` for columns separated
            by runs of spaces or tabs, as aligned ``.dat`` files); default (None): each file's header's, ``;`` if
            it holds one, else a tab if it holds one, else ``,``.
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
            coordinates are then its joints in its order (``coord_names`` its joint names); without
            ``coordinates`` or ``joints``, the columns (or a bag's joints) named as its joints.
        parameters: known parameters per recording: ``{"names": [...], "units": [...], "kinds": [...],
            "values": {recording: [...] or a tool's name}, "tools": {name: [...]}}``; for a robot arm
            the names default to the payload at its flange, ``payload_mass, payload_x, payload_y,
            payload_z`` (kg, m; ten values with the inertia about the centre of mass). A recording
            without values carries zeros (no payload). A robot arm's tool may declare only what is
            known, ``{mass: 1.2}``, ``{mass, com: [x, y, z]}`` or ``{}`` (``inertia``: six values about
            the centre of mass, payloads of ten): the rest is identified at import from the recordings
            that carry it (``lnn_torch.data.import_tools``).
        tool_targets: the derivative estimate for that identification (``lnn_torch.data.derivatives``
            settings; default a 10 Hz Butterworth of the measured velocities).
        dt: resampling interval, s (default: the median interval of the first recording, rounded to 0.1
            ms; refused, asking for ``dt``, where the recordings' median intervals differ by over 2 % and
            round to different intervals).
        max_gap: the longest interval between two time stamps interpolated across, s (default 25 x the
            median): a window of the split (or a whole recording) may not cross a longer gap.
        split: ``{"train": [...], "val": [...], "test": [...]}`` of recording names (file names without
            ``.gz`` and ``.csv``/``.tsv``/``.txt``/``.dat``) or time windows ``"name[start:end]"``
            (seconds from the recording's first sample, not values of its time column; an end may be
            left out), or three fractions of the recordings (seeded by ``seed``): ``[0.7, 0.15, 0.15]``
            or ``{"train": 0.7, "val": 0.15, "test": 0.15}``. Every entry needs 16 samples or more.
        window_context: seconds of the recording kept on each side of a time window (for filters).
        label: the system's name (recorded).

    ROS bags (``.db3``, ``.mcap``, ``.bag`` or a rosbag2 folder; ``lnn_torch.data.bags``) of
    ``sensor_msgs/JointState``: ``coordinates``, ``velocities`` and ``inputs`` (or ``currents``) name the
    bag's *joints* whose position, velocity and effort they take (velocities and inputs default to the
    coordinates' joints, for the ``streams`` imported); or ``joints`` maps them:

    Attributes:
        topic: the bag's topic of ``sensor_msgs/JointState`` messages (default ``/joint_states``).
        joints: ``{bag joint name: model coordinate name}``, instead of ``coordinates``: the coordinates
            are then the model's in its order (a robot's joints; else ``coord_names``; else the mapping's
            order), their velocities and efforts the velocities and inputs (for the ``streams``
            imported). Every model coordinate must be mapped; a joint of the bag that is not mapped is
            refused unless listed in ``ignore_joints``.
        ignore_joints: joints of the bag not imported (e.g. a gripper's fingers).
        streams: the JointState fields imported: ``position`` and any of ``velocity``, ``effort`` (default
            all three).
        effort_topic: the topic of the efforts where they come on another topic than the positions (a
            ``sensor_msgs/JointState`` of the same joints, e.g. ``/joint_efforts``; default None: on ``topic``):
            each effort linearly interpolated to the position messages' times (both topics timed alike by
            ``stamps``); position messages before the first effort, after the last or in a gap of the
            efforts over five of their intervals are left out and counted.
        stamps: a bag's time: ``header`` (the messages' header stamps), ``receive`` (the bag's receive
            times: when the recorder got each message; refused where they come in bursts), ``sequence``
            (message k at k ``dt``: a publisher at a fixed rate that lost no message, whose stamps are unset)
            or ``auto`` (default: the header stamps unless every one is zero).
        repeated_rows: a row identical to the previous one in every imported value (a stale message:
            the publisher sent the last state again) is ``drop``-ped or ``keep``-t; default: dropped in a
            bag, kept in a CSV (where it is reported). A row at rest (every measured velocity exactly
            zero; without velocities, the next row's positions the same) is kept; one that also repeats
            the time stamp is dropped even then.
        torque_delay: the delay of the torque (input) stream behind the positions, s: estimated and
            reported (default None: not applied), ``auto`` (the estimate applied), a number (that delay
            applied: each input at t replaced by its value at t + delay) or ``off`` (not estimated).
        torque_delay_range: the delays searched, +- s (default the larger of 5 samples and 50 ms).
    """

    coordinates: list[str] | None = None
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
    topic: str = "/joint_states"
    effort_topic: str | None = None
    joints: dict | None = None
    ignore_joints: list[str] | None = None
    streams: list[str] | None = None
    stamps: str = "auto"
    repeated_rows: str | None = None
    torque_delay: float | str | None = None
    torque_delay_range: float | None = None
    tool_targets: dict | None = None

    def __post_init__(self) -> None:
        self._types()
        self._bag_fields()
        if self.joints is not None:
            self._mapped_joints()
        elif self.coordinates is None and self.robot is not None:  # the columns or bag joints named as the robot's
            from ..robots.mujoco_arm import MujocoArm

            self.coordinates = list(MujocoArm(self.robot).joint_names)
        if self.coordinates is None:
            raise InputError("import: name the coordinate columns (coordinates), or a bag's joints (joints), or "
                             "give the robot whose joints they are named as")
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
        # (no inputs named: a bag's default to the coordinates' efforts, for_bags; a CSV's are refused on import)
        if self.input_names is not None and n_u and len(self.input_names) != n_u:
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
        if self.length_units != "m" and (self.angle_mask is None or all(self.angle_mask)) and self.robot is None:
            # (a cart's millimetres were read as degrees without a word)
            raise InputError(f"import: length_units is {self.length_units}, but every coordinate is an angle: mark the "
                             "lengths false in angle_mask (e.g. [false, true] for a cart's position and an angle)")
        if self.delimiter is not None:
            sep = separator(self.delimiter)
            if sep is None:
                raise InputError(f"import: delimiter must be one character (or 'tab' or 'whitespace'), not a quote, "
                                 f"'#' or a line break; got {self.delimiter!r}")
            if sep == "," and self.decimal == ",":
                raise InputError("import: decimal ',' needs a delimiter other than ','")
        for name in ("dt", "max_gap"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise InputError(f"import: {name} must be positive, got {value}")

    def _types(self) -> None:
        """Each field of the kind it must be, refused in one line naming it (a string where a number or a list
        belongs failed later with a traceback, or was split into letters)."""
        for name in ("dt", "max_gap", "window_context", "coulomb_velocity", "torque_delay_range"):
            value = as_number(getattr(self, name))  # (a number given as text)
            setattr(self, name, value)
            if value is not None and not is_number(value):
                unit = "rad/s" if name == "coulomb_velocity" else "s"
                raise InputError(f"import: {name} must be a number ({unit}), got {value!r}")
        if not isinstance(self.seed, int) or isinstance(self.seed, bool):
            raise InputError(f"import: seed must be a whole number, got {self.seed!r}")
        if not isinstance(self.friction, bool):
            raise InputError(f"import: friction must be true or false, got {self.friction!r}")
        for name in ("coordinates", "velocities", "inputs", "currents", "coord_names", "input_names", "ignore_joints"):
            value = getattr(self, name)
            if value is not None and (not isinstance(value, (list, tuple)) or not all(isinstance(x, str)
                                                                                      for x in value)):
                what = "joint names" if name == "ignore_joints" else "column names"
                raise InputError(f"import: {name} must be a list of {what}, got {value!r}")
        if self.drive_gains is not None and (not isinstance(self.drive_gains, (list, tuple))
                                             or not all(is_number(g) for g in self.drive_gains)):
            raise InputError(f"import: drive_gains must be a list of numbers (N m per A), got {self.drive_gains!r}")
        if self.torque_delay is False:  # YAML reads an unquoted off as false
            self.torque_delay = "off"

    @property
    def input_columns(self) -> list[str]:
        return list(self.inputs or self.currents or [])

    @property
    def delay_mode(self) -> str:
        """``estimate`` (reported only), ``auto``, ``off`` or ``fixed`` (``torque_delay`` s applied)."""
        if self.torque_delay is None:
            return "estimate"
        return self.torque_delay if isinstance(self.torque_delay, str) else "fixed"

    def _bag_fields(self) -> None:
        """Check the fields for ROS bags (their types and values)."""
        if not isinstance(self.topic, str) or not self.topic.strip("/"):
            raise InputError(f"import: topic must name a topic, e.g. /joint_states; got {self.topic!r}")
        other = self.effort_topic
        if other is not None and (not isinstance(other, str) or not other.strip("/")):
            raise InputError(f"import: effort_topic must name a topic, e.g. /joint_efforts; got {other!r}")
        if other is not None and other.strip("/") == self.topic.strip("/"):
            raise InputError(f"import: effort_topic names the topic of the positions ({self.topic}): leave it out")
        if self.streams is not None:
            streams = list(self.streams)
            unknown = [x for x in streams if x not in STREAMS]
            if unknown or "position" not in streams or len(set(streams)) != len(streams):
                raise InputError(f"import: streams lists position and any of velocity, effort (the JointState "
                                 f"fields imported), got {streams}")
        for name, known in (("stamps", STAMPS), ("repeated_rows", (None, *REPEATED_ROWS))):
            if getattr(self, name) not in known:
                raise InputError(f"import: {name} must be one of {', '.join(str(k) for k in known if k)}, got "
                                 f"{getattr(self, name)!r}")
        delay = self.torque_delay
        if isinstance(delay, str):
            try:
                self.torque_delay = delay = float(delay)  # a number given as text (the command line)
            except ValueError:
                if delay not in ("auto", "off"):
                    raise InputError(f"import: torque_delay must be a delay in s, auto or off; got {delay!r}") from None
        if delay is not None and not isinstance(delay, str):
            if isinstance(delay, bool) or not math.isfinite(float(delay)):
                raise InputError(f"import: torque_delay must be a delay in s, auto or off; got {delay!r}")
            self.torque_delay = float(delay)
        span = self.torque_delay_range
        if span is not None and not (math.isfinite(span) and span > 0):
            raise InputError(f"import: torque_delay_range must be positive (s), got {span}")
        for name in ("ignore_joints",):
            value = getattr(self, name)
            if value is not None and not all(isinstance(x, str) for x in value):
                raise InputError(f"import: {name} must list joint names, got {value!r}")

    def _mapped_joints(self) -> None:
        """``coordinates`` (the bag's joints) and ``coord_names`` (the model's) from ``joints``, in the
        model's order: a robot's joints, else ``coord_names``, else the mapping's; every model coordinate
        mapped once (the ones left over, or mapped twice, named)."""
        joints = self.joints
        if not isinstance(joints, dict) or not joints or not all(
                isinstance(k, str) and isinstance(v, str) for k, v in joints.items()):
            raise InputError(f"import: joints maps a bag's joint names to the model's coordinates ({{bag name: "
                             f"model name}}), got {joints!r}")
        names = list(joints.values())
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise InputError(f"import: joints maps several bag joints to {', '.join(twice)}")
        if self.robot is not None:
            from ..robots.mujoco_arm import MujocoArm

            order, whose = list(MujocoArm(self.robot).joint_names), f"a joint of robot {self.robot}"
        elif self.coord_names is not None:
            order, whose = list(self.coord_names), "in coord_names"
        else:
            order, whose = names, ""
        unmapped = [n for n in order if n not in names]
        unknown = [f"{k} -> {v}" for k, v in joints.items() if v not in order]
        if unmapped or unknown:
            parts = ([f"no bag joint is mapped to {', '.join(unmapped)}"] if unmapped else []) + (
                [f"{', '.join(unknown)}: not {whose} "
                 f"({', '.join(order)})"] if unknown else [])
            raise InputError(f"import: joints: {'; '.join(parts)}")
        by_model = {v: k for k, v in joints.items()}
        mapped = [by_model[n] for n in order]
        if self.coordinates is not None and list(self.coordinates) != mapped:
            raise InputError("import: give a bag's joints either as joints (mapped to the model's names) or as "
                             "coordinates, not both")
        self.coordinates = mapped
        if self.coord_names is None:
            self.coord_names = list(order)
        streams = self.streams or STREAMS
        if "velocity" in streams and self.velocities is None:
            self.velocities = list(mapped)  # a bag's: the velocities of the same joints
        if "effort" in streams and self.inputs is None and self.currents is None:
            self.inputs = list(mapped)

    def for_bags(self) -> ImportSpec:
        """This spec for ROS bags: velocities and inputs default to the coordinates' joints (for the
        ``streams`` imported), repeated rows to ``drop``."""
        import dataclasses

        streams = list(self.streams or STREAMS)
        velocities, inputs = self.velocities, self.inputs
        if "velocity" in streams:
            velocities = list(self.coordinates) if velocities is None else velocities
        elif velocities:
            raise InputError("import: velocities are named, but streams leaves velocity out")
        if "effort" in streams:
            if inputs is None and self.currents is None:
                inputs = list(self.coordinates)
        elif self.input_columns:
            raise InputError("import: inputs (or currents) are named, but streams leaves effort out")
        elif self.effort_topic:
            raise InputError("import: effort_topic names the efforts' topic, but streams leaves effort out")
        return dataclasses.replace(self, velocities=velocities, inputs=inputs, streams=streams,
                                   repeated_rows=self.repeated_rows or "drop")

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
        values (a tool's by its name, its unknown entries zero until identified; zeros for a recording
        without values)."""
        if not self.parameters:
            return {"names": [], "units": [], "kinds": []}, np.zeros((len(names), 0))
        spec = dict(self.parameters)
        unknown = sorted(set(spec) - {"names", "units", "kinds", "values", "tools"})
        if unknown:
            raise InputError(f"import: parameters take names, units, kinds, values and tools, got {', '.join(unknown)}")
        P, tools = self._width(), self.tools(names)
        rows = {}
        for rec, value in dict(spec.get("values") or {}).items():
            if rec not in names:
                raise InputError(f"import: parameters given for an unknown recording {rec!r} (recordings: "
                                 f"{', '.join(names)})")
            rows[rec] = tools[value].known_row().tolist() if isinstance(value, str) else [float(v) for v in value]
        width = {len(r) for r in rows.values()}
        if len(width) > 1 or (width and width.pop() != P):
            raise InputError(f"import: every recording's parameters need the same number of values, got "
                             f"{sorted({len(r) for r in rows.values()})}")
        if self.robot is not None:
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

    def _width(self) -> int:
        """The parameters per recording: the values' (given as lists), else ten where a tool declares an
        inertia or ``names`` has ten, else four for a robot arm's payload (else ``names``' count)."""
        spec = dict(self.parameters or {})
        lists = [v for v in list((spec.get("values") or {}).values()) + list((spec.get("tools") or {}).values())
                 if not isinstance(v, (str, dict))]
        if lists:
            return len(lists[0])
        if "names" in spec:
            return len(spec["names"])
        if self.robot is None:
            return 0
        return 10 if any(isinstance(v, dict) and "inertia" in v for v in (spec.get("tools") or {}).values()) else 4

    def tools(self, names: list[str] | None = None) -> dict:
        """The named tools ``{name: identification.payload.Tool}`` (a list of values: known; a mapping of what
        is known, ``mass``, ``com``, ``inertia``: the rest identified at import; robot arms only), each
        recording's named tool checked against them."""
        from ..robots.tools import Tool

        spec = dict(self.parameters or {})
        declared = dict(spec.get("tools") or {})
        width = self._width()
        tools = {}
        for name, value in declared.items():
            if isinstance(value, dict) and self.robot is None:
                raise InputError(f"import: tool {name!r} leaves parameters to identify: only a robot arm's payloads "
                                 "are identified (give its values as a list)")
            if not isinstance(value, (list, tuple, dict)):
                raise InputError(f"import: tool {name!r} needs a list of values or a mapping of what is known "
                                 f"(mass, com, inertia), got {value!r}")
            tools[name] = Tool.declared(name, value, width)
        for rec, value in dict(spec.get("values") or {}).items():
            if isinstance(value, str) and value not in tools:
                raise InputError(f"import: recording {rec!r} names tool {value!r}, which parameters.tools does "
                                 f"not define ({', '.join(tools) or 'none'})")
        return tools

    def tool_of(self, names: list[str]) -> dict:
        """``{recording: tool name}`` for the recordings that name a tool."""
        values = dict(dict(self.parameters or {}).get("values") or {})
        return {rec: v for rec, v in values.items() if isinstance(v, str) and rec in names}

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
