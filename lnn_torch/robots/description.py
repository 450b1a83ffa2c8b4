"""A robot description as the robot you have: which description (a shipped one, an MJCF or a URDF file,
read by MuJoCo), where payloads attach (the flange: a body or a site), which of its bodies the real
robot does not carry (``remove``, e.g. a hand it was logged without), a tool it does carry (a fixed,
known rigid body at the flange), and its joints' armature and damping (as written, exactly zero, or
given values). The description file is never edited: MuJoCo's model editor (``mujoco.MjSpec``) applies
the changes to the model it compiles.

    ArmDescription.of("franka_panda")
    ArmDescription.of({"source": "franka_panda", "remove": ["hand"], "armature": "zero", "damping": "zero"})
    ArmDescription.of({"source": "my_arm.urdf", "flange": "tool0", "tool": [0.8, 0, 0, 0.05]})

The compiled model carries a massless body ``payload`` at the flange (the payload a scene or a model
sets at run time) and, with a ``tool``, a body ``tool`` there with the tool's mass, centre of mass and
inertia (flange frame).

A checkpoint carries the compiled model of every description file its model was built from, and a
dataset file that of the description its scene names (``compiled_copies``, MuJoCo's binary model, a few
kB to a few MB): loaded where that file is gone (another machine, a moved folder), the model is built
from the copy (``register_copies``), and where the file is there but compiles to another arm than the
copy, a warning says so.
"""

from __future__ import annotations

import json
import re
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from .shipped import DESCRIPTIONS, description_path

PAYLOAD_BODY = "payload"
TOOL_BODY = "tool"
JOINT_SETTINGS = ("as_written", "zero")  # or one value per joint
KEYS = ("source", "flange", "remove", "tool", "armature", "damping")


def _mujoco():
    try:
        import mujoco
    except ImportError:  # pragma: no cover - the optional dependency
        raise InputError("robot arms need MuJoCo: pip install 'lnn-torch[robots]'") from None
    return mujoco


def _xacro_hint(path: Path) -> str:
    """Where a description that MuJoCo cannot read is a xacro macro file (ROS's, unexpanded): how to expand it."""
    try:
        text = Path(path).read_text(errors="replace")
    except OSError:
        return ""
    name = Path(path).name
    if Path(path).suffix == ".xacro" or "<xacro:" in text or "${" in text or "$(arg" in text:
        expanded = name.removesuffix(".xacro") if name.endswith(".urdf.xacro") else f"{Path(path).stem}_expanded.urdf"
        return f"; it is a xacro file (ROS macros, unexpanded): expand it first, e.g. xacro {name} > {expanded}"
    return ""


def _joint_setting(value, key: str):
    if isinstance(value, str):
        if value not in JOINT_SETTINGS:
            raise InputError(f"robot description: {key} must be 'as_written', 'zero' or one value per joint, "
                             f"got {value!r}")
        return value
    try:
        values = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise InputError(f"robot description: {key} must be 'as_written', 'zero' or one value per joint, "
                         f"got {value!r}") from None
    if not all(np.isfinite(values)) or min(values, default=0.0) < 0:
        raise InputError(f"robot description: {key} values must be finite and >= 0, got {list(values)}")
    return values


def payload_row(value, what: str = "tool") -> tuple[float, ...]:
    """A rigid body at the flange as ``(mass, cx, cy, cz[, Ixx, Iyy, Izz, Ixy, Ixz, Iyz])`` (kg, m, kg m^2;
    flange frame; inertia about the centre of mass); a dict ``{mass, com, inertia}`` is read too."""
    if isinstance(value, dict):
        unknown = sorted(set(value) - {"mass", "com", "inertia"})
        if unknown or "mass" not in value:
            raise InputError(f"robot description: {what} takes mass (kg), com (3 values, m) and optionally inertia "
                             f"(Ixx, Iyy, Izz, Ixy, Ixz, Iyz; kg m^2), got {sorted(value)}")
        value = [value["mass"], *value.get("com", (0.0, 0.0, 0.0)), *value.get("inertia", ())]
    try:
        row = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise InputError(f"robot description: {what} must be (mass, cx, cy, cz[, six inertia entries]), "
                         f"got {value!r}") from None
    if len(row) not in (4, 10) or not all(np.isfinite(row)) or row[0] < 0:
        raise InputError(f"robot description: {what} must be (mass >= 0, cx, cy, cz[, Ixx, Iyy, Izz, Ixy, Ixz, Iyz]), "
                         f"got {list(row)}")
    return row


@dataclass(frozen=True)
class ArmDescription:
    """What of a robot description is the robot (module docstring). Frozen and hashable: a model part
    and a scene that read the same description share its compiled model."""

    source: str = "franka_panda"
    flange: str | None = None
    remove: tuple[str, ...] = field(default_factory=tuple)
    tool: tuple[float, ...] | None = None
    armature: str | tuple[float, ...] = "as_written"
    damping: str | tuple[float, ...] = "as_written"

    @classmethod
    def of(cls, value) -> ArmDescription:
        """From a shipped name or a path (the description as written), a dict of the fields (``KEYS``),
        its JSON text, or an ``ArmDescription``; ``InputError`` in one line for anything else."""
        if isinstance(value, ArmDescription):
            return value
        if isinstance(value, str) and value.lstrip().startswith("{"):
            value = json.loads(value)
        if not isinstance(value, dict):
            return cls(source=str(value))
        unknown = sorted(set(value) - set(KEYS))
        if unknown:
            raise InputError(f"robot description: unknown key(s) {', '.join(unknown)}; known: {', '.join(KEYS)}")
        remove = value.get("remove") or ()
        remove = (remove,) if isinstance(remove, str) else tuple(str(b) for b in remove)
        tool = value.get("tool")
        return cls(source=str(value.get("source", "franka_panda")), flange=value.get("flange"), remove=remove,
                   tool=None if tool is None else payload_row(tool),
                   armature=_joint_setting(value.get("armature", "as_written"), "armature"),
                   damping=_joint_setting(value.get("damping", "as_written"), "damping"))

    @property
    def path(self) -> Path:
        """The description's file (a shipped one's in the package), whether or not it is there."""
        return DESCRIPTIONS.get(self.source, Path(self.source))

    @property
    def as_written(self) -> bool:
        """Whether this is the description file itself, unchanged."""
        return self == ArmDescription(source=self.source)

    def to_dict(self) -> dict:
        out = asdict(self)
        out["remove"] = list(self.remove)
        for key in ("tool", "armature", "damping"):
            if isinstance(out[key], tuple):
                out[key] = list(out[key])
        return out

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    def config(self):
        """What a configuration file says: the source's name alone for the description as written."""
        return self.source if self.as_written else self.to_dict()

    def __str__(self) -> str:
        changes = [f"{k}={v}" for k, v in self.to_dict().items()
                   if k != "source" and v not in (None, [], "as_written")]
        return self.source + (f" ({', '.join(changes)})" if changes else "")

    # ------------------------------------------------------------------ the compiled model
    def compile(self):
        """The ``mujoco.MjModel`` of the robot: the description with this one's changes, a massless
        ``payload`` body at the flange and the ``tool`` there; ``InputError`` in one line naming what
        the description lacks."""
        copy = _COPIES.get(self.to_json())
        if copy is not None and self.source not in DESCRIPTIONS and not Path(self.source).exists():
            return _from_copy(self, copy)
        spec, path = self._spec()
        try:
            model = spec.compile()
        except ValueError as err:
            first, *where = str(err).splitlines()
            where = f" ({', '.join(w.strip() for w in where if w.strip())})" if any(w.strip() for w in where) else ""
            body = re.search(r"Element name '([^']*)'", where)
            if "mjMINVAL" in first and "moving bodies" in first and body:  # (MuJoCo's words for a massless link)
                raise InputError(f"robot description {path}: body '{body.group(1)}' moves but has no mass or "
                                 "inertia (give it an <inertial>; a link between two joints too, e.g. 1 g and "
                                 "1e-6 kg m^2: the fit identifies what it carries)") from None
            raise InputError(f"robot description {path} as changed ({self}): {first}{where}") from None
        if self.source not in DESCRIPTIONS:  # what a checkpoint of a model built now carries (compiled_copies)
            _BUILT[self.to_json()] = _mjb(model)
        return model

    def spec(self):
        """The ``mujoco.MjSpec`` of the robot, as ``compile`` compiles it (the description file with this
        one's changes): for tools that edit the model further, e.g. ``mujoco.sysid``."""
        return self._spec()[0]

    def _spec(self):
        mujoco = _mujoco()
        path = description_path(self.source)
        try:
            spec = mujoco.MjSpec.from_file(str(path))
        except ValueError as err:
            lines = [line.strip() for line in str(err).splitlines() if line.strip()]
            where = f" ({'; '.join(lines[1:])})" if len(lines) > 1 else ""
            raise InputError(f"robot description {path}: {lines[0] if lines else err}{where}{_xacro_hint(path)}") \
                from None
        spec.compiler.fusestatic = False  # keep a URDF's fixed frames (its flange link) as bodies
        left_out = drop_missing_meshes(spec, path)
        if left_out and (str(path), *left_out) not in _WARNED:
            _WARNED.add((str(path), *left_out))
            warnings.warn(f"robot description {path}: {len(left_out)} mesh file(s) not found ({', '.join(left_out[:3])}"
                          f"{', ...' if len(left_out) > 3 else ''}); their geoms are left out: the dynamics use the "
                          "bodies' inertials as written, which do not depend on them", stacklevel=4)
        names = [b.name for b in spec.bodies]
        for name in self.remove:
            body = spec.body(name) if name in names else None
            if body is None or name == "world":
                raise InputError(f"robot description {path}: no body '{name}' to remove (bodies: "
                                 f"{', '.join(n for n in names if n != 'world')})")
            spec.delete(body)
        names = [b.name for b in spec.bodies]
        flange = self._flange(spec, names, path)
        if PAYLOAD_BODY in names and (flange is None or _hangs_at(spec, spec.body(PAYLOAD_BODY), flange)):
            payload = spec.body(PAYLOAD_BODY)  # the shipped descriptions' own, or one written back at this flange
        else:
            if PAYLOAD_BODY in names:
                raise InputError(f"robot description {path} has a body '{PAYLOAD_BODY}' and a flange "
                                 f"'{self.flange}': the payload attaches at one of them (leave out flange)")
            parent, pos, quat = flange if flange is not None else (self._leaf(spec, path), None, None)
            payload = parent.add_body(name=PAYLOAD_BODY)
            if pos is not None:
                payload.pos, payload.quat = pos, quat
            payload.mass, payload.inertia, payload.explicitinertial = 0.0, [0.0, 0.0, 0.0], True
        if self.tool is not None:
            tool = payload.parent.add_body(name=TOOL_BODY, pos=payload.pos, quat=payload.quat)
            row = self.tool
            tool.mass, tool.ipos, tool.explicitinertial = row[0], list(row[1:4]), True
            if len(row) == 10 and any(row[4:]):  # about its centre of mass, flange axes (MuJoCo's fullinertia order)
                tool.fullinertia = list(row[4:])
            else:  # a point mass
                tool.inertia = [0.0, 0.0, 0.0]
        for key in ("armature", "damping"):
            setting = getattr(self, key)
            if setting == "as_written":
                continue
            joints = [j for j in spec.joints if j.type == mujoco.mjtJoint.mjJNT_HINGE]
            values = (0.0,) * len(joints) if setting == "zero" else setting
            if len(values) != len(joints):
                raise InputError(f"robot description {path}: {key} has {len(values)} values for {len(joints)} joints")
            for joint, v in zip(joints, values, strict=True):
                # damping is MuJoCo's polynomial (linear coefficient first): the value is viscous, N m s/rad
                setattr(joint, key, float(v) if key == "armature" else [float(v), 0.0, 0.0])
        return spec, path

    def _flange(self, spec, names: list[str], path):
        """``(body, pos, quat)`` where the payload attaches for a named flange (a body: its origin; a
        site: its frame in its body), None where none is named."""
        if self.flange is None:
            return None
        if self.flange in names:
            return spec.body(self.flange), None, None
        site = spec.site(self.flange)
        if site is None:
            sites = [s.name for s in spec.sites if s.name]
            raise InputError(f"robot description {path}: no body or site '{self.flange}' for the flange (bodies: "
                             f"{', '.join(n for n in names if n != 'world')}"
                             + (f"; sites: {', '.join(sites)})" if sites else ")"))
        return site.parent, list(site.pos), _quaternion(spec, site)

    @staticmethod
    def _leaf(spec, path):
        """The last body of the chain (the default flange): the deepest body, which must be unique."""
        def depth(body):
            n = 0
            while body.name != "world":
                body, n = body.parent, n + 1
            return n

        bodies = [b for b in spec.bodies if b.name != "world"]
        if not bodies:
            raise InputError(f"robot description {path} has no bodies")
        deepest = max(depth(b) for b in bodies)
        leaves = [b for b in bodies if depth(b) == deepest]
        if len(leaves) > 1:
            raise InputError(f"robot description {path}: name the flange (a body or site where payloads attach); "
                             f"the chain ends in {', '.join(b.name for b in leaves)}")
        return leaves[0]


def _quaternion(spec, element) -> list[float]:
    """The orientation of a body or site of ``spec`` as a quaternion, however it is written (MjSpec keeps an
    ``euler``, ``axisangle``, ``xyaxes`` or ``zaxis`` in ``alt`` and ``quat`` at its default)."""
    if element.alt.type == _mujoco().mjtOrientation.mjORIENTATION_QUAT:
        return list(element.quat)
    return list(spec.resolve_orientation(spec.compiler.degree, spec.compiler.eulerseq, element.alt))


def _hangs_at(spec, body, flange) -> bool:
    """Whether ``body`` (an ``MjsBody`` of ``spec``) is welded at ``flange`` ``(parent body, pos, quat)`` (pos
    None: the parent's origin) with nothing hanging from it: a payload body ``lnn-torch export`` wrote there,
    which a description read back with the same flange uses as its own."""
    parent, pos, quat = flange
    if body.parent is None or body.parent.name != parent.name or body.joints or body.bodies:
        return False
    pos, quat = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]) if pos is None else (pos, quat)
    own = _quaternion(spec, body)
    q = np.asarray(own, dtype=np.float64) / np.linalg.norm(own)
    r = np.asarray(quat, dtype=np.float64) / np.linalg.norm(quat)
    return bool(np.allclose(body.pos, pos, rtol=0, atol=1e-9) and min(np.abs(q - r).max(), np.abs(q + r).max()) < 1e-9)


# ---------------------------------------------------------------------------- meshes it cannot find
_WARNED: set[tuple] = set()  # (description file, its missing meshes) reported in this process


def _asset_file(spec, file: str, folder: str) -> Path:
    """Where MuJoCo looks for an asset ``file`` of ``spec`` (its compiler's ``strippath``; an absolute name
    as it is; else ``folder`` (the compiler's meshdir) if absolute, else the model file's folder and it)."""
    name = Path(Path(file).name if spec.strippath else file)
    if name.is_absolute():
        return name
    base = Path(folder) if folder and Path(folder).is_absolute() else Path(spec.modelfiledir or ".") / (folder or "")
    return base / name


def missing_meshes(spec) -> dict[str, str]:
    """``{mesh name: file}`` of the mesh assets of ``spec`` (a ``mujoco.MjSpec``) whose files are not there."""
    return {m.name: m.file for m in spec.meshes
            if m.file and m.file not in spec.assets and not _asset_file(spec, m.file, spec.meshdir).is_file()}


def drop_missing_meshes(spec, path) -> list[str]:
    """Leave out of ``spec`` (a ``mujoco.MjSpec`` read from ``path``) the mesh assets whose files are not
    there and the geoms that show them: a robot description from a ROS package names its meshes as
    ``package://...``, which MuJoCo cannot open, and a URDF copied without its meshes has none, while the
    dynamics need only the bodies' inertials. A moving body whose inertia MuJoCo would compute from such
    a geom (no inertial written, or the compiler's ``inertiafromgeom="true"``) cannot be modelled without
    it: ``InputError`` naming the body and the file. Returns the files left out (none: ``spec`` as read)."""
    mujoco = _mujoco()
    missing = missing_meshes(spec)
    if not missing:
        return []
    from_geoms = spec.compiler.inertiafromgeom == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE
    for geom in [g for g in spec.geoms if g.type == mujoco.mjtGeom.mjGEOM_MESH and g.meshname in missing]:
        body = geom.parent
        while not isinstance(body, mujoco.MjsBody):  # a geom in a frame
            body = body.parent
        if (from_geoms or not body.explicitinertial) and _moves(body):
            why = "the compiler computes every inertia from geoms" if from_geoms else "it has no inertial written"
            raise InputError(f"robot description {path}: body '{body.name}' takes its inertia from mesh "
                             f"'{missing[geom.meshname]}', which is not there ({why}): give the mesh files (the "
                             "compiler's meshdir) or write the body's inertial")
        spec.delete(geom)
    for mesh in [m for m in spec.meshes if m.name in missing]:
        spec.delete(mesh)
    return sorted(set(missing.values()))


def _moves(body) -> bool:
    """Whether ``body`` (an ``MjsBody``) or a body above it has a joint: its inertia enters the dynamics."""
    while body is not None and body.name != "world":
        if body.joints:
            return True
        body = body.parent
    return False


# ---------------------------------------------------------------------------- copies in checkpoints
# The compiled copies registered from checkpoints (``register_copies``), by the description's JSON:
# {"mjb": MuJoCo's binary model, "mujoco": the version that wrote it, "where": the checkpoint}.
_COPIES: dict[str, dict] = {}
# the binary model each description file was last compiled to in this process, as compiled (before a
# scene edits its copy): what a checkpoint of a model built from it carries, whatever the file is later
_BUILT: dict[str, bytes] = {}
# the arrays that make two compiled arms the same arm for the dynamics and its scene: structure,
# kinematics (joint offsets ``qpos0`` included), inertia, joints' armature, damping, springs and limits,
# gravity compensation, actuators
_SAME_ARM = ("body_parentid", "body_jntnum", "body_pos", "body_quat", "body_mass", "body_ipos", "body_iquat",
             "body_inertia", "body_gravcomp", "jnt_type", "jnt_bodyid", "jnt_axis", "jnt_pos", "jnt_range",
             "jnt_limited", "jnt_stiffness", "qpos0", "qpos_spring", "dof_armature", "dof_damping", "dof_frictionloss",
             "actuator_trnid", "actuator_gear", "actuator_gainprm", "actuator_biasprm", "opt.gravity")


def _mjb(model) -> bytes:
    mujoco = _mujoco()
    buffer = np.empty(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buffer)
    return buffer.tobytes()


def _model_of(copy: dict):
    try:
        return _mujoco().MjModel.from_binary_path("arm.mjb", {"arm.mjb": copy["mjb"]})
    except ValueError as err:
        raise InputError(f"the compiled robot description {copy['where']} carries cannot be read "
                         f"({str(err).strip().splitlines()[0]})") from None


def _from_copy(description: ArmDescription, copy: dict):
    """The compiled model of ``description`` from the copy a checkpoint carries (its file is gone)."""
    mujoco = _mujoco()
    if copy["mujoco"] != mujoco.__version__:
        raise InputError(f"robot description {description.source}: no such file, and the copy {copy['where']} "
                         f"carries was compiled by MuJoCo {copy['mujoco']} (this is {mujoco.__version__}): restore "
                         f"the file or install mujoco=={copy['mujoco']}")
    model = _model_of(copy)
    if not copy.get("warned"):
        copy["warned"] = True
        warnings.warn(f"robot description {description.source}: no such file; using the compiled copy "
                      f"{copy['where']} carries", stacklevel=3)
    return model


def _field(model, name: str):
    obj = model
    for part in name.split("."):
        obj = getattr(obj, part)
    return np.asarray(obj)


def same_arm(a, b) -> bool:
    """Whether two compiled models are the same arm for the dynamics (``_SAME_ARM`` to 1e-12)."""
    return all(_field(a, k).shape == _field(b, k).shape and np.allclose(_field(a, k), _field(b, k), rtol=0, atol=1e-12)
               for k in _SAME_ARM)


def descriptions_in(settings) -> list[ArmDescription]:
    """The robot descriptions a model's settings name (every ``description`` key, at any depth of its
    scene configuration and model options), each once."""
    found: list[ArmDescription] = []

    def walk(value):
        if isinstance(value, dict):
            for key, item in value.items():
                if key == "description" and item is not None:
                    d = ArmDescription.of(item)
                    if d not in found:
                        found.append(d)
                else:
                    walk(item)
        elif isinstance(value, (list, tuple)):
            for item in value:
                walk(item)

    walk(settings)
    return found


def compiled_copies(settings) -> dict:
    """What a checkpoint carries of the description files ``settings`` names (``descriptions_in``; the
    shipped ones are in the package): the description's JSON -> ``{"mjb": bytes, "mujoco": version}``."""
    files = [d for d in descriptions_in(settings) if d.source not in DESCRIPTIONS]
    version = _mujoco().__version__ if files else None
    return {d.to_json(): {"mjb": _BUILT.get(d.to_json()) or _mjb(d.compile()), "mujoco": version} for d in files}


def register_copies(copies: dict, where: str) -> None:
    """Make the compiled copies a checkpoint carries (``compiled_copies``; ``where`` names it) available to
    ``ArmDescription.compile`` where their files are gone; a warning where a file is there but compiles
    to another arm than the copy (the checkpoint was trained on the arm of the copy)."""
    if not isinstance(copies, dict) or not all(isinstance(c, dict) and isinstance(c.get("mjb"), (bytes, bytearray))
                                               and "mujoco" in c for c in copies.values()):
        raise InputError(f"{where}: its compiled robot descriptions are malformed (expected the description's "
                         "JSON -> {mjb: bytes, mujoco: version})")
    for key, copy in copies.items():
        description = ArmDescription.of(key)
        file = Path(description.source)
        stat = file.stat() if file.exists() else None
        entry = {"mjb": bytes(copy["mjb"]), "mujoco": str(copy["mujoco"]), "where": where,
                 "checked": None if stat is None else (stat.st_mtime_ns, stat.st_size)}
        before = _COPIES.get(key)
        if before is not None and before["mjb"] == entry["mjb"] and before["checked"] == entry["checked"]:
            continue  # registered and checked against the file as it is: a file read again, a checkpoint of its data
        _COPIES[key] = entry
        if stat is None or entry["mujoco"] != _mujoco().__version__:
            continue
        try:
            differs = not same_arm(description.compile(), _model_of(entry))
        except (InputError, ValueError):
            differs = True
        if differs:
            warnings.warn(f"robot description {description.source} is not the arm {where} was trained with (its "
                          "compiled copy there): the model is built from the file as it is now", stacklevel=2)
