"""The identified arm handed back as a robot description (``lnn-torch export --format mjcf|urdf``).

``write_description(source, path, format)`` writes the user's own description (the file the model was
built from: ``ArmDescription.source``; a shipped name such as ``franka_panda`` is the shipped MJCF) with
what the model identified, and nothing else changed:

* per moving body: its mass, centre of mass and inertia about it (MJCF ``<inertial pos mass
  fullinertia>``, URDF ``<inertial><origin xyz rpy="0 0 0"/><mass/><inertia/>``), in the body's (URDF:
  the link's) own frame, converted exactly from the model's pseudo-inertia ``J`` of that body;
* per joint: armature (MJCF only: URDF has no rotor inertia), viscous damping ``b`` (MJCF ``damping``,
  URDF ``<dynamics damping>``) and the Coulomb level ``c`` (MJCF ``frictionloss``, URDF ``<dynamics
  friction>``), where the model has those forms (else the joint's values stay as written). MuJoCo's
  ``frictionloss`` is a hard Coulomb friction (a constraint: the joint sticks below it), not the
  model's ``c tanh(v / v_c)``; the smoothing is listed as not expressed;
* the payload at the flange (``payload``: the one a model was conditioned on or identified, ``(mass, cx,
  cy, cz[, Ixx, Iyy, Izz, Ixy, Ixz, Iyz])``, flange frame, inertia about its centre of mass) as the body
  ``payload`` (none without a payload where the file read alone finds the flange: the chain's last body),
  and the description's ``tool`` as the body ``tool``.

The file written is the robot as the model saw it (``ArmDescription.compile``): the description's
changes are applied too: the bodies it ``remove``-s are gone (with the actuators, sensors, contact
exclusions and transmissions that name them), a ``payload`` body hangs at the flange where a payload is
written (a URDF link and fixed joint), the ``tool`` is there. Use it as ``source`` alone (no ``remove``, ``tool`` or
``flange``). Geometry, joints, limits, actuators, defaults, visuals and comments are kept as written:
the file is edited as XML (``xml.etree``; MJCF and URDF alike; the root's start tag and the closing of empty
elements as the file writes them), numbers written with every digit (``repr``), relative asset paths re-pointed
where the file is written elsewhere. What the data left as described is written as the description has it: an
identified value within the model's round-off of the description's is the description's (``_as_described``; a
float32 model gives a mass of 3.7 as 3.6999999), a body whose inertial is then the description's keeps its
element as written, and a value of a changed one that did not change keeps its text. MuJoCo's own writer
(``MjSpec.to_xml``) is not used: it prints 6 significant digits, which alone moves the shipped Panda's
mass matrix by 1.5e-6 relative (its body quaternions become 0.707107), and rewrites the whole file.

Bodies welded to a moving body (the Panda's hand, the tool; a URDF's fixed links) are folded into the
moving body's ``J`` by the model (``lnn_torch.robots.kinematics.read_chain``), so they keep their
inertials as written and the moving body gets the identified ``J`` less theirs; where that difference is
not a rigid body (not positive definite), the moving body gets the whole identified ``J`` and the welded
bodies' inertials are set to zero (a note says so).

What neither MuJoCo nor URDF can express is listed (``WriteBack.unexpressed``: printed by the command,
in a comment at the top of the file and in the sidecar ``<file>.json`` beside it, with every value),
never dropped: Coulomb smoothing, friction offset, Stribeck, sigmoid friction, static friction's stick
window, Rayleigh damping, a force residual, learned kinetic or potential residual parts, learned input
gains or matrix, and, in URDF, the armature. The written file is compiled by MuJoCo before it is kept
and must give the identified chain (its geometry unchanged, every link's ``J`` to 1e-9, armature,
damping and friction loss): else ``InputError`` and nothing is written.

A URDF-described arm written as MJCF (``format="mjcf"``) is its URDF write-back converted by MuJoCo's own URDF
importer (``_urdf_as_mjcf``): static bodies kept, the armature set, every body frame, inertial and joint value
rewritten in full from the compiled model (``MjSpec.to_xml`` writes six digits), mesh files not found here left
out (noted), the joints' ranges and effort limits in full; URDF velocity limits have no MJCF attribute (noted);
then checked as above.

Sources: an ``LNNModule`` or network whose kinetic part is ``spatial`` (the grey box; its kinetic
``eps`` on the diagonal is folded into the armature, exact), or a classical ``ArmModel`` with full
parameters (``pi``; give its ``description``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import warnings
import xml.etree.ElementTree as ET
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..errors import InputError
from ..robots.description import (
    PAYLOAD_BODY,
    TOOL_BODY,
    ArmDescription,
    drop_missing_meshes,
    missing_meshes,
    payload_row,
)

FORMATS = ("mjcf", "urdf")
SUFFIXES = {"mjcf": ".xml", "urdf": ".urdf"}
REFUSAL = "write-back needs a grey box built from a robot description (kinetic part 'spatial')"
CHECK_RTOL = 1e-9  # the written file's links against the identified ones (relative to each link's largest entry)
# an identified pseudo-inertia entry within this many machine epsilons of the model's dtype of the description's
# (relative to the entry's scale, sqrt(J_aa J_bb)) is the description's: what the data left undetermined comes
# back from a float32 model as 3.6999999304954803 for a mass of 3.7, and 0 as -6e-35 (_as_described)
ROUND_OFF = 16
_ORIENTATIONS = ("quat", "axisangle", "xyaxes", "zaxis", "euler")


# ---------------------------------------------------------------------------- what was identified
@dataclass
class IdentifiedArm:
    """The arm a model identified, in SI (float64 numpy): per moving body ``J (n, 4, 4)`` in its frame
    (welded bodies folded in, payload excluded), per joint ``armature``, ``damping`` (viscous) and
    ``frictionloss`` (Coulomb level; None where the model has no such form), the ``payload`` row at the
    flange (or None), what cannot be expressed (``unexpressed``: ``{term, why, values}``), notes and
    ``resolution``: the relative round-off of the numbers the model computes in (``ROUND_OFF`` machine epsilons
    of its dtype), below which an identified value is the description's (``_as_described``)."""

    description: ArmDescription
    what: str
    J: np.ndarray
    armature: np.ndarray
    damping: np.ndarray | None
    frictionloss: np.ndarray | None
    payload: tuple[float, ...] | None
    joint_names: tuple[str, ...]
    unexpressed: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    resolution: float = 0.0


@dataclass
class WriteBack:
    """What ``write_description`` wrote: the file, its sidecar JSON, the format, what the format cannot
    express (one line each, values included), notes, and the values written."""

    path: Path
    sidecar: Path
    format: str
    unexpressed: list[str]
    notes: list[str]
    values: dict


def _vector(x) -> np.ndarray:
    return np.asarray(torch.as_tensor(x).detach().cpu().double().reshape(-1).numpy(), dtype=np.float64)


def _per_joint(names, values) -> dict:
    return {str(n): float(v) for n, v in zip(names, np.asarray(values, dtype=np.float64).reshape(-1), strict=True)}


def _dynamics_model(source):
    return getattr(source, "model", source)


def refusal(source) -> str | None:
    """Why ``source`` cannot be written back (one line), or None."""
    from ..identification.classical_arm import ArmModel

    if isinstance(source, ArmModel):
        if source.pi is None:
            return (f"write-back needs every link's parameters: a physically consistent fit (consistent_fit); "
                    f"this {source.method} fit has only base parameters")
        return None
    m = _dynamics_model(source)
    part = m.part("kinetic", "spatial") if hasattr(m, "part") else None
    if part is None:
        kinetic = list(getattr(m, "kinetic", {}) or {})
        what = f"variant '{getattr(m, 'variant', type(m).__name__)}'" + (f", kinetic {kinetic}" if kinetic else "")
        return f"{REFUSAL}; this model: {what}"
    return None


def identified_arm(source, payload=None, description=None) -> IdentifiedArm:
    """The arm ``source`` identified (``IdentifiedArm``); ``payload``: the load at the flange it is written
    with (and, for a grey box conditioned on a payload, evaluated at); ``description``: the robot
    description of an ``ArmModel`` (a grey box has its own). ``InputError`` in one line where it cannot."""
    from ..identification.classical_arm import ArmModel

    why = refusal(source)
    if why is not None:
        raise InputError(why)
    row = None if payload is None else payload_row(payload, "payload")
    if isinstance(source, ArmModel):
        return _from_arm_model(source, row, description)
    return _from_grey_box(_dynamics_model(source), row)


def _from_grey_box(m, row) -> IdentifiedArm:
    part = m.part("kinetic", "spatial")
    desc = part.description
    names = tuple(part.joint_names)
    n = part.dof
    unexpressed, notes = [], []
    with torch.no_grad():
        J = part.link_J(torch.float64).cpu().numpy()
        armature = part.armature(torch.float64).cpu().numpy().copy()
        eps = float(getattr(m, "eps", 0.0))
        if eps:  # M = F F^T + eps I (normalised): a constant diagonal, exactly an armature
            norm = m.normalizer
            D = (norm.time_scale.double() / norm.coord_scale.double()).cpu()
            extra = _vector(m._joules(eps * D * D))
            armature = armature + extra
            notes.append(f"the model's eps ({eps:g}, normalised) is in the armature: {_fmt(extra)} kg m^2 added")
        P = m.scene.num_params
        params = torch.zeros(1, P, dtype=torch.float64)
        if row is not None and P:
            given = torch.tensor(row[:P], dtype=torch.float64)
            params[0, : len(given)] = given
            if len(row) > P:
                notes.append(f"the model takes the payload's first {P} values; the payload body is written with "
                             f"all {len(row)}")
        elif row is not None:
            notes.append("the model has no payload parameter: the payload body is written as given")
        dtype = m.dtype
        params_norm = m.normalizer.params(params.to(dtype))
        damping = frictionloss = None
        forces = m.forces
        if forces is not None and forces.friction:
            forms = forces.drive.forms
            coef = {k: _vector(v.reshape(-1, v.shape[-1])[0])
                    for k, v in forces.drive_coefficients(params_norm).items()}
            if not forces.identity_joints or forces.num_joints != n:
                unexpressed.append({"term": "joint map", "why": "the model's friction acts on joint rates D qd, D "
                                    "not the identity: no joint damping or friction loss written",
                                    "values": forces.joint_map.tolist()})
            if forces.identity_joints and forces.num_joints == n:
                if "viscous" in forms:
                    damping = coef["b"]
                if "coulomb" in forms:
                    frictionloss = coef["c"]
            joints = names if forces.num_joints == n else tuple(f"joint rate {i}" for i in range(forces.num_joints))
            unexpressed += _drive_terms(forces.drive, coef, joints, stiction=forces.stiction,
                                        stick_velocity=forces.stick_velocity)
            if hasattr(forces, "coefficient_net") and P:
                other = forces.drive_coefficients(m.normalizer.params((params + 1.0).to(dtype)))
                if any(not torch.equal(v.reshape(-1, v.shape[-1])[0].double().cpu(), torch.as_tensor(coef[k]))
                       for k, v in other.items() if k in coef):
                    notes.append("the friction coefficients depend on the payload: written at "
                                 + ("the payload given" if row is not None else "no payload"))
        if forces is not None and forces.rayleigh is not None:
            unexpressed.append({"term": "Rayleigh damping", "why": "a learned state-dependent damping matrix "
                                "R(q, qd) qd (dissipation joint+rayleigh); no joint damping expresses it",
                                "values": None})
        if forces is not None and forces.residual is not None:
            if any(bool(p.any()) for p in forces.residual.output_layer):
                at_rest = _residual_at_rest(m, params, desc)
                worst = int(np.argmax(at_rest))
                unexpressed.append({"term": "force residual", "why": "a learned generalised force Q_r(q, qd) "
                                    "(option residual_force); not written. At rest over the joints' ranges it is "
                                    f"up to {at_rest[worst]:.3g} N m RMS ({names[worst]}): a torque the written arm "
                                    "lacks, gravity-like where the residual took up what the rigid body left (per "
                                    "joint, N m RMS at zero velocity)", "values": at_rest.tolist()})
            else:  # (its output layer at zero: validation kept a state without it)
                notes.append("the model's force residual is zero (its output layer at zero): nothing left out")
        if forces is not None and forces.num_inputs:
            gains = forces.input_gains()
            if gains is not None:
                unexpressed.append({"term": "input gains", "why": "learned gains on the inputs (learn_input_matrix: "
                                    "gains); the actuators are left as written", "values": _vector(gains).tolist()})
            elif isinstance(getattr(forces, "input_matrix", None), torch.nn.Parameter):
                unexpressed.append({"term": "input matrix", "why": "a learned input matrix (learn_input_matrix: true);"
                                    " the actuators are left as written", "values": forces.input_matrix.tolist()})
    for role in ("kinetic", "potential"):
        others = [k for k in getattr(m, role) if k != "spatial"]
        if others:
            unexpressed.append({"term": f"{role} parts {', '.join(others)}", "why": f"learned {role} energy beside "
                                "the rigid body's; the written arm is the model without it", "values": None})
    if "spatial" not in m.potential:
        unexpressed.append({"term": "gravity", "why": "the model's potential is not the rigid body's gravity "
                            "(no potential part 'spatial'); MuJoCo's is, from the written masses", "values": None})
    if damping is None:
        notes.append("the model has no viscous friction: the joints' damping is left as written")
    if frictionloss is None:
        notes.append("the model has no Coulomb friction: the joints' friction loss is left as written")
    _check_geometry(desc, part, None)
    return IdentifiedArm(desc, f"grey box ({m.variant}, kinetic part 'spatial')", J, armature, damping,
                         frictionloss, row, names, unexpressed, notes,
                         ROUND_OFF * float(torch.finfo(m.dtype).eps))


def _residual_at_rest(m, params: torch.Tensor, desc, count: int = 512) -> np.ndarray:
    """``(dof,)``: the RMS of the model's force residual (N m) at zero velocity over ``count`` joint angles drawn
    uniformly within the description's joint ranges (a joint without limits: a whole turn; seeded): the torque at
    rest that a description without the residual lacks."""
    model = desc.compile()
    limited = np.asarray(model.jnt_limited, dtype=bool)[:, None]
    ranges = np.where(limited, np.asarray(model.jnt_range, dtype=np.float64), [-np.pi, np.pi])
    q = np.random.default_rng(0).uniform(ranges[:, 0], ranges[:, 1], (count, len(ranges)))
    q = torch.as_tensor(q, dtype=m.dtype)
    force = m.residual_force(q, torch.zeros_like(q), params.expand(count, -1).to(m.dtype))
    return force.double().pow(2).mean(0).sqrt().cpu().numpy()


def _drive_terms(drive, coef: dict, names, stiction: bool = False, stick_velocity: float | None = None) -> list[dict]:
    """The drive model's terms beyond viscous and a hard Coulomb level (``lnn_torch.mechanics.friction``)."""
    out = []
    if "coulomb" in drive.forms:
        out.append({"term": "Coulomb smoothing", "why": f"c tanh(v / v_c) with v_c = {drive.coulomb_velocity:g} rad/s; "
                    "MuJoCo's frictionloss (URDF's friction) is a hard Coulomb level", "values":
                    {"coulomb_velocity": drive.coulomb_velocity, "c": _per_joint(names, coef["c"])}})
    if "offset" in drive.forms:
        out.append({"term": "friction offset", "why": "a constant torque o per joint (not a friction)",
                    "values": {"o": _per_joint(names, coef["o"])}})
    if "stribeck" in drive.forms:
        out.append({"term": "Stribeck friction", "why": f"s tanh(v / v_c) exp(-(v / v_s)^2), v_s = "
                    f"{drive.stribeck_velocity:g} rad/s", "values": {"stribeck_velocity": drive.stribeck_velocity,
                                                                     "s": _per_joint(names, coef["s"])}})
    if "saturating" in drive.forms:
        out.append({"term": "saturating friction", "why": f"d tanh(v / v_d), v_d = {drive.saturation_velocity:g} rad/s",
                    "values": {"saturation_velocity": drive.saturation_velocity, "d": _per_joint(names, coef["d"])}})
    if "sigmoid" in drive.forms:
        out.append({"term": "sigmoid friction", "why": "phi1 [sigmoid(phi2 (v + phi3)) - sigmoid(phi2 phi3)]",
                    "values": {k: _per_joint(names, coef[k]) for k in ("phi1", "phi2", "phi3")}})
    if stiction:
        out.append({"term": "static friction window", "why": f"held at rest up to c below v_s = {stick_velocity:g} "
                    "rad/s (dissipation joint+stiction); MuJoCo's frictionloss sticks without a window",
                    "values": {"stick_velocity": stick_velocity}})
    return out


def _from_arm_model(model, row, description) -> IdentifiedArm:
    from ..robots.regressor import pseudo_inertia_of

    if description is None:
        raise InputError("an ArmModel carries no robot description: pass description= (the one its chain was read "
                         "from, e.g. franka_panda)")
    desc = ArmDescription.of(description)
    chain = model.chain
    n = chain.dof
    pi = np.asarray(model.pi, dtype=np.float64)
    J = pseudo_inertia_of(torch.as_tensor(pi[: 10 * n]).reshape(n, 10)).numpy()
    if not (np.linalg.eigvalsh(J) > 0).all():
        raise InputError(f"write-back: the {model.method} fit's links are not all rigid bodies (a pseudo-inertia "
                         "is not positive definite)")
    forms = model.drive.forms
    names = tuple(chain.joint_names)
    coef = {k: np.asarray(v, dtype=np.float64) for k, v in model.friction_coefficients.items()}
    damping = pi[11 * n:].copy() if "viscous" in forms else None
    frictionloss = coef["c"] if "coulomb" in forms else None
    notes = []
    if row is not None:
        notes.append("the payload body is written as given (the fit's links do not include it)")
    if damping is None:
        notes.append("the fit has no viscous friction: the joints' damping is left as written")
    if frictionloss is None:
        notes.append("the fit has no Coulomb friction: the joints' friction loss is left as written")
    _check_geometry(desc, None, chain)
    return IdentifiedArm(desc, f"classical {model.method} fit (drive {model.drive.name})", J, pi[10 * n: 11 * n].copy(),
                         damping, frictionloss, row, names, _drive_terms(model.drive, coef, names), notes,
                         ROUND_OFF * float(np.finfo(np.float64).eps))


def _check_geometry(desc: ArmDescription, part, chain) -> None:
    """The description's file is there and its chain is the model's (joints, frames, axes)."""
    from ..robots import kinematics as K

    path = desc.path
    if not path.exists():
        raise InputError(f"write-back: the robot description {desc.source} is not here (a checkpoint carries only "
                         "its compiled copy): restore the file")
    nominal = K.read_chain(desc.compile())
    if part is not None:
        like = torch.zeros((), dtype=torch.float64)
        chain = K.SerialChain(*(part.const(k, like) for k in ("X", "axis", "anchor", "qpos0")), None, None, None, None,
                              None, part.joint_names)
    same = nominal.joint_names == tuple(chain.joint_names) and all(
        getattr(nominal, k).shape == getattr(chain, k).shape
        and torch.allclose(getattr(nominal, k), getattr(chain, k).double(), rtol=0, atol=1e-12)
        for k in ("X", "axis", "anchor", "qpos0"))
    if not same:
        raise InputError(f"write-back: the robot description {desc} is not the arm the model was built on (its "
                         "joints or frames differ)")


# ---------------------------------------------------------------------------- the bodies to write
def _as_described(ident: IdentifiedArm, nominal: np.ndarray) -> tuple[IdentifiedArm, int]:
    """``ident`` with each link's pseudo-inertia entries that lie within the model's round-off
    (``ident.resolution`` times the entry's scale ``sqrt(J_aa J_bb)``) of the description's ``nominal (n, 4, 4)``
    set to the description's (a link whose result would not be a rigid body is left as identified), and how
    many of the links' ten values each were so set. The written file then holds the description's own numbers
    where the data determined nothing (and the file's text for them: ``_keep``)."""
    J = ident.J.copy()
    count = 0
    for i in range(len(J)):
        diag = np.abs(np.diagonal(nominal[i]))
        close = np.abs(J[i] - nominal[i]) <= ident.resolution * np.sqrt(np.outer(diag, diag))
        if not close.any():
            continue
        snapped = np.where(close, nominal[i], J[i])
        if np.linalg.eigvalsh(0.5 * (snapped + snapped.T)).min() <= 0:
            continue
        J[i] = snapped
        count += int(np.triu(close).sum())
    if not count:
        return ident, 0
    return dataclasses.replace(ident, J=J), count


def _keep(old: str | None, new, scale: float | None = None) -> str:
    """The numbers ``new`` as an attribute's text, each one the old text's own token where the old one is the
    same number to float64 round-off (relative to ``scale``, default the largest of either): values the data
    left as described keep the description's spelling (``0.0193``, not ``0.019299999999999998``)."""
    values = np.asarray(new, dtype=np.float64).reshape(-1)
    tokens = (old or "").split()
    try:
        before = np.array([float(t) for t in tokens])
    except ValueError:
        before = np.array([])
    if before.shape != values.shape:
        return _nums(values)
    scale = float(np.max(np.abs(np.concatenate([before, values])), initial=0.0)) if scale is None else scale
    same = np.abs(before - values) <= 1e-12 * scale
    return " ".join(t if ok else _num(v) for t, ok, v in zip(tokens, same, values, strict=True))


def inertial_of(J: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """``(mass, centre of mass (3,), inertia about it (3, 3))`` of a pseudo-inertia ``J (4, 4)`` in its
    body's frame (what MJCF's ``<inertial pos mass fullinertia>`` and URDF's ``<inertial>`` hold)."""
    J = 0.5 * (J + J.T)
    m = float(J[3, 3])
    c = J[:3, 3] / m
    S = J[:3, :3] - m * np.outer(c, c)
    I = np.trace(S) * np.eye(3) - S
    return m, c, 0.5 * (I + I.T)


def _transform(pos, quat) -> np.ndarray:
    from ..robots.kinematics import _transform as t

    return t(pos, quat)


def _body_J(model, b: int) -> np.ndarray:
    """The pseudo-inertia of body ``b`` of a compiled model, in the body's frame (its inertial as compiled)."""
    from ..robots.kinematics import _quat_matrix, pseudo_inertia

    R = _quat_matrix(model.body_iquat[b])
    return pseudo_inertia(float(model.body_mass[b]), model.body_ipos[b], R @ np.diag(model.body_inertia[b]) @ R.T)


def _body_groups(model) -> list[dict]:
    """Per moving body of a compiled description (chain order): its name, its joint's name, and the
    bodies welded to it (payload excluded) with their pose in it and their pseudo-inertia there, as
    ``read_chain`` folds them."""
    import mujoco

    name = lambda kind, i: mujoco.mj_id2name(model, kind, i)  # noqa: E731
    frame_of = {0: (-1, np.eye(4))}
    groups: list[dict] = []
    for b in range(1, model.nbody):
        owner, pose = frame_of[int(model.body_parentid[b])]
        local = pose @ _transform(model.body_pos[b], model.body_quat[b])
        if int(model.body_jntnum[b]) == 1:
            groups.append({"body": name(mujoco.mjtObj.mjOBJ_BODY, b), "id": b,
                           "joint": name(mujoco.mjtObj.mjOBJ_JOINT, int(model.body_jntadr[b])), "welded": []})
            owner, local = len(groups) - 1, np.eye(4)
        frame_of[b] = (owner, local)
        body = name(mujoco.mjtObj.mjOBJ_BODY, b)
        if owner < 0 or body == PAYLOAD_BODY:
            continue
        if int(model.body_jntnum[b]) != 1:
            Jb = _body_J(model, b)
            groups[owner]["welded"].append({"body": body, "id": b, "local": local, "J": local @ Jb @ local.T,
                                            "mass": float(model.body_mass[b])})
    return groups


def _plan(ident: IdentifiedArm, model) -> tuple[dict, list[str]]:
    """``{body name: J in its own frame or None (zeroed)}`` for every body whose inertial is written (a body
    whose ``J`` is the description's keeps its inertial as written), and notes (module docstring: welded bodies
    keep theirs where the rest is a rigid body)."""
    groups = _body_groups(model)
    plan, notes = {}, []
    for i, g in enumerate(groups):
        if g["body"] is None:
            raise InputError(f"write-back: moving body {g['id']} of the description has no name")
        welded = sum((w["J"] for w in g["welded"]), np.zeros((4, 4)))
        own = ident.J[i] - welded
        written = _body_J(model, g["id"])
        if np.abs(own - written).max() <= 1e-12 * np.abs(written).max():  # as described: its inertial as written
            continue
        eig = np.linalg.eigvalsh(0.5 * (own + own.T))
        if eig.min() > 1e-9 * max(eig.max(), 1e-300):
            plan[g["body"]] = own
            continue
        heavy = [w for w in g["welded"] if w["mass"] > 0]
        unnamed = [w["id"] for w in heavy if w["body"] is None]
        if unnamed:
            raise InputError(f"write-back: body '{g['body']}''s identified inertia less its welded bodies' is not a "
                             f"rigid body, and welded bodies {unnamed} have no name to set them to zero")
        plan[g["body"]] = ident.J[i]
        for w in heavy:
            plan[w["body"]] = None
        if heavy:
            welded_names = ", ".join(w["body"] for w in heavy)
            notes.append(f"{g['body']}: the identified inertia less that of {welded_names} is not a rigid body: "
                         f"{g['body']} carries all of it and {welded_names} none")
    return plan, notes


# ---------------------------------------------------------------------------- XML
def _num(x: float) -> str:
    x = float(x)
    if x == 0.0:
        return "0"
    text = repr(x)
    return text[:-2] if text.endswith(".0") else text


def _nums(values) -> str:
    return " ".join(_num(v) for v in np.asarray(values, dtype=np.float64).reshape(-1))


def _fmt(values) -> str:
    return "[" + ", ".join(f"{float(v):.6g}" for v in np.asarray(values).reshape(-1)) + "]"


def _parse(text: str):
    """The root of an XML text with its comments, and the namespaces it declares registered."""
    import io

    for _, (prefix, uri) in ET.iterparse(io.StringIO(text), events=("start-ns",)):
        if prefix:
            ET.register_namespace(prefix, uri)
    return ET.fromstring(text, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))


def _serialise(text: str, root) -> str:
    """``root`` in place of the original's root element: what stands before and after it kept as written."""
    comments = [(m.start(), m.end()) for m in re.finditer(r"<!--.*?-->", text, re.S)]
    start = next((m.start() for m in re.finditer(rf"<{re.escape(root.tag)}[\s/>]", text)
                  if not any(a <= m.start() < b for a, b in comments)), 0)
    end = text.rfind(f"</{root.tag}>")
    after = text[end + len(root.tag) + 3:] if end >= 0 else "\n"
    body = ET.tostring(root, encoding="unicode")
    if " />" not in text:  # the writer closes empty elements with " />": as the file does, where it never does
        body = body.replace(" />", "/>")
    # the root's start tag as written (the write-back never changes the root's attributes; ElementTree drops the
    # namespace declarations no element uses, e.g. a xacro output's xmlns:xacro)
    written, original = re.match(r"<[^>]*>", body), re.match(r"<[^>]*>", text[start:])
    if written and original and not original.group(0).endswith("/>"):
        body = original.group(0) + body[written.end():]
    return text[:start] + body + after


def _child_indent(root, parent) -> str:
    """The whitespace before each child of ``parent``: as its children are laid out, else two spaces deeper
    than ``parent`` itself."""
    ws = parent.text if len(parent) else None
    if ws is not None and not ws.strip() and "\n" in ws:
        return "\n" + ws.rsplit("\n", 1)[1]
    up = _parents(root).get(parent)
    return (_child_indent(root, up) if up is not None else "\n") + "  "


def _layout(element, base: str) -> None:
    """Lay out the children of a new element (no whitespace yet) one level deeper than ``base``."""
    children = list(element)
    if not children or element.text is not None:
        return
    element.text = base + "  "
    for child in children:
        child.tail = base + "  "
        _layout(child, base + "  ")
    children[-1].tail = base


def _insert(root, parent, element, first: bool = False) -> None:
    """Add ``element`` to ``parent`` (last, or ``first``), indented as its siblings are."""
    inner = _child_indent(root, parent)
    up = _parents(root).get(parent)
    outer = _child_indent(root, up) if up is not None else "\n"
    children = list(parent)
    if not children:
        parent.text, element.tail = inner, outer
        parent.append(element)
    elif first:
        element.tail = parent.text if parent.text is not None and not parent.text.strip() else inner
        parent.text = inner
        parent.insert(0, element)
    else:
        element.tail = children[-1].tail if children[-1].tail is not None else outer
        children[-1].tail = inner
        parent.append(element)
    _layout(element, inner)


def _remove(parent, element) -> None:
    """Remove ``element``, the whitespace after it kept where it closed ``parent``."""
    children = list(parent)
    i = children.index(element)
    if i == len(children) - 1:
        if i > 0:
            children[i - 1].tail = element.tail
        elif element.tail is not None:
            parent.text = element.tail
    parent.remove(element)


def _parents(root) -> dict:
    return {child: parent for parent in root.iter() for child in parent}


def _comment(ident: IdentifiedArm, fmt: str, sidecar: str, unexpressed: list[str]):
    joints = (["armature"] if fmt == "mjcf" else []) + (["damping"] if ident.damping is not None else []) \
        + (["friction loss"] if ident.frictionloss is not None else [])
    lines = [f"lnn_torch write-back ({fmt}): the link masses, centres of mass and inertias"
             + (f" and the joints' {', '.join(joints)}" if joints else "") + f" identified by a {ident.what}."]
    if unexpressed:
        lines.append(f"Not expressed in {fmt.upper()} (every value in {sidecar}):")
        lines += [f"  {u}" for u in unexpressed]
    text = "\n".join(lines).replace("--", "- -")
    return ET.Comment(" " + text.replace("\n", "\n     ") + " ")


def _relocate(value: str, src_dir: Path, out_dir: Path) -> str:
    if not value or "://" in value or os.path.isabs(value) or src_dir.resolve() == out_dir.resolve():
        return value
    return os.path.relpath(src_dir.resolve() / value, out_dir.resolve())


# ---------------------------------------------------------------------------- MJCF
_REFERENCES = {"joint": ("joint", "joint1", "joint2", "jointinparent"), "body": ("body", "body1", "body2"),
               "geom": ("geom", "geom1", "geom2"), "site": ("site", "site1", "site2", "cranksite", "slidersite",
                                                           "refsite")}


def _mjcf_remove(root, names: tuple[str, ...], where) -> None:
    """Remove the bodies ``names`` (with their subtrees) and every element outside the bodies that names
    something in them (actuators, sensors, contact pairs and exclusions, equalities, tendon entries)."""
    parents = _parents(root)
    bodies = {b.get("name"): b for b in root.iter("body") if b.get("name")}
    gone = {kind: set() for kind in _REFERENCES}
    for name in names:
        body = bodies.get(name)
        if body is None:
            raise InputError(f"write-back: {where} has no body '{name}' to remove (is it in an included file?)")
        for el in body.iter():
            if el.tag in ("body", "joint", "geom", "site") and el.get("name"):
                gone[el.tag].add(el.get("name"))
            if el.tag == "freejoint" and el.get("name"):
                gone["joint"].add(el.get("name"))
        _remove(parents[body], body)
    every = set().union(*gone.values())
    changed = True
    while changed:
        changed = False
        parents = _parents(root)
        for el in list(root.iter()):
            if el.tag in ("body", "worldbody") or el not in parents:
                continue
            refs = [el.get(a) for kind, attrs in _REFERENCES.items() for a in attrs if el.get(a) in gone[kind]]
            if el.get("objname") in every or el.get("target") in every:
                refs.append(el.get("objname") or el.get("target"))
            if refs:
                parent = parents[el]
                _remove(parent, el)
                changed = True
                if parent.tag in ("fixed", "spatial") and parent.get("name"):  # a tendon that lost an entry
                    gone.setdefault("tendon", set()).add(parent.get("name"))
                    every.add(parent.get("name"))
        tendons = gone.get("tendon", set())
        for el in list(root.iter()):
            if el.get("tendon") in tendons and el in _parents(root):
                _remove(_parents(root)[el], el)
                changed = True
        for el in list(root.iter()):
            if el.tag in ("fixed", "spatial") and el.get("name") in tendons and el in _parents(root):
                _remove(_parents(root)[el], el)
                changed = True


def _add(root, parent, element, first: bool = False) -> None:
    """Add ``element`` to ``parent``: laid out as its siblings where ``parent`` is in the document, as it is
    where ``parent`` is new (laid out when it is added)."""
    if parent is root or parent in _parents(root):
        _insert(root, parent, element, first)
    elif first:
        parent.insert(0, element)
    else:
        parent.append(element)


def _mjcf_inertial(root, body):
    """The body's ``<inertial>`` with its orientation and inertia attributes cleared (a new one first)."""
    inertial = body.find("inertial")
    if inertial is None:
        inertial = ET.Element("inertial")
        _add(root, body, inertial, first=True)
    for key in (*_ORIENTATIONS, "diaginertia", "fullinertia"):
        inertial.attrib.pop(key, None)
    return inertial


def _mjcf_set_inertial(root, body, J) -> None:
    """A body's inertial from its pseudo-inertia ``J`` in its frame (None: massless); a value the same as the
    file's keeps its text (``_keep``)."""
    found = body.find("inertial")
    was = {} if found is None else dict(found.attrib)
    inertial = _mjcf_inertial(root, body)
    if J is None:
        inertial.set("pos", "0 0 0")
        inertial.set("mass", "0")
        inertial.set("diaginertia", "0 0 0")
        return
    m, c, I = inertial_of(J)
    inertial.set("pos", _keep(was.get("pos"), c))
    inertial.set("mass", _keep(was.get("mass"), [m]))
    full = [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
    scale = float(np.abs(full).max())
    oriented = any(was.get(k) for k in _ORIENTATIONS)
    if not oriented and "diaginertia" in was and _keep(was["diaginertia"] + " 0 0 0", full, scale) \
            == was["diaginertia"] + " 0 0 0":  # the same diagonal inertia: as written
        inertial.set("diaginertia", was["diaginertia"])
    else:
        inertial.set("fullinertia", _keep(None if oriented else was.get("fullinertia"), full, scale))


def _row_J(row) -> np.ndarray:
    from ..robots.kinematics import payload_pseudo_inertia

    return payload_pseudo_inertia(torch.tensor([row], dtype=torch.float64))[0].numpy()


def _write_row(root, body, row, fmt: str) -> None:
    """The inertial of a payload or tool body from its row ``(mass, com[, inertia])`` (a point mass:
    zero inertia, as ``ArmDescription.compile`` writes it)."""
    if fmt == "mjcf":
        inertial = _mjcf_inertial(root, body)
        inertial.set("pos", _nums(row[1:4]))
        inertial.set("mass", _num(row[0]))
        if len(row) == 10 and any(row[4:]):
            inertial.set("fullinertia", _nums(row[4:]))
        else:
            inertial.set("diaginertia", "0 0 0")
    else:
        ixx, iyy, izz, ixy, ixz, iyz = row[4:] if len(row) == 10 else (0.0,) * 6
        _urdf_set_inertial(root, body, row[0], row[1:4], np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]))


def _flange(desc: ArmDescription, spec, path) -> tuple[str, list | None, list | None]:
    """``(body name, pos, quat)`` where the payload body hangs (``ArmDescription.compile``'s rule)."""
    names = [b.name for b in spec.bodies]
    flange = desc._flange(spec, names, path)
    if flange is None:
        body = desc._leaf(spec, path)
        return body.name, None, None
    body, pos, quat = flange
    if not body.name:
        raise InputError(f"write-back: the flange '{desc.flange}' hangs from a body without a name")
    return body.name, pos, quat


def _flange_is_leaf(desc: ArmDescription, spec, path, parent_name: str, pos) -> bool:
    """Whether the written file, read alone (no flange named), puts the payload where ``desc`` does: at the
    origin of the chain's one last body. Only then may a file without a payload go without a payload body
    (a site flange, or a body other than the last, is recorded by the body written there)."""
    if pos is not None:
        return False
    try:
        return desc._leaf(spec, path).name == parent_name
    except InputError:  # the chain ends in several bodies
        return False


def _new_body(root, attrs: dict, row) -> ET.Element:
    """A new body (not yet in the document) with an inertial: ``row``'s, or massless."""
    body = ET.Element("body", attrs)
    inertial = ET.SubElement(body, "inertial")
    inertial.set("pos", "0 0 0")
    inertial.set("mass", "0")
    inertial.set("diaginertia", "0 0 0")
    if row is not None:
        _write_row(root, body, row, "mjcf")
    return body


def _write_mjcf(ident: IdentifiedArm, plan: dict, text: str, src: Path, out: Path, spec) -> ET.Element:
    import mujoco

    desc = ident.description
    if spec.compiler.inertiafromgeom == mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE:
        raise InputError(f"write-back: {src} computes every inertia from its geoms (compiler inertiafromgeom=true), "
                         "which would ignore the identified inertials")
    root = _parse(text)
    if root.tag != "mujoco":
        raise InputError(f"write-back: {src} is not an MJCF file (root <{root.tag}>)")
    for compiler in root.iter("compiler"):
        if float(compiler.get("settotalmass", "-1")) > 0:
            raise InputError(f"write-back: {src} rescales every mass (compiler settotalmass): remove it first")
    if desc.remove:
        _mjcf_remove(root, desc.remove, src)
    bodies = {b.get("name"): b for b in root.iter("body") if b.get("name")}
    # the payload body at the flange, the tool beside it
    payload = bodies.get(PAYLOAD_BODY)
    parent_name, pos, quat = _flange(desc, spec, src) if payload is None else (None, None, None)
    attrs = {"name": PAYLOAD_BODY}
    if pos is not None:
        attrs.update(pos=_nums(pos), quat=_nums(quat))
    if payload is None:
        if parent_name not in bodies:
            raise InputError(f"write-back: {src} has no body '{parent_name}' for the flange (in an included file?)")
        holder, held = bodies[parent_name], (pos, quat)
        if ident.payload is not None or not _flange_is_leaf(desc, spec, src, parent_name, pos):
            # (no payload, and the file read alone finds the flange: no body; the robot as described)
            payload = _new_body(root, attrs, ident.payload)
            _add(root, holder, payload)
    else:
        if ident.payload is not None:
            _write_row(root, payload, ident.payload, "mjcf")
        holder = _parents(root)[payload]
        held = (list(spec.body(PAYLOAD_BODY).pos), list(spec.body(PAYLOAD_BODY).quat))
    if desc.tool is not None:  # beside the payload, at its position and quaternion (ArmDescription.compile)
        if TOOL_BODY in bodies:
            raise InputError(f"write-back: {src} has a body '{TOOL_BODY}' already and the description adds its tool")
        tool_attrs = {"name": TOOL_BODY}
        if held[0] is not None:
            tool_attrs["pos"] = _nums(held[0])
            if held[1] is not None and list(held[1]) != [1.0, 0.0, 0.0, 0.0]:
                tool_attrs["quat"] = _nums(held[1])
        _add(root, holder, _new_body(root, tool_attrs, desc.tool))
    # the identified inertials, the joints
    bodies = {b.get("name"): b for b in root.iter("body") if b.get("name")}
    for name, J in plan.items():
        body = bodies.get(name)
        if body is None:
            raise InputError(f"write-back: {src} has no body '{name}' (is it in an included file?)")
        _mjcf_set_inertial(root, body, J)
    for i, joint_name in enumerate(ident.joint_names):
        joint = next((j for j in root.iter("joint") if j.get("name") == joint_name), None)
        if joint is None:
            raise InputError(f"write-back: {src} has no joint '{joint_name}' (is it in an included file?)")
        joint.set("armature", _num(ident.armature[i]))
        if ident.damping is not None:
            joint.set("damping", _num(ident.damping[i]))
        if ident.frictionloss is not None:
            joint.set("frictionloss", _num(ident.frictionloss[i]))
    # relative asset paths, where the file is written elsewhere
    src_dir, out_dir = src.parent, out.parent
    dirs = ("meshdir", "texturedir", "assetdir")
    compilers = list(root.iter("compiler"))
    has_dir = {k: any(c.get(k) for c in compilers) for k in dirs}
    for c in compilers:
        for k in dirs:
            if c.get(k):
                c.set(k, _relocate(c.get(k), src_dir, out_dir))
    for el in root.iter():
        if el.get("file") is None:
            continue
        by_dir = {"mesh": ("meshdir", "assetdir"), "hfield": ("meshdir", "assetdir"), "skin": ("meshdir", "assetdir"),
                  "texture": ("texturedir", "assetdir")}.get(el.tag, ())
        if not any(has_dir[k] for k in by_dir):
            el.set("file", _relocate(el.get("file"), src_dir, out_dir))
    return root


# ---------------------------------------------------------------------------- URDF
def _urdf_set_inertial(root, link, mass, com, I) -> None:
    """A link's ``<inertial>``: origin at the centre of mass (``rpy 0 0 0``: the link's axes), mass, and
    the inertia about the centre of mass; the elements it has are edited, the missing ones added."""
    inertial = link.find("inertial")
    new = inertial is None
    if new:
        inertial = ET.Element("inertial")
    parts = {}
    for tag in ("origin", "mass", "inertia"):
        parts[tag] = inertial.find(tag)
        if parts[tag] is None:
            parts[tag] = ET.Element(tag)
            _add(root, inertial, parts[tag], first=tag == "origin")
    # a value the same as the file's keeps its text (``_keep``), where the file's inertia is in the link's axes
    axes = not any(float(v) for v in (parts["origin"].get("rpy") or "0 0 0").split())
    parts["origin"].set("xyz", _keep(parts["origin"].get("xyz"), com))
    parts["origin"].set("rpy", "0 0 0")
    parts["mass"].set("value", _keep(parts["mass"].get("value"), [mass]))
    scale = float(np.abs(I).max())
    for key, (a, b) in zip(("ixx", "iyy", "izz", "ixy", "ixz", "iyz"),
                           ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)), strict=True):
        parts["inertia"].set(key, _keep(parts["inertia"].get(key) if axes else None, [I[a, b]], scale))
    if new:
        _add(root, link, inertial, first=True)


def _write_urdf(ident: IdentifiedArm, plan: dict, text: str, src: Path, out: Path, spec) -> ET.Element:
    desc = ident.description
    root = _parse(text)
    if root.tag != "robot":
        raise InputError(f"write-back: {src} is not a URDF file (root <{root.tag}>); write it back as mjcf")
    links = {link.get("name"): link for link in root.findall("link")}
    joints = root.findall("joint")
    if desc.remove:  # the links, their descendants and every joint, transmission and gazebo element naming them
        children = {}
        for j in joints:
            parent, child = j.find("parent"), j.find("child")
            if parent is not None and child is not None:
                children.setdefault(parent.get("link"), []).append(child.get("link"))
        gone, stack = set(), []
        for name in desc.remove:
            if name not in links:
                raise InputError(f"write-back: {src} has no link '{name}' to remove")
            stack.append(name)
        while stack:
            name = stack.pop()
            if name not in gone:
                gone.add(name)
                stack += children.get(name, [])
        gone_joints = {j.get("name") for j in joints
                       if j.find("child") is not None and j.find("child").get("link") in gone}
        for el in list(root):
            if (el.tag == "link" and el.get("name") in gone) or (el.tag == "joint" and el.get("name") in gone_joints) \
                    or (el.tag == "gazebo" and el.get("reference") in gone | gone_joints) \
                    or (el.tag == "transmission" and any(j.get("name") in gone_joints for j in el.findall("joint"))):
                _remove(root, el)
        links = {link.get("name"): link for link in root.findall("link")}
        joints = root.findall("joint")
    parent_name, pos, quat = _flange(desc, spec, src) if PAYLOAD_BODY not in links else (None, None, None)
    joint_names = {j.get("name") for j in joints}

    def add_link(name, parent, row, origin):
        link = ET.Element("link", {"name": name})
        if row is not None:
            _write_row(root, link, row, "urdf")
        joint_name = f"{name}_joint"
        while joint_name in joint_names:
            joint_name += "_"
        joint_names.add(joint_name)
        joint = ET.Element("joint", {"name": joint_name, "type": "fixed"})
        if origin is not None:
            ET.SubElement(joint, "origin", origin)
        ET.SubElement(joint, "parent", {"link": parent})
        ET.SubElement(joint, "child", {"link": name})
        _add(root, root, link)
        _add(root, root, joint)

    origin = None
    if pos is not None:  # a frame in the flange body (URDF has no sites; for completeness)
        from ..robots.kinematics import _quat_matrix

        R = _quat_matrix(quat)
        rpy = (math.atan2(R[2, 1], R[2, 2]), math.asin(-max(-1.0, min(1.0, R[2, 0]))), math.atan2(R[1, 0], R[0, 0]))
        origin = {"xyz": _nums(pos), "rpy": _nums(rpy)}
    if PAYLOAD_BODY in links:
        if ident.payload is not None:
            _write_row(root, links[PAYLOAD_BODY], ident.payload, "urdf")
        holder = next((j for j in joints if j.find("child") is not None
                       and j.find("child").get("link") == PAYLOAD_BODY), None)
        if holder is not None:  # the tool hangs where the payload does (ArmDescription.compile)
            parent_name = holder.find("parent").get("link")
            at = holder.find("origin")
            origin = None if at is None else dict(at.attrib)
    elif ident.payload is not None or not _flange_is_leaf(desc, spec, src, parent_name, pos):
        # (no payload, and the file read alone finds the flange: no link; the robot as described)
        add_link(PAYLOAD_BODY, parent_name, ident.payload, origin)
    if desc.tool is not None:
        if TOOL_BODY in links:
            raise InputError(f"write-back: {src} has a link '{TOOL_BODY}' already and the description adds its tool")
        add_link(TOOL_BODY, parent_name, desc.tool, origin)
    links = {link.get("name"): link for link in root.findall("link")}
    for name, J in plan.items():
        if name not in links:
            raise InputError(f"write-back: {src} has no link '{name}'")
        if J is None:
            _urdf_set_inertial(root, links[name], 0.0, np.zeros(3), np.zeros((3, 3)))
        else:
            _urdf_set_inertial(root, links[name], *inertial_of(J))
    by_name = {j.get("name"): j for j in root.findall("joint")}
    for i, joint_name in enumerate(ident.joint_names):
        joint = by_name.get(joint_name)
        if joint is None:
            raise InputError(f"write-back: {src} has no joint '{joint_name}'")
        if ident.damping is None and ident.frictionloss is None:
            continue
        dynamics = joint.find("dynamics")
        if dynamics is None:
            dynamics = ET.Element("dynamics")
            _add(root, joint, dynamics)
        if ident.damping is not None:
            dynamics.set("damping", _num(ident.damping[i]))
        if ident.frictionloss is not None:
            dynamics.set("friction", _num(ident.frictionloss[i]))
    src_dir, out_dir = src.parent, out.parent
    for el in root.iter():
        if el.tag == "mesh" and el.get("filename"):
            el.set("filename", _relocate(el.get("filename"), src_dir, out_dir))
        if el.tag == "compiler" and el.get("meshdir"):
            el.set("meshdir", _relocate(el.get("meshdir"), src_dir, out_dir))
    return root


def _urdf_as_mjcf(source, path: Path, ident: IdentifiedArm, *, payload, description, overwrite: bool,
                  check: bool) -> WriteBack:
    """The write-back of a URDF-described arm as MJCF: the URDF write-back (beside ``path``, removed after), read by
    MuJoCo's URDF importer (static bodies kept, the mesh files not found here left out), each joint's armature set
    (URDF has no element for it), saved as MJCF and checked as any write-back is."""
    import mujoco

    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists (--overwrite replaces it)")
    path.parent.mkdir(parents=True, exist_ok=True)
    urdf = path.with_name(f".{path.stem}.writing.urdf")
    temp = path.with_name(f".{path.stem}.writing.xml")
    try:
        # (the converted file is the one checked, below)
        back = write_description(source, urdf, "urdf", payload=payload, description=description, check=False)
        spec = mujoco.MjSpec.from_file(str(urdf))
        spec.compiler.fusestatic = False
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            dropped = drop_missing_meshes(spec, urdf)
        for name, value in zip(ident.joint_names, ident.armature, strict=True):
            spec.joint(name).armature = float(value)
        try:
            model = spec.compile()
            root = ET.fromstring(spec.to_xml())
        except ValueError as err:
            raise InputError(f"write-back as mjcf: MuJoCo cannot convert the URDF write-back ({err})") from None
        _exact_frames(root, model)
        head = ET.Comment(f" {ident.what}: identified by lnn_torch from {ident.description.path.name} (URDF), "
                          f"converted to MJCF by MuJoCo {mujoco.__version__}; what MJCF cannot express: "
                          f"{path.name}.json ")
        root.insert(0, head)
        ET.indent(root)
        temp.write_text(ET.tostring(root, encoding="unicode") + "\n")
        rel = _check_written(temp, ident, "mjcf") if check else None
        os.replace(temp, path)
        record = json.loads(back.sidecar.read_text())
        unexpressed = [u for u in record["not_expressed"] if u["term"] != "armature"]
        notes = [n for n in back.notes if "the description names are not found here" not in n]  # (URDF's own)
        notes.append("converted from the URDF write-back by MuJoCo's URDF importer: bodies, joints and inertials as "
                     "MuJoCo reads the URDF, each joint's armature set")
        speeds = [j.get("name") for j in _parse(urdf.read_text()).iter("joint")
                  if j.find("limit") is not None and j.find("limit").get("velocity") is not None]
        if speeds:
            notes.append(f"the URDF's joint velocity limits ({len(speeds)} joints) have no MJCF attribute: not in the "
                         "MJCF (its position limits are the joints' range, its effort limits their actuatorfrcrange)")
        if dropped:
            more = ", ..." if len(dropped) > 1 else ""
            notes.append(f"{len(dropped)} mesh file(s) not found here ({dropped[0]}{more}): their geoms are left out "
                         "of the MJCF (the dynamics do not depend on them)")
        others = Counter(el.tag for el in _parse(urdf.read_text()) if isinstance(el.tag, str)
                         and el.tag not in ("link", "joint", "material"))
        if others:
            notes.append("the URDF's " + ", ".join(f"<{tag}> ({n})" for tag, n in sorted(others.items()))
                         + " elements are not in the MJCF (MuJoCo does not read them; --format urdf keeps them)")
        record.update({"written": path.name, "format": "mjcf", "not_expressed": unexpressed, "notes": notes,
                       "check": None if rel is None else {"largest_relative_difference": rel, "bound": CHECK_RTOL}})
        sidecar = path.with_name(path.name + ".json")
        sidecar.write_text(json.dumps(record, indent=1) + "\n")
        return WriteBack(path, sidecar, "mjcf", [_line(u) for u in unexpressed], notes, back.values)
    finally:
        for leftover in (urdf, urdf.with_name(urdf.name + ".json"), temp):
            leftover.unlink(missing_ok=True)


def _exact_frames(root, model) -> None:
    """Every body's frame, inertial and joint of the MJCF ``root`` (MuJoCo's ``to_xml``, which writes six digits)
    written in full from the compiled ``model`` it was saved from."""
    import mujoco

    for body in root.iter("body"):
        b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body.get("name", ""))
        if b < 0:
            continue
        for key in ("euler", "axisangle", "xyaxes", "zaxis"):
            body.attrib.pop(key, None)
        body.set("pos", _nums(model.body_pos[b]))
        body.set("quat", _nums(model.body_quat[b]))
        inertial = body.find("inertial")
        if inertial is not None:
            inertial.attrib.pop("fullinertia", None)
            inertial.set("pos", _nums(model.body_ipos[b]))
            inertial.set("quat", _nums(model.body_iquat[b]))
            inertial.set("mass", _num(model.body_mass[b]))
            inertial.set("diaginertia", _nums(model.body_inertia[b]))
        for joint in body.findall("joint"):
            j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, joint.get("name", ""))
            if j >= 0:
                d = int(model.jnt_dofadr[j])
                joint.set("pos", _nums(model.jnt_pos[j]))
                joint.set("axis", _nums(model.jnt_axis[j]))
                for key, values in (("armature", model.dof_armature), ("damping", model.dof_damping),
                                    ("frictionloss", model.dof_frictionloss)):
                    joint.set(key, _num(values[d]))
                if joint.get("range") is not None:  # the URDF's limits in full (to_xml: 6.28319 for 6.28318530718)
                    joint.set("range", _nums(model.jnt_range[j]))
                if joint.get("actuatorfrcrange") is not None:
                    joint.set("actuatorfrcrange", _nums(model.jnt_actfrcrange[j]))


# ---------------------------------------------------------------------------- the check
def _compile_file(path: Path):
    import mujoco

    try:
        spec = mujoco.MjSpec.from_file(str(path))
        spec.compiler.fusestatic = False
        drop_missing_meshes(spec, path)  # as the description was read (its meshes' geoms do not enter the check)
        return spec.compile()
    except ValueError as err:
        first = str(err).strip().splitlines()[0] if str(err).strip() else "cannot be compiled"
        raise InputError(f"write-back: the written description does not compile ({first})") from None


def _check_written(path: Path, ident: IdentifiedArm, fmt: str) -> float:
    """The written file's chain against the identified one; the largest relative difference of a link's
    pseudo-inertia. ``InputError`` where anything differs by more than ``CHECK_RTOL``."""
    import mujoco

    from ..robots import kinematics as K

    model = _compile_file(path)
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, PAYLOAD_BODY) < 0:  # written without a payload: read
        # as the file is to be used, as source alone (its payload body added at the chain's last body)
        model = ArmDescription.of(str(path)).compile()
    chain = K.read_chain(model)
    nominal = K.read_chain(ident.description.compile())

    def fail(what):
        raise InputError(f"write-back: the written description does not give the identified arm: {what}")

    if chain.joint_names != nominal.joint_names:
        fail(f"joints {chain.joint_names} instead of {nominal.joint_names}")
    for key in ("X", "axis", "anchor", "qpos0"):
        if not torch.allclose(getattr(chain, key), getattr(nominal, key), rtol=0, atol=1e-12):
            fail(f"its geometry ({key}) changed")
    J = torch.as_tensor(ident.J)
    rel = float(((chain.J - J).abs().amax((-2, -1)) / J.abs().amax((-2, -1))).max())
    if not rel <= CHECK_RTOL:
        fail(f"a link's inertia differs by {rel:.3g} relative")

    def compare(name, got, want):
        want = np.asarray(want, dtype=np.float64)
        if not np.allclose(np.asarray(got), want, rtol=CHECK_RTOL, atol=1e-15):
            fail(f"{name} {_fmt(got)} instead of {_fmt(want)}")

    dofs = [int(model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)]) for n in chain.joint_names]
    if fmt == "mjcf":
        compare("armature", model.dof_armature[dofs], ident.armature)
    if ident.damping is not None:
        compare("damping", model.dof_damping[dofs], ident.damping)
    if ident.frictionloss is not None:
        compare("friction loss", model.dof_frictionloss[dofs], ident.frictionloss)
    if ident.payload is not None:
        got = _body_J(model, mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, PAYLOAD_BODY))
        compare("the payload's pseudo-inertia", got, _row_J(ident.payload))
    if (chain.flange is None) != (nominal.flange is None) or (
            chain.flange is not None and not torch.allclose(chain.flange, nominal.flange, rtol=0, atol=1e-12)):
        fail("the payload body is not at the flange")
    return rel


# ---------------------------------------------------------------------------- the writer
def _format_of(path: Path, format: str | None) -> str:
    if format is None:
        return "urdf" if path.suffix.lower() == ".urdf" else "mjcf"
    if format not in FORMATS:
        raise InputError(f"write-back format must be one of {', '.join(FORMATS)}, got {format!r}")
    return format


def _line(u: dict) -> str:
    values = u.get("values")
    if isinstance(values, dict):
        parts = []
        for k, v in values.items():
            parts.append(f"{k} {_fmt(list(v.values()))}" if isinstance(v, dict) else f"{k} {v:g}")
        shown = "; ".join(parts)
    elif values is None:
        shown = ""
    else:
        shown = _fmt(np.asarray(values, dtype=np.float64).reshape(-1))
    return f"{u['term']}: {u['why']}" + (f" ({shown})" if shown else "")


def write_description(source, path, format: str | None = None, *, payload=None, description=None,
                      overwrite: bool = True, check: bool = True) -> WriteBack:
    """Write the robot description of what ``source`` identified (module docstring) to ``path`` in
    ``format`` (``mjcf``/``urdf``; default from the suffix), and its sidecar ``<path>.json``.

    Args:
        source: an ``LNNModule`` or network with the kinetic part ``spatial``, or an ``ArmModel`` with
            full parameters.
        payload: the load at the flange, ``(mass, cx, cy, cz[, Ixx, Iyy, Izz, Ixy, Ixz, Iyz])`` (kg, m, kg
            m^2; flange frame): written as the body ``payload`` (a grey box is evaluated with it).
        description: the robot description of an ``ArmModel`` (a grey box has its own).
        overwrite: replace an existing file (else ``FileExistsError``).
        check: compile the written file and compare its chain with the identified one (leave on).

    Returns a ``WriteBack``; ``InputError`` in one line where it cannot be written.
    """
    import mujoco

    from ..robots.kinematics import read_chain

    path = Path(path)
    fmt = _format_of(path, format)
    ident = identified_arm(source, payload, description)
    nominal = ident.description.compile()  # the robot as the model saw it
    ident, described = _as_described(ident, read_chain(nominal).J.double().numpy())
    if described:
        ident.notes.append(f"{described} of the links' values lie within the model's round-off ({ident.resolution:.2g} "
                           "relative) of the description's (the data determined nothing there): written as the "
                           "description has them")
    held = (getattr(source, "classical_start", None) or {}).get("held_by_prior") or []
    if held:
        shown = ", ".join(held[:8]) + (f" and {len(held) - 8} more" if len(held) > 8 else "")
        ident.notes.append(f"the training recordings do not determine {len(held)} of the values written ({shown}): "
                           "the fit's prior towards the description holds them (lnn-torch identify lists what the "
                           "recordings determine)")
    desc = ident.description
    src = desc.path
    text = src.read_text()
    original = _parse(text)
    kind = "urdf" if original.tag == "robot" else "mjcf"
    if kind == "urdf" and fmt == "mjcf":  # through the URDF write-back, converted by MuJoCo (armature added)
        return _urdf_as_mjcf(source, path, ident, payload=payload, description=description, overwrite=overwrite,
                             check=check)
    if kind != fmt:
        raise InputError(f"write-back as {fmt}: the robot description {src.name} is {kind.upper()}; write it back as "
                         f"{kind} (--format {kind})")
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists (--overwrite replaces it)")
    sidecar = path.with_name(path.name + ".json")
    spec = mujoco.MjSpec.from_file(str(src))
    spec.compiler.fusestatic = False
    for name in desc.remove:
        body = spec.body(name)
        if body is None:
            raise InputError(f"write-back: {src} has no body '{name}' to remove")
        spec.delete(body)
    plan, notes = _plan(ident, nominal)
    if desc.remove:
        notes.append(f"the bodies the model's description removes ({', '.join(desc.remove)}) and all that hangs from "
                     "them are not in the written file, as the model has none (where the recordings were logged "
                     "with them on, what they weigh is in the links they hang from: putting them back counts it twice)")
    missing = sorted(set(missing_meshes(spec).values()))
    if missing:
        notes.append(f"{len(missing)} mesh file(s) the description names are not found here ({missing[0]}"
                     f"{', ...' if len(missing) > 1 else ''}): written as named, so MuJoCo opens the file where they "
                     "resolve (e.g. with the ROS package's meshes); here, read it with "
                     "lnn_torch.robots.mujoco_arm.load_description, which leaves them out")
    unexpressed = list(ident.unexpressed)
    if fmt == "urdf" and np.any(ident.armature != 0):
        unexpressed.insert(0, {"term": "armature", "why": "rotor inertia per joint (kg m^2) has no URDF element; "
                               "MuJoCo: set each joint's armature", "values": _per_joint(ident.joint_names,
                                                                                       ident.armature)})
    lines = [_line(u) for u in unexpressed]
    writer = _write_mjcf if fmt == "mjcf" else _write_urdf
    path.parent.mkdir(parents=True, exist_ok=True)
    root = writer(ident, plan, text, src, path, spec)
    kind_tag = "body" if fmt == "mjcf" else "link"
    if ident.payload is None and not any(e.get("name") == PAYLOAD_BODY for e in original.iter(kind_tag)) \
            and any(e.get("name") == PAYLOAD_BODY for e in root.iter(kind_tag)):
        notes.append(f"a massless {kind_tag} '{PAYLOAD_BODY}' is added at the flange "
                     f"({desc.flange or 'the chain end'}): it records where loads attach, so that the file read alone "
                     "as a description has the same flange (--payload or --tool gives it a load)")
    _add(root, root, _comment(ident, fmt, sidecar.name, lines), first=True)
    written = _serialise(text, root)
    temp = path.with_name(f".{path.stem}.writing{path.suffix}")
    temp.write_text(written)
    try:
        with warnings.catch_warnings():  # the source's missing meshes were reported when it was read
            warnings.filterwarnings("ignore", message=r"robot description .* mesh file\(s\) not found")
            rel = _check_written(temp, ident, fmt) if check else None
        os.replace(temp, path)
    finally:
        temp.unlink(missing_ok=True)
    values = {"links": {}, "bodies": {}, "joints": {}}
    groups = _body_groups(nominal)
    for i, g in enumerate(groups):
        m, c, I = inertial_of(ident.J[i])
        values["links"][g["body"]] = {"mass": m, "com": c.tolist(), "inertia": I.tolist()}
    for name, J in plan.items():
        if J is None:
            values["bodies"][name] = {"mass": 0.0, "com": [0.0] * 3, "inertia": np.zeros((3, 3)).tolist()}
        else:
            m, c, I = inertial_of(J)
            values["bodies"][name] = {"mass": m, "com": c.tolist(), "inertia": I.tolist()}
    for i, name in enumerate(ident.joint_names):
        values["joints"][name] = {"armature": float(ident.armature[i]),
                                  "damping": None if ident.damping is None else float(ident.damping[i]),
                                  "frictionloss": None if ident.frictionloss is None else float(ident.frictionloss[i])}
    notes = ident.notes + notes
    record = {"written": path.name, "format": fmt, "model": ident.what, "description": desc.to_dict(),
              "payload": None if ident.payload is None else list(ident.payload),
              "use": "as the description's source alone (its changes are applied: no remove, tool or flange)",
              "frames": "links: the moving body with its welded bodies, each body's own frame; com in m, inertia "
                        "about the centre of mass in kg m^2",
              **values, "not_expressed": unexpressed, "notes": notes,
              "check": None if rel is None else {"largest_relative_difference": rel, "bound": CHECK_RTOL}}
    sidecar.write_text(json.dumps(record, indent=1) + "\n")
    return WriteBack(path, sidecar, fmt, lines, notes, values)
