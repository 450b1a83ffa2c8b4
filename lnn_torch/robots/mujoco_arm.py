"""A serial arm read from its robot description (MJCF) by MuJoCo, which is its ground truth: joint-space
mass matrix, bias forces, passive (damping) forces, inverse and forward dynamics, potential energy,
batched over states and payloads (a loop over MuJoCo's single-state calls: MuJoCo has no batched call
for these; about 3-4 us per state).

Conventions: ``q`` the joint angles of the description (rad; its zero configuration and axes; the
Panda's q = 0 lies outside joint 4's range), ``qd`` rad/s, torques N m at the joints, gravity -9.81
m/s^2 along world z. The payload is a rigid body at the flange: ``payload = (mass, cx, cy, cz)`` (kg,
centre of mass in m in the flange frame) and optionally the six entries of its inertia about its centre
of mass in that frame ``(Ixx, Iyy, Izz, Ixy, Ixz, Iyz)`` (kg m^2; default a point mass). A method
given no payload computes the arm with the description's own (massless in the shipped ones); no payload
carries over between calls.

    M qdd + bias(q, qd) = tau + passive(qd)      (passive = -damping qd; armature is in M)
"""

from __future__ import annotations

import numpy as np
import torch

from ..errors import InputError
from . import description_path

PAYLOAD_BODY = "payload"


def _mujoco():
    try:
        import mujoco
    except ImportError:  # pragma: no cover - the optional dependency
        raise InputError("robot arms need MuJoCo: pip install 'lnn-torch[robots]'") from None
    return mujoco


def load_description(description="franka_panda"):
    """The compiled ``mujoco.MjModel`` of a shipped description or an MJCF path; ``InputError`` in one line."""
    mujoco = _mujoco()
    path = description_path(description)
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as err:
        raise InputError(f"robot description {path}: {str(err).splitlines()[0]}") from None


class MujocoArm:
    """The dynamics of a description's arm, the payload a parameter (see the module docstring)."""

    def __init__(self, description="franka_panda") -> None:
        mujoco = _mujoco()
        self.path = description_path(description)
        try:
            self.model = mujoco.MjModel.from_xml_path(str(self.path))
        except ValueError as err:
            raise InputError(f"robot description {self.path}: {str(err).splitlines()[0]}") from None
        m = self.model
        if m.nq != m.nv or m.nv == 0 or any(m.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE for j in range(m.njnt)):
            raise InputError(f"robot description {self.path}: a serial arm of hinge joints is expected "
                             f"({m.njnt} joints, nq = {m.nq}, nv = {m.nv})")
        self.payload_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, PAYLOAD_BODY)
        if self.payload_id < 0:
            raise InputError(f"robot description {self.path} has no body '{PAYLOAD_BODY}' at its flange (add "
                             f"<body name=\"{PAYLOAD_BODY}\" pos=...><inertial mass=\"0\" pos=\"0 0 0\" "
                             "diaginertia=\"0 0 0\"/></body> to the last link)")
        # a body compiled with its centre of mass at its origin ignores later edits of it, unless told
        m.body_sameframe[self.payload_id] = 0
        i = self.payload_id  # the description's own payload (massless in the shipped ones): payload=None
        self._written = (float(m.body_mass[i]), m.body_ipos[i].copy(), m.body_inertia[i].copy(), m.body_iquat[i].copy())
        self.data = mujoco.MjData(m)
        self.dof = int(m.nv)
        self.joint_names = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(m.njnt))
        self.joint_range = torch.tensor(m.jnt_range, dtype=torch.float64)
        self.armature = torch.tensor(m.dof_armature, dtype=torch.float64)
        self.damping = torch.tensor(m.dof_damping, dtype=torch.float64)
        self.gravity = torch.tensor(m.opt.gravity, dtype=torch.float64)

    # ------------------------------------------------------------------ payload
    def set_payload(self, payload) -> None:
        """``(mass, cx, cy, cz[, Ixx, Iyy, Izz, Ixy, Ixz, Iyz])`` in SI, flange frame."""
        mujoco = _mujoco()
        p = np.asarray(payload, dtype=np.float64).reshape(-1)
        if p.shape[0] not in (4, 10) or not np.isfinite(p).all() or p[0] < 0:
            raise InputError(f"payload must be (mass >= 0, cx, cy, cz[, Ixx, Iyy, Izz, Ixy, Ixz, Iyz]), got {p.tolist()}")
        m, i = self.model, self.payload_id
        m.body_mass[i], m.body_ipos[i] = p[0], p[1:4]
        inertia = np.zeros((3, 3))
        if p.shape[0] == 10:
            ixx, iyy, izz, ixy, ixz, iyz = p[4:]
            inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        w, v = np.linalg.eigh(inertia)
        if w.min() < -1e-12:
            raise InputError(f"payload inertia is not positive semi-definite (eigenvalues {w.tolist()})")
        if np.linalg.det(v) < 0:
            v[:, 0] = -v[:, 0]
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, v.reshape(-1))
        m.body_inertia[i], m.body_iquat[i] = np.clip(w, 0, None), quat

    # ------------------------------------------------------------------ per state
    def _each(self, q, qd=None, payload=None, qdd=None, tau=None):
        """Yield ``k`` after loading state ``k`` (and its payload) into ``self.data``."""
        q = _array(q, "q", self.dof)
        B = q.shape[0]
        arrays = {name: _array(x, name, self.dof, B) for name, x in (("qd", qd), ("qdd", qdd), ("tau", tau))
                  if x is not None}
        if payload is None:
            m, i = self.model, self.payload_id
            m.body_mass[i], m.body_ipos[i], m.body_inertia[i], m.body_iquat[i] = self._written
        else:
            payload = np.asarray(payload, dtype=np.float64)
            payload = payload.reshape(B if payload.ndim > 1 else 1, -1)  # one payload, or one per state
        d = self.data
        for k in range(B):
            if payload is not None and (k == 0 or len(payload) > 1):
                self.set_payload(payload[k if len(payload) > 1 else 0])
            d.qpos[:] = q[k]
            d.qvel[:] = arrays["qd"][k] if "qd" in arrays else 0.0
            d.qacc[:] = arrays["qdd"][k] if "qdd" in arrays else 0.0
            d.qfrc_applied[:] = arrays["tau"][k] if "tau" in arrays else 0.0
            yield k

    def mass_matrix(self, q, payload=None) -> torch.Tensor:
        """``M (B, n, n)``, armature included."""
        mujoco = _mujoco()
        out = np.zeros((len(_array(q, "q", self.dof)), self.dof, self.dof))
        for k in self._each(q, payload=payload):
            mujoco.mj_kinematics(self.model, self.data)
            mujoco.mj_comPos(self.model, self.data)
            mujoco.mj_crb(self.model, self.data)
            mujoco.mj_fullM(self.model, self.data, out[k])
        return torch.from_numpy(out)

    def _forward_field(self, field: str, q, qd=None, payload=None, tau=None) -> torch.Tensor:
        mujoco = _mujoco()
        out = np.zeros((len(_array(q, "q", self.dof)), self.dof))
        for k in self._each(q, qd, payload, tau=tau):
            mujoco.mj_forward(self.model, self.data)
            out[k] = getattr(self.data, field)
        return torch.from_numpy(out)

    def bias(self, q, qd, payload=None) -> torch.Tensor:
        """Coriolis, centrifugal and gravity forces ``(B, n)`` (MuJoCo's ``qfrc_bias``)."""
        return self._forward_field("qfrc_bias", q, qd, payload)

    def gravity_torque(self, q, payload=None) -> torch.Tensor:
        """The torques that hold the arm still at ``q``: ``bias(q, 0)``."""
        return self.bias(q, np.zeros_like(_array(q, "q", self.dof)), payload)

    def passive(self, qd) -> torch.Tensor:
        """Joint damping forces ``-damping qd`` (MuJoCo's ``qfrc_passive`` of this description)."""
        return -torch.as_tensor(np.asarray(qd), dtype=torch.float64) * self.damping

    def forward(self, q, qd, tau, payload=None) -> torch.Tensor:
        """Accelerations ``(B, n)`` under joint torques ``tau`` (smooth dynamics: no joint-limit
        constraint, ``qacc_smooth``)."""
        return self._forward_field("qacc_smooth", q, qd, payload, tau)

    def inverse(self, q, qd, qdd, payload=None) -> torch.Tensor:
        """The joint torques ``(B, n)`` that give ``qdd`` (MuJoCo's ``mj_inverse``: ``M qdd + bias -
        passive``)."""
        mujoco = _mujoco()
        out = np.zeros((len(_array(q, "q", self.dof)), self.dof))
        for k in self._each(q, qd, payload, qdd=qdd):
            mujoco.mj_inverse(self.model, self.data)
            out[k] = self.data.qfrc_inverse
        return torch.from_numpy(out)

    def payload_regressor(self, q, qd, qdd) -> torch.Tensor:
        """``Y (B, n, 10)``: the joint torques a payload adds are linear in its inertial parameters
        ``pi = (m, m c (3), I_o (Ixx, Iyy, Izz, Ixy, Ixz, Iyz))`` (centre of mass ``c`` and inertia ``I_o``
        about the flange point, flange frame): ``inverse(payload) - inverse(description's) = Y pi``
        (Newton-Euler of the payload body: the flange's angular velocity and acceleration and its
        acceleration against gravity from MuJoCo, mapped to the joints by the flange Jacobian). The
        classical least-squares identification stacks these rows."""
        mujoco = _mujoco()
        m, d, i = self.model, self.data, self.payload_id
        out = np.zeros((len(_array(q, "q", self.dof)), self.dof, 10))
        vel, acc = np.zeros(6), np.zeros(6)
        jacp, jacr = np.zeros((3, self.dof)), np.zeros((3, self.dof))
        for k in self._each(q, qd, None, qdd=qdd):
            mujoco.mj_inverse(m, d)
            mujoco.mj_rnePostConstraint(m, d)
            mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, i, vel, 1)
            mujoco.mj_objectAcceleration(m, d, mujoco.mjtObj.mjOBJ_BODY, i, acc, 1)
            mujoco.mj_jacBody(m, d, jacp, jacr, i)
            R = d.xmat[i].reshape(3, 3)
            Jv, Jw = R.T @ jacp, R.T @ jacr  # flange frame
            w, dw, a = vel[:3], acc[:3], acc[3:]  # a: the flange point's acceleration against gravity
            force, moment = np.zeros((3, 10)), np.zeros((3, 10))
            force[:, 0] = a
            for j in range(3):
                e = np.eye(3)[j]
                force[:, 1 + j] = np.cross(dw, e) + np.cross(w, np.cross(w, e))
                moment[:, 1 + j] = np.cross(e, a)
            for j, (r, c) in enumerate(((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))):
                E = np.zeros((3, 3))
                E[r, c] = E[c, r] = 1.0
                moment[:, 4 + j] = E @ dw + np.cross(w, E @ w)
            out[k] = Jv.T @ force + Jw.T @ moment
        return torch.from_numpy(out)

    @staticmethod
    def inertial_parameters(payload) -> torch.Tensor:
        """``pi (10,)`` of ``payload_regressor`` from ``(mass, c (3)[, I_com (6)])`` (parallel axes)."""
        p = torch.as_tensor(np.asarray(payload, dtype=np.float64))
        mass, c = p[0], p[1:4]
        I = torch.zeros(3, 3, dtype=torch.float64)
        if p.shape[0] == 10:
            ixx, iyy, izz, ixy, ixz, iyz = p[4:]
            I = torch.stack([torch.stack([ixx, ixy, ixz]), torch.stack([ixy, iyy, iyz]), torch.stack([ixz, iyz, izz])])
        I_o = I + mass * (c.dot(c) * torch.eye(3, dtype=torch.float64) - torch.outer(c, c))
        return torch.cat([mass[None], mass * c, I_o[[0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]]])

    def payload_position(self, q, payload) -> torch.Tensor:
        """The payload's centre of mass in the world ``(B, 3)`` (m) at ``q``."""
        mujoco = _mujoco()
        out = np.zeros((len(_array(q, "q", self.dof)), 3))
        for k in self._each(q, payload=payload):
            mujoco.mj_kinematics(self.model, self.data)
            out[k] = self.data.xipos[self.payload_id]
        return torch.from_numpy(out)

    def sample_q(self, rng: np.random.Generator, n: int, margin: float = 0.1) -> np.ndarray:
        """Joint angles uniform within the description's ranges, ``margin`` rad inside each end."""
        low, high = self.joint_range[:, 0].numpy() + margin, self.joint_range[:, 1].numpy() - margin
        return rng.uniform(low, high, (n, self.dof))


def _array(x, name: str, dof: int, batch: int | None = None) -> np.ndarray:
    a = x.detach().double().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != dof or (batch is not None and a.shape[0] != batch):
        raise InputError(f"{name} must have shape ({batch if batch is not None else 'batch'}, {dof}), got {a.shape}")
    if not np.isfinite(a).all():
        raise InputError(f"{name} contains NaN or Inf")
    return a
