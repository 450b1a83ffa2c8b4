"""Planar double pendulum with point masses on massless rods.

Conventions (written into every dataset file):

* ``q = (theta1, theta2)``: absolute angles of rod 1 and rod 2 from the downward vertical, in rad,
  counter-clockwise positive. ``qd``, ``qdd`` are their first and second time derivatives.
* ``params = (m1, m2, l1, l2)`` in kg, kg, m, m; gravity g = 9.81 m/s^2 along -y.
* Positions: ``x1 = l1 sin t1, y1 = -l1 cos t1; x2 = x1 + l2 sin t2, y2 = y1 - l2 cos t2``.

Physics:

* ``T = 1/2 (m1+m2) l1^2 t1d^2 + 1/2 m2 l2^2 t2d^2 + m2 l1 l2 t1d t2d cos(t1 - t2)``
* ``V = -(m1+m2) g l1 cos t1 - m2 g l2 cos t2`` (so V_max - V_min = 2 g ((m1+m2) l1 + m2 l2))

Default sampler (the reference design): ``m1 = exp(0.3 N(0,1))``, ``m2 = m1 U(0.2, 1)``,
``l1 ~ U(0.9, 2)``, ``l2 = l1 U(0.9, 1.1)``, ``theta0 ~ U(-pi/2, pi/2)^2``,
``thetad0 ~ U(-pi/5, pi/5)^2``.

Optional joint damping (``joint_damping = (b1, b2)`` in N m s/rad, off by default): viscous friction
at the pivot (rate ``thetad1``) and at the elbow (rate ``thetad2 - thetad1``), ``Q = -D^T (b * D qd)``
with ``D = [[1, 0], [-1, 1]]`` (``lnn_torch.mechanics.forces``). The coefficients are part of the scene's
configuration, not of ``params``.

Wider training distributions (off by default): ``param_margin`` widens the ratios' and ``l1``'s ranges by
that fraction at both ends; ``whole_circle: {fraction, omega}`` draws that fraction of the initial states
over the whole circle with rates up to ``omega`` rad/s. The regimes (``regimes``) stay those of the box
and ranges above.

Model features: besides ``sin``/``cos`` of both angles, models read those of the relative angle
``theta1 - theta2`` (``angle_combinations``), on which the mass matrix alone depends (``relative_angle``,
on by default; checkpoints saved before it existed load with it off, as they were trained).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..errors import InputError
from .base import GRAVITY, System, as_range

CONVENTIONS = (
    "q=(theta1, theta2): absolute angles from the downward vertical, counter-clockwise positive, rad; "
    "params=(m1, m2, l1, l2) in kg, kg, m, m; point masses on massless rods; g=9.81 m/s^2"
)


class DoublePendulum(System):
    name = "double_pendulum"
    dof = 2
    angle_mask = (True, True)
    coord_names = ("theta1", "theta2")
    param_names = ("m1", "m2", "l1", "l2")
    param_units = ("kg", "kg", "m", "m")
    quadratic_kinetic = True
    conventions = CONVENTIONS

    def __init__(
        self,
        m1_log_std: float = 0.3,
        m2_ratio=(0.2, 1.0),
        l1_range=(0.9, 2.0),
        l2_ratio=(0.9, 1.1),
        theta_range=(-math.pi / 2, math.pi / 2),
        omega_range=(-math.pi / 5, math.pi / 5),
        joint_damping=(0.0, 0.0),
        param_margin: float = 0.0,
        whole_circle: dict | None = None,
        relative_angle: bool = True,
    ) -> None:
        if not (math.isfinite(m1_log_std) and m1_log_std >= 0):
            raise InputError(f"double_pendulum: m1_log_std must be >= 0, got {m1_log_std}")
        self.m1_log_std = float(m1_log_std)
        self.m2_ratio = as_range(m2_ratio, "m2_ratio")
        self.l1_range = as_range(l1_range, "l1_range")
        self.l2_ratio = as_range(l2_ratio, "l2_ratio")
        self.theta_range = as_range(theta_range, "theta_range")
        self.omega_range = as_range(omega_range, "omega_range")
        for name in ("m2_ratio", "l1_range", "l2_ratio"):
            if getattr(self, name).low <= 0:
                raise InputError(f"double_pendulum: {name} must be positive, got {getattr(self, name)}")
        if not (math.isfinite(param_margin) and 0 <= param_margin < 1):
            raise InputError(f"double_pendulum: param_margin must be in [0, 1), got {param_margin}")
        self.param_margin = float(param_margin)
        circle = dict(whole_circle or {})
        unknown = sorted(set(circle) - {"fraction", "omega"})
        if unknown:
            raise InputError(f"double_pendulum: whole_circle takes fraction and omega, got {', '.join(unknown)}")
        self.circle_fraction, self.circle_omega = float(circle.get("fraction", 0.0)), float(circle.get("omega", 6.0))
        if not (0 <= self.circle_fraction <= 1 and self.circle_omega > 0):
            raise InputError(f"double_pendulum: whole_circle needs fraction in [0, 1] and omega > 0, got {circle}")
        if not isinstance(relative_angle, bool):
            raise InputError(f"double_pendulum: relative_angle must be true or false, got {relative_angle!r}")
        self.relative_angle = relative_angle
        try:
            self.joint_damping = tuple(float(b) for b in joint_damping)
        except (TypeError, ValueError):
            raise InputError(f"double_pendulum: joint_damping must be two numbers, got {joint_damping!r}") from None
        if len(self.joint_damping) != 2 or not all(math.isfinite(b) and b >= 0 for b in self.joint_damping):
            raise InputError(f"double_pendulum: joint_damping must be two coefficients >= 0, got {joint_damping!r}")

    def config(self) -> dict:
        pair = lambda r: [r.low, r.high]  # noqa: E731
        return {
            "m1_log_std": self.m1_log_std,
            "m2_ratio": pair(self.m2_ratio),
            "l1_range": pair(self.l1_range),
            "l2_ratio": pair(self.l2_ratio),
            "theta_range": pair(self.theta_range),
            "omega_range": pair(self.omega_range),
            **({"joint_damping": list(self.joint_damping)} if self.has_friction else {}),
            **({"param_margin": self.param_margin} if self.param_margin else {}),
            **({"whole_circle": {"fraction": self.circle_fraction, "omega": self.circle_omega}}
               if self.circle_fraction else {}),
            **({} if self.relative_angle else {"relative_angle": False}),
        }

    def sample_params(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """The box, each ratio's and ``l1``'s range widened by ``param_margin`` (relative) at both ends."""
        k = 1.0 + self.param_margin
        widen = lambda r, size: rng.uniform(r.low / k, r.high * k, size)  # noqa: E731
        m1 = np.exp(self.m1_log_std * rng.standard_normal(n))
        m2 = m1 * widen(self.m2_ratio, n)
        l1 = widen(self.l1_range, n)
        l2 = l1 * widen(self.l2_ratio, n)
        return np.stack([m1, m2, l1, l2], axis=-1)

    def sample_state(self, rng: np.random.Generator, n: int):
        """``theta_range`` and ``omega_range``; with ``whole_circle``, a ``fraction`` of the states with both
        angles uniform on the circle and rates uniform in ``+-omega`` instead (whirling, over the top)."""
        q, qd = self.theta_range.sample(rng, (n, 2)), self.omega_range.sample(rng, (n, 2))
        if self.circle_fraction:
            pick = rng.uniform(size=n) < self.circle_fraction
            q = np.where(pick[:, None], rng.uniform(-math.pi, math.pi, (n, 2)), q)
            qd = np.where(pick[:, None], rng.uniform(-self.circle_omega, self.circle_omega, (n, 2)), qd)
        return q, qd

    def angle_combinations(self):
        """The relative angle ``theta1 - theta2`` (the kinetic energy's coupling ``cos(theta1 - theta2)``), a
        feature angle of models unless ``relative_angle`` is off."""
        return torch.tensor([[1.0, -1.0]], dtype=torch.float64) if self.relative_angle else None

    # ------------------------------------------------------------------ joint damping (optional)
    @property
    def has_friction(self) -> bool:
        return any(b > 0 for b in self.joint_damping)

    def joint_map(self):
        return torch.tensor([[1.0, 0.0], [-1.0, 1.0]], dtype=torch.float64)  # pivot and elbow rates

    def friction_coefficients(self, params):
        """Viscous and Coulomb coefficients per joint, ``(*batch, 2)`` each (no Coulomb friction here)."""
        b = torch.tensor(self.joint_damping, dtype=params.dtype, device=params.device).expand(*params.shape[:-1], 2)
        return b, torch.zeros_like(b)

    def friction_torque(self, rates, params):
        return rates * torch.tensor(self.joint_damping, dtype=rates.dtype, device=rates.device)

    # ------------------------------------------------------------------ physics
    def mass_matrix(self, q, params):
        m1, m2, l1, l2 = params.unbind(-1)
        m12 = m2 * l1 * l2 * torch.cos(q[..., 0] - q[..., 1])
        row0 = torch.stack([(m1 + m2) * l1**2, m12], dim=-1)
        row1 = torch.stack([m12, m2 * l2**2], dim=-1)
        return torch.stack([row0, row1], dim=-2)

    def kinetic(self, q, qd, params):
        m1, m2, l1, l2 = params.unbind(-1)
        w1, w2 = qd[..., 0], qd[..., 1]
        c = torch.cos(q[..., 0] - q[..., 1])
        return 0.5 * (m1 + m2) * l1**2 * w1**2 + 0.5 * m2 * l2**2 * w2**2 + m2 * l1 * l2 * w1 * w2 * c

    def potential(self, q, params):
        m1, m2, l1, l2 = params.unbind(-1)
        return -(m1 + m2) * GRAVITY * l1 * torch.cos(q[..., 0]) - m2 * GRAVITY * l2 * torch.cos(q[..., 1])

    def free_acceleration(self, q, qd, params):
        # M qdd = r with M = [[(m1 + m2) l1^2, m2 l1 l2 c], [m2 l1 l2 c, m2 l2^2]] (c = cos d, s = sin d,
        # d = t1 - t2) solved in closed form: det M = m2 l1^2 l2^2 D, D = m1 + m2 s^2 > 0. Four
        # transcendental calls; the rest by angle-sum identities, in few ops (this is the inner loop of
        # every ground-truth rollout)
        m1, m2, l1, l2 = params.unbind(-1)
        w1, w2 = qd[..., 0], qd[..., 1]
        s1, c1 = torch.sin(q[..., 0]), torch.cos(q[..., 0])
        s2, c2 = torch.sin(q[..., 1]), torch.cos(q[..., 1])
        s = s1 * c2 - c1 * s2
        c = c1 * c2 + s1 * s2
        D = torch.addcmul(m1, m2, s * s)
        total = m1 + m2
        minus_r1 = torch.add(m2 * l2 * s * (w2 * w2), total * s1, alpha=GRAVITY)  # -r1 / l1
        r2 = torch.add(l1 * s * (w1 * w1), s2, alpha=-GRAVITY)  # r2 / (m2 l2)
        a1 = torch.addcmul(minus_r1, m2 * c, r2) / (l1 * D)
        a2 = torch.addcmul(total * r2, c, minus_r1) / (l2 * D)
        return torch.stack([a1.neg_(), a2], dim=-1)

    def energy_scale(self, params):
        m1, m2, l1, l2 = params.unbind(-1)
        return 2 * GRAVITY * ((m1 + m2) * l1 + m2 * l2)

    def scale_invariance(self) -> dict:
        """The common scale of its masses (``System.mass_scale``: every mass is a parameter)."""
        return self.mass_scale()

    def identifiable_quantities(self):
        """What free motion determines (``lnn_torch.identification.learned``): a common scale of both masses
        leaves the accelerations unchanged, so only the ratio m2/m1 and the lengths."""
        return {"m2/m1": {"m1": -1.0, "m2": 1.0}, "l1": {"l1": 1.0}, "l2": {"l2": 1.0}}

    def linear_regressor(self, q, qd, qdd, tau=None):
        """The two equations of motion, each divided by its mass factor ((m1 + m2) and m2), are linear
        in ``phi = (l1, l2, mu l2)`` with ``mu = m2 / (m1 + m2)``:

            l1 th1'' + mu l2 (th2'' cos d + th2'^2 sin d) = -g sin th1
            l1 (th1'' cos d - th1'^2 sin d) + l2 th2''    = -g sin th2,     d = th1 - th2,

        so that m2/m1 = mu / (1 - mu). None with joint damping (not in these equations)."""
        if self.has_friction:
            return None
        d = q[:, 0] - q[:, 1]
        c, s = torch.cos(d), torch.sin(d)
        zero = torch.zeros_like(d)
        Y = torch.cat([torch.stack([qdd[:, 0], zero, qdd[:, 1] * c + qd[:, 1] ** 2 * s], -1),
                       torch.stack([qdd[:, 0] * c - qd[:, 0] ** 2 * s, qdd[:, 1], zero], -1)])
        b = torch.cat([-GRAVITY * torch.sin(q[:, 0]), -GRAVITY * torch.sin(q[:, 1])])

        def quantities(phi):
            mu = phi[2] / phi[1]
            return torch.stack([mu / (1 - mu), phi[0], phi[1]])

        return Y, b, quantities

    def ood_cases(self):
        """The reference design's four out-of-distribution cases (parameters outside the training box)."""
        cases = [((2.5, 1.5, 1.2, 1.3), (0.4, -0.4, 0.1, -0.1)), ((1.0, 0.8, 2.5, 2.3), (-0.8, 0.8, 0.3, -0.3)),
                 ((3.0, 2.0, 2.8, 2.5), (-0.6, 0.6, -0.9, 0.9)), ((0.3, 0.2, 0.5, 0.6), (1.5, 1.0, -1.2, 0.35))]
        return [{"params": p, "q0": s[:2], "qd0": s[2:]} for p, s in cases]

    def regimes(self) -> dict:
        """In distribution (the sampled box); out of the parameter range (each of ``m2/m1``, ``l1`` and
        ``l2/l1`` beyond a random end of its range by 5-30 % of that end, ``m1`` and the states as in
        distribution); high energy over the whole circle (both angles uniform on the circle, the velocity's
        direction uniform, its size giving a total energy ``V_min + f (V_max - V_min)``, ``f`` uniform in
        [0.25, 1.5]: from well inside the potential's range to past the upright state, the separatrices
        included; parameters in distribution). Drawn from the box and ranges alone: a scene widened for
        training (``param_margin``, ``whole_circle``) is judged in the same regimes as the default one."""
        box = self if not (self.param_margin or self.circle_fraction) else DoublePendulum(
            **{k: v for k, v in self.config().items() if k not in ("param_margin", "whole_circle")})

        def within(rng, n):
            q, qd = box.sample_state(rng, n)
            return q, qd, box.sample_params(rng, n)

        def outside(rng, n, r):
            side = rng.integers(0, 2, n).astype(bool)
            beyond = rng.uniform(0.05, 0.30, n)
            return np.where(side, r.high * (1 + beyond), r.low * (1 - beyond))

        def out_of_range(rng, n):
            q, qd = box.sample_state(rng, n)
            m1 = np.exp(self.m1_log_std * rng.standard_normal(n))
            m2, l1 = m1 * outside(rng, n, self.m2_ratio), outside(rng, n, self.l1_range)
            return q, qd, np.stack([m1, m2, l1, l1 * outside(rng, n, self.l2_ratio)], -1)

        def high_energy(rng, n):
            params = torch.as_tensor(box.sample_params(rng, n))
            q = torch.as_tensor(rng.uniform(-math.pi, math.pi, (n, 2)))
            span = self.energy_scale(params)  # V_max - V_min, V_min = -span / 2
            target = span * (torch.as_tensor(rng.uniform(0.25, 1.5, n)) - 0.5)
            kinetic = (target - self.potential(q, params)).clamp_min(0.0)
            direction = torch.as_tensor(rng.standard_normal((n, 2)))
            unit = self.kinetic(q, direction, params)
            qd = direction * torch.sqrt(kinetic / unit)[:, None]
            return q.numpy(), qd.numpy(), params.numpy()

        return {"in distribution": within, "out of the parameter range": out_of_range,
                "high energy, whole circle": high_energy}

    def hard_parameter_cases(self):
        return {"m2/m1 = 1e-3": (1.0, 1e-3, 1.2, 1.2), "m2/m1 = 1e3": (0.1, 100.0, 1.2, 1.2),
                "l2/l1 = 0.1": (1.0, 0.6, 1.5, 0.15), "l2/l1 = 10": (1.0, 0.6, 0.3, 3.0)}

    def positions(self, q, params):
        """Cartesian positions of both masses, shape ``(*batch, 2, 2)`` as ``[[x1, y1], [x2, y2]]`` in m."""
        _, _, l1, l2 = params.unbind(-1)
        x1, y1 = l1 * torch.sin(q[..., 0]), -l1 * torch.cos(q[..., 0])
        x2, y2 = x1 + l2 * torch.sin(q[..., 1]), y1 - l2 * torch.cos(q[..., 1])
        return torch.stack([torch.stack([x1, y1], -1), torch.stack([x2, y2], -1)], -2)
