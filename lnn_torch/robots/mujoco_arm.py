"""A serial arm read from its robot description (MJCF) by MuJoCo, which is its ground truth: joint-space
mass matrix, bias forces, passive (damping) forces, inverse and forward dynamics, potential energy,
batched over states and payloads (a loop over MuJoCo's single-state calls: MuJoCo has no batched call
for these; about 3-4 us per state), and the engine's own RK4 integration of one sample interval under
a held torque (``start``/``hold``: data generation).

Conventions: ``q`` the joint angles of the description (rad; its zero configuration and axes; the
Panda's q = 0 lies outside joint 4's range), ``qd`` rad/s, torques N m at the joints, gravity the
description's (MuJoCo's default: -9.81 m/s^2 along world z). The payload is a rigid body at the flange:
``payload = (mass, cx, cy, cz)`` (kg, centre of mass in m in the flange frame) and optionally the six
entries of its inertia about its centre of mass in that frame ``(Ixx, Iyy, Izz, Ixy, Ixz, Iyz)`` (kg m^2;
default a point mass). A method given no payload computes the arm with the description's own (massless in
the shipped ones); no payload carries over between calls.

    M qdd + bias(q, qd) = tau + passive(qd)      (passive = -damping qd; armature is in M)

Generalised forces the engine cannot express (``forces``, a hook; None by default: the engine alone)
are added to the arm in every call that has a velocity, at every stage of the integration: ``forces(arm,
data)`` gives ``(Q_c, Q_d)``, each ``(n,)`` N m, at the state loaded into ``data`` (its kinematics done,
the payload loaded): ``Q_c`` the gradient force ``-dV_x/dq`` of a potential the caller accounts for
(springs, cogging), ``Q_d`` the rest (friction; its power enters the damper's work in ``hold``). With
them ``M qdd + bias = tau + passive + Q_c + Q_d``; ``damping=False`` switches them off with the damper
(``lnn_torch.robots.unmodelled`` gives the scene's).

The dynamics are the smooth ones: MuJoCo's constraint solver (joint limits, contacts) is switched off,
so that forward dynamics is ``qacc_smooth`` everywhere, also outside the joint ranges. ``damping=False``
(the methods that take it) switches the joint damper off (``mjDSBL_DAMPER``): the arm without its
passive force, to which a caller adds its own generalised force.

A perturbed arm (``perturbation=seed``): "a real arm is not its description". The compiled model is
edited, seeded: every moving body's mass (payload excepted) times U(0.8, 1.2), its centre of mass
shifted by U(-0.01, 0.01) m per axis (its own frame), its three principal inertias each times U(0.7,
1.3), the three factors drawn again together until the perturbed inertias satisfy the triangle
inequality (a rigid body's); each joint's armature times U(0.7, 1.3) and damping times U(0.5, 2.0).
``perturbation_report()`` gives the nominal and perturbed values.
"""

from __future__ import annotations

import math
from contextlib import contextmanager

import numpy as np
import torch

from ..errors import InputError
from .description import PAYLOAD_BODY, ArmDescription

# the perturbation's factors and offsets (module docstring)
MASS_FACTOR, COM_SHIFT, INERTIA_FACTOR = (0.8, 1.2), 0.01, (0.7, 1.3)
ARMATURE_FACTOR, DAMPING_FACTOR = (0.7, 1.3), (0.5, 2.0)


def _mujoco():
    try:
        import mujoco
    except ImportError:  # pragma: no cover - the optional dependency
        raise InputError("robot arms need MuJoCo: pip install 'lnn-torch[robots]'") from None
    return mujoco


def load_description(description="franka_panda"):
    """The compiled ``mujoco.MjModel`` of a robot description: a shipped name, an MJCF or URDF path, or
    the description as the robot you have (``ArmDescription``: a dict of source, flange, remove, tool,
    armature, damping); ``InputError`` in one line."""
    return ArmDescription.of(description).compile()


class MujocoArm:
    """The dynamics of a description's arm, the payload a parameter (see the module docstring).

    Args:
        description: a shipped description's name (``franka_panda``), an MJCF or URDF path, or the
            description as the robot you have (``lnn_torch.robots.description.ArmDescription`` or its dict).
        perturbation: None (the description as written) or an int seed of the perturbed arm.
        forces: None (the engine alone) or the hook of further generalised forces (module docstring),
            also settable later as the attribute ``forces``.
    """

    def __init__(self, description="franka_panda", perturbation: int | None = None, forces=None) -> None:
        mujoco = _mujoco()
        self.description = ArmDescription.of(description)
        self.path = self.description.path
        self.model = self.description.compile()
        m = self.model
        _check_serial_arm(m, self.path)
        self.payload_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, PAYLOAD_BODY)
        # smooth dynamics (no joint-limit or contact constraints); the engine's energies on
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
        m.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_ENERGY)
        # a body compiled with its centre of mass at its origin ignores later edits of it, unless told
        m.body_sameframe[self.payload_id] = 0
        self.moving_bodies = tuple(int(b) for b in range(1, m.nbody)
                                   if m.body_weldid[b] != 0 and b != self.payload_id and m.body_mass[b] > 0)
        self._nominal = self._inertials()
        self.perturbation = None if perturbation is None else int(perturbation)
        if self.perturbation is not None:
            self._perturb(np.random.default_rng(self.perturbation))
        i = self.payload_id  # the description's own payload (massless in the shipped ones): payload=None
        self._written = (float(m.body_mass[i]), m.body_ipos[i].copy(), m.body_inertia[i].copy(), m.body_iquat[i].copy())
        self._loaded = None  # the payload row last written into the model
        self.data = mujoco.MjData(m)
        self._sim = None  # the MjData of start/hold
        self.dof = int(m.nv)
        self.joint_names = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(m.njnt))
        self.body_names = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(m.nbody))
        self.actuator_names = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) for a in range(m.nu))
        # a joint without limits (a URDF's continuous joint: MuJoCo's range [0, 0]) turns all the way round
        limited = torch.tensor(m.jnt_limited, dtype=torch.bool)[:, None]
        self.joint_range = torch.where(limited, torch.tensor(m.jnt_range, dtype=torch.float64),
                                       torch.tensor([-math.pi, math.pi], dtype=torch.float64))
        self.armature = torch.tensor(m.dof_armature, dtype=torch.float64)
        self.damping = torch.tensor(m.dof_damping, dtype=torch.float64)
        self.gravity_vector = torch.tensor(m.opt.gravity, dtype=torch.float64)  # m/s^2, world frame
        self.forces = forces
        # which bodies move with each joint (the joint's body and its descendants): gravity_from_kinematics
        subtree = np.zeros((self.dof, m.nbody))
        for j in range(self.dof):
            root = int(m.dof_bodyid[j])
            for b in range(m.nbody):
                k = b
                while k > 0 and k != root:
                    k = int(m.body_parentid[k])
                subtree[j, b] = k == root
        self._subtree = subtree
        joints = np.asarray(m.dof_jntid, dtype=np.int64)
        self._dof_joint = slice(None) if np.array_equal(joints, np.arange(m.njnt)) else joints
        gx, gy, gz = m.opt.gravity
        self._cross_g = np.array([[0.0, -gz, gy], [gz, 0.0, -gx], [-gy, gx, 0.0]])  # r @ this = r x g

    # ------------------------------------------------------------------ perturbation
    def _inertials(self) -> dict:
        """Copies of the values a perturbation edits (moving bodies; every joint)."""
        m, b = self.model, list(self.moving_bodies)
        return {"mass": m.body_mass[b].copy(), "com": m.body_ipos[b].copy(), "inertia": m.body_inertia[b].copy(),
                "armature": m.dof_armature.copy(), "damping": m.dof_damping.copy()}

    def _perturb(self, rng: np.random.Generator) -> None:
        """Edit the compiled model in place (module docstring); draws in a fixed order: per moving body
        its mass factor, centre-of-mass shift and inertia factors, then the armature and damping factors."""
        m = self.model
        for b in self.moving_bodies:
            m.body_mass[b] *= rng.uniform(*MASS_FACTOR)
            m.body_ipos[b] += rng.uniform(-COM_SHIFT, COM_SHIFT, 3)
            principal = m.body_inertia[b].copy()
            for _ in range(100_000):
                scaled = principal * rng.uniform(*INERTIA_FACTOR, 3)
                if np.all(scaled <= scaled.sum() - scaled):  # the triangle inequality of a rigid body
                    break
            else:  # pragma: no cover - only a degenerate inertia (a point or a rod) can fail
                raise InputError(f"robot description {self.path}: no perturbation of body {b}'s inertia "
                                 f"{principal.tolist()} satisfies the triangle inequality")
            m.body_inertia[b] = scaled
            m.body_sameframe[b] = 0  # the shifted centre of mass is no longer the body's origin
        m.dof_armature[:] *= rng.uniform(*ARMATURE_FACTOR, m.nv)
        m.dof_damping[:] *= rng.uniform(*DAMPING_FACTOR, m.nv)

    def perturbation_report(self) -> dict:
        """The nominal (description's) and the model's values of everything a perturbation edits:
        ``{"seed", "bodies": {name: {"mass": [nominal, value] (kg), "com": [[3], [3]] (m, body frame),
        "principal_inertia": [[3], [3]] (kg m^2)}}, "joints": {name: {"armature": [nominal, value]
        (kg m^2), "damping": [nominal, value] (N m s/rad)}}}`` (the two equal without a perturbation)."""
        now = self._inertials()
        bodies = {self.body_names[b]: {"mass": [float(self._nominal["mass"][k]), float(now["mass"][k])],
                                       "com": [self._nominal["com"][k].tolist(), now["com"][k].tolist()],
                                       "principal_inertia": [self._nominal["inertia"][k].tolist(),
                                                             now["inertia"][k].tolist()]}
                  for k, b in enumerate(self.moving_bodies)}
        joints = {name: {"armature": [float(self._nominal["armature"][j]), float(now["armature"][j])],
                         "damping": [float(self._nominal["damping"][j]), float(now["damping"][j])]}
                  for j, name in enumerate(self.joint_names)}
        return {"seed": self.perturbation, "bodies": bodies, "joints": joints}

    # ------------------------------------------------------------------ payload
    def set_payload(self, payload) -> None:
        """``(mass, cx, cy, cz[, Ixx, Iyy, Izz, Ixy, Ixz, Iyz])`` in SI, flange frame."""
        mujoco = _mujoco()
        p = np.asarray(payload, dtype=np.float64).reshape(-1)
        if p.shape[0] not in (4, 10) or not np.isfinite(p).all() or p[0] < 0:
            raise InputError("payload must be (mass >= 0, cx, cy, cz[, Ixx, Iyy, Izz, Ixy, Ixz, Iyz]), "
                             f"got {p.tolist()}")
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
        self._loaded = p.tobytes()

    def _load_payload(self, row) -> None:
        """Write a payload row (None: the description's own) unless it is the one already loaded."""
        if row is None:
            m, i = self.model, self.payload_id
            m.body_mass[i], m.body_ipos[i], m.body_inertia[i], m.body_iquat[i] = self._written
            self._loaded = None
        elif np.asarray(row, dtype=np.float64).tobytes() != self._loaded:
            self.set_payload(row)

    # ------------------------------------------------------------------ per state
    @contextmanager
    def _damper(self, on: bool):
        """The joint damper on (the description's) or off (``mjDSBL_DAMPER``) within the block."""
        flag = int(_mujoco().mjtDisableBit.mjDSBL_DAMPER)
        opt = self.model.opt
        old = opt.disableflags
        opt.disableflags = (old & ~flag) if on else (old | flag)
        try:
            yield
        finally:
            opt.disableflags = old

    def _each(self, q, qd=None, payload=None, qdd=None, tau=None):
        """Yield ``k`` after loading state ``k`` (and its payload) into ``self.data``."""
        q = _array(q, "q", self.dof)
        B = q.shape[0]
        arrays = {name: _array(x, name, self.dof, B) for name, x in (("qd", qd), ("qdd", qdd), ("tau", tau))
                  if x is not None}
        if payload is not None:  # one payload, or one per state
            payload = np.asarray(payload, dtype=np.float64)
            payload = payload.reshape(-1, payload.shape[-1]) if payload.ndim > 1 else payload[None]
            if len(payload) not in (1, B):
                raise InputError(f"payload must be one row or one per state ({B}), got {len(payload)} rows")
        d = self.data
        for k in range(B):
            self._load_payload(None if payload is None else payload[k if len(payload) > 1 else 0])
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

    def potential(self, q, payload=None) -> torch.Tensor:
        """Gravitational potential energy ``(B,)`` in J: MuJoCo's ``mj_energyPos``, ``-sum_i m_i g .
        x_i`` over the bodies (their centres of mass ``x_i``, payload included; the fixed base adds a
        constant)."""
        mujoco = _mujoco()
        out = np.zeros(len(_array(q, "q", self.dof)))
        for k in self._each(q, payload=payload):
            mujoco.mj_kinematics(self.model, self.data)
            mujoco.mj_energyPos(self.model, self.data)
            out[k] = self.data.energy[0]
        return torch.from_numpy(out)

    def _forward_field(self, field: str, q, qd=None, payload=None, tau=None, damping: bool = True) -> torch.Tensor:
        mujoco = _mujoco()
        out = np.zeros((len(_array(q, "q", self.dof)), self.dof))
        hooked = damping and self.forces is not None and field != "qfrc_bias"
        with self._damper(damping):
            for k in self._each(q, qd, payload, tau=tau):
                if hooked:
                    self.data.qfrc_applied[:] += self._extra_force(self.data)
                mujoco.mj_forward(self.model, self.data)
                out[k] = getattr(self.data, field)
        return torch.from_numpy(out)

    def _extra_force(self, d) -> np.ndarray:
        """``Q_c + Q_d (n,)`` of the ``forces`` hook at the state in ``d`` (its kinematics computed here)."""
        _mujoco().mj_kinematics(self.model, d)
        conservative, dissipative = self.forces(self, d)
        return conservative + dissipative

    def gravity_from_kinematics(self, d) -> np.ndarray:
        """The joint torques ``(n,)`` N m that hold the arm still at the state in ``d`` (``gravity``,
        from the bodies' centres of mass after ``mj_kinematics``, the loaded payload's included): for each
        joint, ``-a . (sum_k m_k (x_k - p) x g)`` over the bodies ``k`` it moves, ``a`` its axis and ``p``
        its anchor in the world. For the ``forces`` hook (a joint's gravity load), without another engine
        call."""
        mass, joint = self.model.body_mass, self._dof_joint
        r = self._subtree @ (mass[:, None] * d.xipos) - (self._subtree @ mass)[:, None] * d.xanchor[joint]
        return -np.einsum("ij,ij->i", d.xaxis[joint], r @ self._cross_g)  # -a . (r x g); numpy's cross is slow

    def bias(self, q, qd, payload=None) -> torch.Tensor:
        """Coriolis, centrifugal and gravity forces ``(B, n)`` (MuJoCo's ``qfrc_bias``)."""
        return self._forward_field("qfrc_bias", q, qd, payload)

    def gravity(self, q, payload=None) -> torch.Tensor:
        """``g (B, n)``: the torques that hold the arm still at ``q``, ``bias(q, 0)``."""
        return self.bias(q, np.zeros_like(_array(q, "q", self.dof)), payload)

    def friction(self, q, qd, payload=None) -> torch.Tensor:
        """Joint damping forces ``Q_f = -damping qd (B, n)`` (MuJoCo's ``qfrc_passive`` of this
        description; ``q`` and ``payload`` do not change it)."""
        return -torch.as_tensor(np.asarray(qd), dtype=torch.float64) * self.damping

    def forward(self, q, qd, tau, payload=None, damping: bool = True) -> torch.Tensor:
        """Accelerations ``(B, n)`` under joint torques ``tau`` (smooth dynamics, ``qacc_smooth``), the
        ``forces`` hook's included; ``damping=False``: without the joint damper and the hook (``M qdd +
        bias = tau``)."""
        return self._forward_field("qacc_smooth", q, qd, payload, tau, damping)

    def inverse(self, q, qd, qdd, payload=None, damping: bool = True) -> torch.Tensor:
        """The joint torques ``(B, n)`` that give ``qdd`` (MuJoCo's ``mj_inverse``: ``M qdd + bias -
        passive``, less the ``forces`` hook's ``Q_c + Q_d``; ``damping=False``: ``M qdd + bias``)."""
        mujoco = _mujoco()
        out = np.zeros((len(_array(q, "q", self.dof)), self.dof))
        hooked = damping and self.forces is not None
        with self._damper(damping):
            for k in self._each(q, qd, payload, qdd=qdd):
                extra = self._extra_force(self.data) if hooked else 0.0
                mujoco.mj_inverse(self.model, self.data)
                out[k] = self.data.qfrc_inverse - extra
        return torch.from_numpy(out)

    # ------------------------------------------------------------------ integration (data generation)
    def start(self, q, qd, payload=None) -> None:
        """Put the arm at ``q``, ``qd`` ``(n,)`` with its payload: the state that ``hold`` advances."""
        q, qd = (_array(np.reshape(x, (1, -1)), name, self.dof)[0] for name, x in (("q", q), ("qd", qd)))
        if self._sim is None:  # its own MjData: the per-state methods may run between two holds
            self._sim = _mujoco().MjData(self.model)
        self._load_payload(payload)
        self._sim_payload = payload if payload is None else np.asarray(payload, dtype=np.float64).copy()
        self._sim.qpos[:], self._sim.qvel[:], self._sim.qfrc_applied[:] = q, qd, 0.0

    def hold(self, tau, dt: float, substeps: int = 1):
        """Advance the state of ``start`` by ``dt`` s under the torques ``tau (n,)`` held constant
        (N m, zero-order hold): MuJoCo's RK4 (``mj_RungeKutta``) in ``substeps`` steps of ``dt /
        substeps``, damper on, no constraints.

        Returns ``(qdd, work)``: the acceleration at the start under ``tau`` ``(n,)`` (the engine's
        ``qacc``, exactly ``forward(q, qd, tau)``) and the work ``(2,)`` in J over the interval of the
        torques ``int tau . qd dt`` and of the damper ``int -qd . D qd dt``, each by the trapezoidal
        rule with its end correction (error O(h^5) per step of length h: ``h/2 (P0 + P1) + h^2/12
        (P0' - P1')``, ``P' = tau . qdd`` and ``-2 qd . D qdd``). The new state is ``state()``.

        With the ``forces`` hook (module docstring) the hook's forces act at every stage: the classical
        RK4 written here over the engine's ``mj_forward`` (``mj_RungeKutta`` holds the applied force
        through its stages), the work integrated by the same stages (RK4 of the augmented system ``W' =
        P``, error O(h^5) per step), the damper's column with the power ``qd . Q_d`` of the hook's
        non-conservative part (``Q_c``'s work is its potential's change, which the caller's energy holds).
        """
        mujoco = _mujoco()
        if self._sim is None:
            raise InputError("MujocoArm.hold: call start() first")
        m, d = self.model, self._sim
        self._load_payload(self._sim_payload)  # (unless loaded: the per-state methods may load others)
        tau = _array(np.reshape(tau, (1, -1)), "tau", self.dof)[0]
        if not (np.isfinite(dt) and dt > 0 and int(substeps) >= 1):
            raise InputError(f"MujocoArm.hold: dt must be positive and substeps >= 1, got dt={dt}, substeps={substeps}")
        h = dt / int(substeps)
        D = m.dof_damping
        if self.forces is not None:
            return self._hold_with_forces(tau, h, int(substeps))
        m.opt.timestep = h
        d.qfrc_applied[:] = tau
        work = np.zeros(2)

        def powers():
            qd, qdd = d.qvel, d.qacc
            return (np.array([tau @ qd, -qd @ (D * qd)]), np.array([tau @ qdd, -2 * qd @ (D * qdd)]))

        with self._damper(True):
            mujoco.mj_forward(m, d)
            qdd0 = d.qacc.copy()
            p0, dp0 = powers()
            for _ in range(int(substeps)):
                mujoco.mj_RungeKutta(m, d, 4)
                mujoco.mj_forward(m, d)  # the accelerations at the step's end (the next step's start)
                p1, dp1 = powers()
                work += h / 2 * (p0 + p1) + h**2 / 12 * (dp0 - dp1)
                p0, dp0 = p1, dp1
        return qdd0, work

    def _hold_with_forces(self, tau: np.ndarray, h: float, substeps: int):
        """``hold`` with the ``forces`` hook: classical RK4 in ``substeps`` steps of ``h`` over the engine's
        accelerations, the hook evaluated at each stage (``hold``'s docstring)."""
        mujoco = _mujoco()
        m, d = self.model, self._sim
        D = m.dof_damping

        def stage(q, qd):  # the accelerations and the powers (torques, damper + hook's Q_d) at one state
            d.qpos[:], d.qvel[:] = q, qd
            mujoco.mj_kinematics(m, d)
            conservative, dissipative = self.forces(self, d)
            d.qfrc_applied[:] = tau + conservative + dissipative
            mujoco.mj_forward(m, d)
            return d.qacc.copy(), np.array([tau @ qd, qd @ (dissipative - D * qd)])

        q, qd = d.qpos.copy(), d.qvel.copy()
        work = np.zeros(2)
        qdd0 = None
        with self._damper(True):
            for _ in range(substeps):
                a1, p1 = stage(q, qd)
                qdd0 = a1 if qdd0 is None else qdd0
                a2, p2 = stage(q + h / 2 * qd, qd + h / 2 * a1)
                v2 = qd + h / 2 * a1
                a3, p3 = stage(q + h / 2 * v2, qd + h / 2 * a2)
                v3 = qd + h / 2 * a2
                a4, p4 = stage(q + h * v3, qd + h * a3)
                v4 = qd + h * a3
                q = q + h / 6 * (qd + 2 * v2 + 2 * v3 + v4)
                qd = qd + h / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
                work += h / 6 * (p1 + 2 * p2 + 2 * p3 + p4)
        d.qpos[:], d.qvel[:], d.qfrc_applied[:] = q, qd, tau
        return qdd0, work

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """The current ``(q, qd)`` of ``start``/``hold``, copies ``(n,)`` each."""
        return self._sim.qpos.copy(), self._sim.qvel.copy()

    # ------------------------------------------------------------------ identification
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
        p = payload if isinstance(payload, torch.Tensor) else torch.as_tensor(np.asarray(payload, dtype=np.float64))
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


def _check_serial_arm(m, path) -> None:
    """Refuse, in one line, what is not a serial arm of hinge joints with massive links: another joint
    type, a branched kinematic tree (two moving children of one body), a moving body without mass."""
    mujoco = _mujoco()
    name = lambda kind, i: mujoco.mj_id2name(m, kind, i) or f"#{i}"  # noqa: E731
    joint_type = {int(mujoco.mjtJoint.mjJNT_FREE): "free", int(mujoco.mjtJoint.mjJNT_BALL): "ball",
                  int(mujoco.mjtJoint.mjJNT_SLIDE): "slide"}
    for j in range(m.njnt):
        if int(m.jnt_type[j]) != int(mujoco.mjtJoint.mjJNT_HINGE):
            body = name(mujoco.mjtObj.mjOBJ_BODY, int(m.jnt_bodyid[j]))
            raise InputError(f"robot description {path}: joint '{name(mujoco.mjtObj.mjOBJ_JOINT, j)}' is a "
                             f"{joint_type.get(int(m.jnt_type[j]), 'non-hinge')} joint; only hinge joints are "
                             f"supported (a gripper's finger: leave its body out, remove: [{body}], and the link it "
                             "hangs from takes up its mass)")
    if m.nv == 0:
        raise InputError(f"robot description {path} has no joints: a serial arm of hinge joints is expected")
    for i in range(1, m.nv):  # in a serial chain each joint hangs from the one before it
        if m.dof_parentid[i] != i - 1:
            parent = 0 if m.dof_parentid[i] < 0 else m.dof_bodyid[m.dof_parentid[i]]
            raise InputError(f"robot description {path}: the kinematic tree branches at body "
                             f"'{name(mujoco.mjtObj.mjOBJ_BODY, parent)}' (joint "
                             f"'{name(mujoco.mjtObj.mjOBJ_JOINT, m.dof_jntid[i])}' does not continue the chain "
                             f"after joint '{name(mujoco.mjtObj.mjOBJ_JOINT, m.dof_jntid[i - 1])}'): a serial "
                             "arm is expected")
    for b in range(1, m.nbody):
        if m.body_jntnum[b] > 0 and not m.body_mass[b] > 0:
            raise InputError(f"robot description {path}: body '{name(mujoco.mjtObj.mjOBJ_BODY, b)}' moves but "
                             "has no mass (give it an <inertial>)")


def _array(x, name: str, dof: int, batch: int | None = None) -> np.ndarray:
    a = x.detach().double().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != dof or (batch is not None and a.shape[0] != batch):
        raise InputError(f"{name} must have shape ({batch if batch is not None else 'batch'}, {dof}), got {a.shape}")
    if not np.isfinite(a).all():
        raise InputError(f"{name} contains NaN or Inf")
    return a
