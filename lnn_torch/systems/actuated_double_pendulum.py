"""Actuated double pendulum with rigid links, joint friction and motor torques (a lab-scale robot arm,
the acrobot and the pendubot as special cases of its actuation mask).

Conventions (written into every dataset file):

* ``q = (q1, q2)``: ``q1`` the angle of link 1 from the downward vertical, ``q2`` the angle of link 2
  RELATIVE to link 1 (a joint angle, as robot encoders measure it); rad, counter-clockwise positive.
  (The absolute angle of link 2 is ``q1 + q2``; ``double_pendulum`` uses absolute angles.)
* ``params = (m1, m2, l1, r1, r2, I1, I2, b1, b2, c1, c2)``: link masses (kg), the length of link 1
  (m; the distance between the two joints), the distance of each link's centre of mass from its own
  joint (m), each link's moment of inertia about its own joint (kg m^2), viscous friction per joint
  (N m s/rad, >= 0) and Coulomb friction per joint (N m, >= 0). The length of link 2 does not enter
  its dynamics (only r2 and I2 do) and is not a parameter.
* Inputs ``tau``: the motor torque at each actuated joint (N m); ``actuated`` selects the joints
  (both by default; ``(True, False)`` is a pendubot, ``(False, True)`` an acrobot).
* Joint friction ``f_j = b_j qd_j + c_j tanh(qd_j / v)`` with ``v = coulomb_velocity`` (rad/s).
* g = 9.81 m/s^2 along -y.

Physics, with ``c2 = cos q2``, ``h = m2 l1 r2 sin q2``:

* ``M11 = I1 + I2 + m2 l1^2 + 2 m2 l1 r2 c2``, ``M12 = I2 + m2 l1 r2 c2``, ``M22 = I2``, ``T = 1/2 qd^T M qd``
* ``V = -m1 g r1 cos q1 - m2 g (l1 cos q1 + r2 cos(q1 + q2))``
* ``M qdd = -c(q, qd) + G(q) + B tau - f(qd)`` with ``c = (-2 h qd1 qd2 - h qd2^2, h qd1^2)`` and
  ``G = -dV/dq`` (the same equations as the lab model in ``shared/data/real_double_pendulum``,
  without its motor-rotor terms).

Point masses (``r_i = l_i``, ``I_i = m_i l_i^2``) give the ``double_pendulum`` in joint angles (tested).

Default sampler (around a lab-scale arm): ``m_i ~ U(0.4, 0.8)``, ``l1 ~ U(0.2, 0.3)``,
``r1 = l1 U(0.5, 1)``, ``r2 = U(0.2, 0.3) U(0.5, 1)`` (link 2 of 0.2-0.3 m), ``I_i = m_i r_i^2
(1 + U(0.05, 0.4))`` (a distributed link about its joint), ``b_i ~ U(0, 0.05)``, ``c_i ~ U(0, 0.15)``,
``q ~ U(-pi/2, pi/2)^2``, ``qd ~ U(-2, 2)^2``; inputs: multisines (``default_excitation``).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..errors import InputError
from ..mechanics.friction import friction_torque
from .base import GRAVITY, System, as_range

PARAM_NAMES = ("m1", "m2", "l1", "r1", "r2", "I1", "I2", "b1", "b2", "c1", "c2")


class ActuatedDoublePendulum(System):
    name = "actuated_double_pendulum"
    dof = 2
    angle_mask = (True, True)
    coord_names = ("q1", "q2")
    param_names = PARAM_NAMES
    param_units = ("kg", "kg", "m", "m", "m", "kg m^2", "kg m^2", "N m s/rad", "N m s/rad", "N m", "N m")
    param_kinds = ("positive",) * 7 + ("nonnegative",) * 4
    quadratic_kinetic = True
    # smoothed Coulomb friction is stiff near zero velocity: 8 RK8 substeps per 5 ms sample keep the
    # power balance within 1e-10 for nearly every trajectory (the rest are refined adaptively)
    ground_truth_substeps = 8

    def __init__(self, actuated=(True, True), m_range=(0.4, 0.8), l1_range=(0.2, 0.3), l2_range=(0.2, 0.3),
                 com_ratio=(0.5, 1.0), inertia_excess=(0.05, 0.4), viscous_range=(0.0, 0.05),
                 coulomb_range=(0.0, 0.15), coulomb_velocity: float = 0.05,
                 theta_range=(-math.pi / 2, math.pi / 2), omega_range=(-2.0, 2.0)) -> None:
        try:
            self.actuated = tuple(bool(a) for a in actuated)
        except TypeError:
            raise InputError(f"actuated_double_pendulum: actuated must be two booleans, got {actuated!r}") from None
        if len(self.actuated) != 2:
            raise InputError(f"actuated_double_pendulum: actuated must be two booleans, got {actuated!r}")
        self.m_range, self.l1_range = as_range(m_range, "m_range"), as_range(l1_range, "l1_range")
        self.l2_range, self.com_ratio = as_range(l2_range, "l2_range"), as_range(com_ratio, "com_ratio")
        self.inertia_excess = as_range(inertia_excess, "inertia_excess")
        self.viscous_range = as_range(viscous_range, "viscous_range")
        self.coulomb_range = as_range(coulomb_range, "coulomb_range")
        self.theta_range, self.omega_range = as_range(theta_range, "theta_range"), as_range(omega_range, "omega_range")
        for name in ("m_range", "l1_range", "l2_range", "com_ratio"):
            if getattr(self, name).low <= 0:
                raise InputError(f"actuated_double_pendulum: {name} must be positive, got {getattr(self, name)}")
        for name in ("inertia_excess", "viscous_range", "coulomb_range"):
            if getattr(self, name).low < 0:
                raise InputError(f"actuated_double_pendulum: {name} must be >= 0, got {getattr(self, name)}")
        if not (math.isfinite(coulomb_velocity) and coulomb_velocity > 0):
            raise InputError(f"actuated_double_pendulum: coulomb_velocity must be positive, got {coulomb_velocity}")
        self.coulomb_velocity = float(coulomb_velocity)
        self.input_names = tuple(f"tau{i + 1}" for i, a in enumerate(self.actuated) if a)
        kind = {(True, True): "both joints actuated", (True, False): "pendubot: only the first joint actuated",
                (False, True): "acrobot: only the second joint actuated", (False, False): "no joint actuated"}
        self.conventions = (
            "q=(q1, q2): q1 angle of link 1 from the downward vertical, q2 angle of link 2 relative to link 1 "
            "(joint angles), counter-clockwise positive, rad; params=(m1, m2, l1, r1, r2, I1, I2, b1, b2, c1, c2): "
            "kg, kg, m, m, m, kg m^2 (about each link's own joint), kg m^2, N m s/rad, N m s/rad, N m, N m; "
            f"joint friction b qd + c tanh(qd / {self.coulomb_velocity:g}); inputs tau = motor torques at the "
            f"actuated joints, N m ({kind[self.actuated]}); g=9.81 m/s^2"
        )

    def config(self) -> dict:
        pair = lambda r: [r.low, r.high]  # noqa: E731
        return {"actuated": list(self.actuated), "coulomb_velocity": self.coulomb_velocity,
                **{k: pair(getattr(self, k)) for k in ("m_range", "l1_range", "l2_range", "com_ratio", "inertia_excess",
                                                       "viscous_range", "coulomb_range", "theta_range", "omega_range")}}

    def check_params(self, params: torch.Tensor) -> None:
        """Also refuses a link whose inertia about its joint is below ``m r^2`` (the parallel-axis
        bound: no rigid body has it, and the mass matrix need not be positive definite)."""
        super().check_params(params)
        m, r, inertia = params[..., 0:2], params[..., 3:5], params[..., 5:7]
        short = inertia < m * r**2 * (1 - 1e-9)
        if short.any():
            i = int(short.reshape(-1, 2).any(0).nonzero()[0])
            row = short[..., i].reshape(-1).nonzero()[0, 0]
            I_, m_, r_ = (x[..., i].reshape(-1)[row] for x in (inertia, m, r))
            raise InputError(f"{self.name}: I{i + 1} = {float(I_):.4g} kg m^2 is below m{i + 1} r{i + 1}^2 = "
                             f"{float(m_ * r_**2):.4g} kg m^2: a link's inertia about its joint is at least m r^2")

    def scaled_params(self, params: torch.Tensor, k: float) -> tuple[torch.Tensor, str]:
        """The similar arm ``k`` times larger under the same gravity (masses and lengths times ``k``,
        time times ``sqrt(k)``): inertias times ``k^3``, Coulomb torques ``k^2``, viscous
        coefficients ``k^2.5``. (Every parameter times ``k`` is not a rigid arm: its inertias fall
        below ``m r^2``.)"""
        f = [k, k, k, k, k, k**3, k**3, k**2.5, k**2.5, k**2, k**2]
        return params * torch.tensor(f, dtype=params.dtype), f"similar arm x{k:g} (inertias x{k**3:g})"

    # ------------------------------------------------------------------ samplers
    def sample_params(self, rng: np.random.Generator, n: int) -> np.ndarray:
        m1, m2 = self.m_range.sample(rng, n), self.m_range.sample(rng, n)
        l1 = self.l1_range.sample(rng, n)
        r1 = l1 * self.com_ratio.sample(rng, n)
        r2 = self.l2_range.sample(rng, n) * self.com_ratio.sample(rng, n)
        I1 = m1 * r1**2 * (1 + self.inertia_excess.sample(rng, n))
        I2 = m2 * r2**2 * (1 + self.inertia_excess.sample(rng, n))
        b = self.viscous_range.sample(rng, (n, 2))
        c = self.coulomb_range.sample(rng, (n, 2))
        return np.stack([m1, m2, l1, r1, r2, I1, I2, b[:, 0], b[:, 1], c[:, 0], c[:, 1]], axis=-1)

    def sample_state(self, rng: np.random.Generator, n: int):
        return self.theta_range.sample(rng, (n, 2)), self.omega_range.sample(rng, (n, 2))

    def default_excitation(self) -> dict:
        amplitude = [a for a, on in zip((1.0, 0.5), self.actuated, strict=True) if on]
        return {"kind": "multisine", "amplitude": amplitude, "band": [0.1, 2.0], "num_sines": 6}

    def angle_combinations(self):
        """Link 2's absolute angle ``q1 + q2`` (the potential and the drawing depend on it)."""
        return torch.tensor([[1.0, 1.0]], dtype=torch.float64)

    # ------------------------------------------------------------------ generalised forces
    def input_matrix(self):
        if not any(self.actuated):
            return None
        return torch.eye(2, dtype=torch.float64)[:, [i for i, a in enumerate(self.actuated) if a]]

    @property
    def has_friction(self) -> bool:
        return True

    def friction_coefficients(self, params):
        """Viscous and Coulomb coefficients per joint, ``(*batch, 2)`` each."""
        return params[..., 7:9], params[..., 9:11]

    def friction_torque(self, rates, params):
        return friction_torque(rates, *self.friction_coefficients(params), self.coulomb_velocity)

    # ------------------------------------------------------------------ physics
    @staticmethod
    def _terms(q, params):
        m1, m2, l1, r1, r2, I1, I2 = params[..., :7].unbind(-1)
        c2, s2 = torch.cos(q[..., 1]), torch.sin(q[..., 1])
        k = m2 * l1 * r2
        M11 = I1 + I2 + m2 * l1**2 + 2 * k * c2
        M12 = I2 + k * c2
        return M11, M12, I2, k * s2

    def mass_matrix(self, q, params):
        M11, M12, M22, _ = self._terms(q, params)
        return torch.stack([torch.stack([M11, M12], -1), torch.stack([M12, M22], -1)], -2)

    def kinetic(self, q, qd, params):
        M11, M12, M22, _ = self._terms(q, params)
        w1, w2 = qd[..., 0], qd[..., 1]
        return 0.5 * M11 * w1**2 + M12 * w1 * w2 + 0.5 * M22 * w2**2

    def potential(self, q, params):
        m1, m2, l1, r1, r2 = params[..., :5].unbind(-1)
        c1, c12 = torch.cos(q[..., 0]), torch.cos(q[..., 0] + q[..., 1])
        return -GRAVITY * (m1 * r1 * c1 + m2 * (l1 * c1 + r2 * c12))

    def free_acceleration(self, q, qd, params):
        return self.forced_acceleration(q, qd, params, None)

    def forced_acceleration(self, q, qd, params, force):
        """``M qdd = -c(q, qd) + G(q) + Q`` solved in closed form (one 2x2 inverse)."""
        m1, m2, l1, r1, r2 = params[..., :5].unbind(-1)
        M11, M12, M22, h = self._terms(q, params)
        w1, w2 = qd[..., 0], qd[..., 1]
        s1, s12 = torch.sin(q[..., 0]), torch.sin(q[..., 0] + q[..., 1])
        g2 = -GRAVITY * m2 * r2 * s12
        g1 = -GRAVITY * (m1 * r1 + m2 * l1) * s1 + g2
        rhs1, rhs2 = h * (2 * w1 * w2 + w2**2) + g1, -h * w1**2 + g2
        if force is not None:
            rhs1, rhs2 = rhs1 + force[..., 0], rhs2 + force[..., 1]
        det = M11 * M22 - M12 * M12
        return torch.stack([M22 * rhs1 - M12 * rhs2, M11 * rhs2 - M12 * rhs1], -1) / det[..., None]

    def energy_scale(self, params):
        m1, m2, l1, r1, r2 = params[..., :5].unbind(-1)
        return 2 * GRAVITY * (m1 * r1 + m2 * (l1 + r2))

    # ------------------------------------------------------------------ cases and drawing
    def positions(self, q, params):
        """The elbow and the centre of mass of link 2, ``(*batch, 2, 2)`` in m."""
        l1, r2 = params[..., 2], params[..., 4]
        q12 = q[..., 0] + q[..., 1]
        x1, y1 = l1 * torch.sin(q[..., 0]), -l1 * torch.cos(q[..., 0])
        x2, y2 = x1 + r2 * torch.sin(q12), y1 - r2 * torch.cos(q12)
        return torch.stack([torch.stack([x1, y1], -1), torch.stack([x2, y2], -1)], -2)

    def ood_cases(self):
        """Free decay (inputs off) of arms outside the sampled box: heavier and longer, lighter and shorter."""
        def arm(m1, m2, l1, r1, r2, excess, b, c):
            return (m1, m2, l1, r1, r2, m1 * r1**2 * (1 + excess), m2 * r2**2 * (1 + excess), b, b, c, c)

        return [{"params": arm(1.2, 1.0, 0.35, 0.3, 0.35, 0.2, 0.03, 0.1), "q0": (1.2, -0.6), "qd0": (0.0, 0.0)},
                {"params": arm(0.3, 0.25, 0.15, 0.1, 0.12, 0.2, 0.01, 0.05), "q0": (0.8, 0.8), "qd0": (1.0, -1.0)}]

    def hard_parameter_cases(self):
        def arm(m1, m2, l1, r1, r2, b, c):
            return (m1, m2, l1, r1, r2, m1 * r1**2 * 1.2, m2 * r2**2 * 1.2, b, b, c, c)

        return {"no friction": arm(0.6, 0.6, 0.25, 0.2, 0.2, 0.0, 0.0),
                "friction x5": arm(0.6, 0.6, 0.25, 0.2, 0.2, 0.25, 0.75),
                "m2/m1 = 10": arm(0.1, 1.0, 0.25, 0.2, 0.2, 0.02, 0.05)}
