"""A classical identified rigid-body model of a two-link arm: the physicist's baseline for measured
recordings, behind the model interface (``acceleration``, ``rollout``), so that
``lnn_torch.evaluation.evaluate_model`` evaluates it exactly as it evaluates a learned model.

The equations are those of the rigid-body model that the lab identified for its double pendulum
(``shared/data/real_double_pendulum/README.md``): joint angles (``q2`` relative to link 1), links of
mass ``m``, length ``l``, centre of mass ``r`` and inertia ``I`` about their own joints, a motor rotor
of inertia ``Ir`` behind a gear ratio ``gr`` at each joint, and per-joint viscous ``b`` and Coulomb
``cf`` friction smoothed as ``cf arctan(k qd)`` (``k = 100`` s/rad; ``coulomb_shape="tanh"``: ``cf
tanh(k qd)``, the smoothing of the learned models' joint friction, for comparisons):

    M11 = I1 + I2 + m2 l1^2 + 2 m2 l1 r2 cos q2 + gr^2 Ir + Ir,  M12 = I2 + m2 l1 r2 cos q2 - gr Ir,
    M22 = I2 + gr^2 Ir,  M qdd = G(q) + tau - c(q, qd) - b qd - cf arctan(k qd).

The torques are linear in ten base parameters (``BASE``): ``A = M11 - 2 K cos q2``, ``B = M12 - K cos
q2``, ``C = M22``, ``K = m2 l1 r2``, the gravity moments ``P1 = m1 r1 + m2 l1`` and ``P2 = m2 r2``, and the
friction ``b1, b2, cf1, cf2``: the model computes with them, ``base_regressor`` is the matrix ``Y(q, qd,
qdd)`` with ``tau = Y beta``, and ``RigidArmModel.least_squares`` is the classical identification of them
from recorded states, accelerations and torques (least squares of the torque error, linear; or of the
acceleration error it causes, nonlinear in the mass matrix's parameters: ``acceleration_error_fit``).
"""

from __future__ import annotations

from pathlib import Path

import torch

from ..mechanics.friction import COULOMB_SHAPES, coulomb_sign, friction_torque
from ..mechanics.integrators import rollout

KEYS = ("m1", "m2", "l1", "r1", "r2", "I1", "I2", "Ir", "gr", "b1", "b2", "cf1", "cf2", "g")
BASE = ("A", "B", "C", "K", "P1", "P2", "b1", "b2", "cf1", "cf2")
def base_regressor(q, qd, qdd, g: float = 9.81, coulomb_slope: float = 100.0,
                   coulomb_shape: str = "arctan") -> torch.Tensor:
    """``Y (..., 2, 10)`` with the joint torques ``tau = Y beta`` for the base parameters ``beta`` in the
    order of ``BASE`` (module docstring), at joint angles ``q``, velocities ``qd`` and accelerations
    ``qdd`` (``(..., 2)``; ``q2`` relative to link 1, angles from the downward vertical)."""
    c2, s2 = torch.cos(q[..., 1]), torch.sin(q[..., 1])
    s1, s12 = torch.sin(q[..., 0]), torch.sin(q[..., 0] + q[..., 1])
    w1, w2 = qd[..., 0], qd[..., 1]
    a1, a2 = qdd[..., 0], qdd[..., 1]
    zero = torch.zeros_like(a1)
    v_c = 1.0 / coulomb_slope
    row1 = [a1, a2, zero, 2 * c2 * a1 + c2 * a2 - s2 * (2 * w1 * w2 + w2**2), g * s1, g * s12,
            w1, zero, coulomb_sign(w1, v_c, coulomb_shape), zero]
    row2 = [zero, a1, a2, c2 * a1 + s2 * w1**2, zero, g * s12, zero, w2, zero, coulomb_sign(w2, v_c, coulomb_shape)]
    return torch.stack([torch.stack(row1, -1), torch.stack(row2, -1)], -2)


def _positive_definite(beta: torch.Tensor) -> bool:
    """Whether the mass matrix of base parameters ``beta`` is positive definite at every angle: ``C > 0``
    and its determinant, concave in ``cos q2``, positive at ``cos q2 = -1`` and ``1``."""
    A, B, C, K = (float(x) for x in beta[:4])
    return C > 0 and all((A + 2 * K * c) * C - (B + K * c) ** 2 > 0 for c in (-1.0, 1.0))


def acceleration_errors(beta: torch.Tensor, Y: torch.Tensor, tau: torch.Tensor, cos_q2: torch.Tensor) -> torch.Tensor:
    """``M(beta)^-1 (Y beta - tau)`` ``(n, 2)``: the model's acceleration minus the given one at each point
    (``Y (n, 2, 10)`` the base regressor of the points, ``cos_q2 (n,)``)."""
    A, B, C, K = beta[0], beta[1], beta[2], beta[3]
    M11, M12 = A + 2 * K * cos_q2, B + K * cos_q2
    e = Y @ beta - tau
    det = M11 * C - M12 * M12
    return torch.stack([C * e[:, 0] - M12 * e[:, 1], M11 * e[:, 1] - M12 * e[:, 0]], -1) / det[:, None]


def acceleration_error_fit(Y: torch.Tensor, tau: torch.Tensor, cos_q2: torch.Tensor, beta: torch.Tensor,
                           iterations: int = 200) -> torch.Tensor:
    """The base parameters minimising the summed squared acceleration error (``acceleration_errors``),
    nonlinear in the mass matrix's four: Levenberg-Marquardt from ``beta`` (e.g. the torque fit), steps
    kept only where they lower the error and the mass matrix stays positive definite at every angle; it
    stops when a step changes the error by less than 1e-12 relative."""
    from torch.func import jacfwd

    def residual(b):
        return acceleration_errors(b, Y, tau, cos_q2).reshape(-1)

    r = residual(beta)
    cost, damping = float(r @ r), 1e-3
    for _ in range(iterations):
        J = jacfwd(residual)(beta)
        JTJ, grad = J.T @ J, J.T @ r
        while damping < 1e12:
            step = torch.linalg.solve(JTJ + damping * torch.diag(torch.diag(JTJ)), -grad)
            trial = beta + step
            if _positive_definite(trial):
                r_trial = residual(trial)
                if float(r_trial @ r_trial) <= cost:
                    break
            damping *= 4
        else:
            return beta  # no step lowers the error: a minimum
        improvement = cost - float(r_trial @ r_trial)
        beta, r, cost, damping = trial, r_trial, float(r_trial @ r_trial), max(damping / 3, 1e-9)
        if improvement <= 1e-12 * cost:
            break
    return beta


class RigidArmModel:
    """The identified model; ``params`` arguments are ignored (a measured system has none)."""

    variant = "identified rigid-body model"

    def __init__(self, m1, m2, l1, r1, r2, I1, I2, Ir=0.0, gr=1.0, b1=0.0, b2=0.0, cf1=0.0, cf2=0.0, g=9.81,
                 coulomb_slope: float = 100.0, l2: float | None = None, coulomb_shape: str = "arctan") -> None:
        self.values = dict(m1=m1, m2=m2, l1=l1, r1=r1, r2=r2, I1=I1, I2=I2, Ir=Ir, gr=gr, b1=b1, b2=b2, cf1=cf1,
                           cf2=cf2, g=g)
        self.coulomb_slope = float(coulomb_slope)
        if coulomb_shape not in COULOMB_SHAPES:
            raise ValueError(f"coulomb_shape must be one of {', '.join(COULOMB_SHAPES)}, got {coulomb_shape!r}")
        self.coulomb_shape = coulomb_shape
        self.l2 = None if l2 is None else float(l2)  # for drawing only (link 2's length is not in its dynamics)
        rotor = gr**2 * Ir
        self.base = dict(A=I1 + I2 + m2 * l1**2 + rotor + Ir, B=I2 - gr * Ir, C=I2 + rotor, K=m2 * l1 * r2,
                         P1=m1 * r1 + m2 * l1, P2=m2 * r2, b1=b1, b2=b2, cf1=cf1, cf2=cf2)

    @classmethod
    def from_base(cls, base, g: float = 9.81, coulomb_slope: float = 100.0,
                  variant: str | None = None, coulomb_shape: str = "arctan") -> RigidArmModel:
        """The model of given base parameters (a dict of ``BASE``, or its ten values in that order). Its
        physical ``values`` are one of the many sets with these base parameters (``gr = r1 = r2 = 1``),
        not an identification of each."""
        if not isinstance(base, dict):
            base = dict(zip(BASE, (float(v) for v in base), strict=True))
        b = {k: float(base[k]) for k in BASE}
        if b["P2"] == 0:
            raise ValueError("base parameters with P2 = m2 r2 = 0 (no gravity moment on link 2) have no model here")
        I2, Ir = (b["B"] + b["C"]) / 2, (b["C"] - b["B"]) / 2
        model = cls(m1=b["P1"] - b["K"], m2=b["P2"], l1=b["K"] / b["P2"], r1=1.0, r2=1.0,
                    I1=b["A"] - I2 - b["K"] ** 2 / b["P2"] - 2 * Ir, I2=I2, Ir=Ir, gr=1.0, b1=b["b1"], b2=b["b2"],
                    cf1=b["cf1"], cf2=b["cf2"], g=g, coulomb_slope=coulomb_slope, coulomb_shape=coulomb_shape)
        model.base = b  # exactly the given ones (not recomputed through the values above)
        if variant is not None:
            model.variant = variant
        return model

    @classmethod
    def least_squares(cls, q, qd, qdd, tau, g: float = 9.81, coulomb_slope: float = 100.0,
                      space: str = "torque", coulomb_shape: str = "arctan") -> RigidArmModel:
        """The classical identification of the ten base parameters from points ``(n, 2)`` each (float64
        advised). ``space="torque"``: ordinary least squares of the torque error, both joints' rows stacked
        (the textbook fit). ``space="acceleration"``: least squares of the acceleration error the torques
        cause, ``|M(beta)^-1 (Y beta - tau)|^2`` (``acceleration_error_fit``), the criterion a learned model
        of the accelerations is fitted by. ``ValueError`` in one line if the points hold non-finite values,
        do not determine the parameters, or the fit's mass matrix is not positive definite at every angle."""
        if space not in ("torque", "acceleration"):
            raise ValueError(f"least squares: space must be 'torque' or 'acceleration', got {space!r}")
        Y = base_regressor(q, qd, qdd, g, coulomb_slope, coulomb_shape).double()  # (n, 2, 10)
        tau = tau.double()
        if not (torch.isfinite(Y).all() and torch.isfinite(tau).all()):
            raise ValueError("least squares: the states, accelerations or torques hold NaN or infinite values")
        rank = int(torch.linalg.matrix_rank(Y.reshape(-1, len(BASE))))
        if rank < len(BASE):
            raise ValueError(f"least squares: the recordings determine {rank} of the {len(BASE)} base parameters "
                             "(too little motion)")
        beta = torch.linalg.lstsq(Y.reshape(-1, len(BASE)), tau.reshape(-1, 1)).solution[:, 0]
        if not _positive_definite(beta):
            raise ValueError("least squares: the torque fit's mass matrix is not positive definite at every angle "
                             "(too little motion, or a model of another form)")
        if space == "acceleration":
            beta = acceleration_error_fit(Y, tau, torch.cos(q[..., 1].double()), beta)
        variant = ("least squares (rigid body + friction)" if space == "torque"
                   else "least squares of the accelerations (rigid body + friction)")
        return cls.from_base(beta.tolist(), g, coulomb_slope, variant=variant, coulomb_shape=coulomb_shape)

    @classmethod
    def fit_recordings(cls, data, space: str = "torque", **options) -> RigidArmModel:
        """``least_squares`` on every valid point of recordings (``Trajectories``; their torques as given,
        filtered or not): the lab model's rigid-body and friction form, its ten base parameters by least
        squares of the torque error (``space="torque"``) or of the acceleration error
        (``"acceleration"``)."""
        from ..data.trajectories import points

        q, qd, qdd, tau, _ = points(data)
        return cls.least_squares(q, qd, qdd, tau, space=space, **options)

    @classmethod
    def from_yaml(cls, path: str | Path) -> RigidArmModel:
        """From an identified-parameters YAML file (the keys of ``KEYS``; others are ignored)."""
        import yaml

        values = yaml.safe_load(Path(path).read_text())
        missing = [k for k in KEYS if k not in values]
        if missing:
            raise ValueError(f"{path}: missing parameter(s) {', '.join(missing)}")
        return cls(**{k: float(values[k]) for k in KEYS}, l2=values.get("l2"))

    def _mass(self, q):
        b = self.base
        c2 = torch.cos(q[..., 1])
        return b["A"] + 2 * b["K"] * c2, b["B"] + b["K"] * c2, b["C"] + 0 * c2

    def mass_matrix(self, q, params=None):
        M11, M12, M22 = self._mass(q)
        return torch.stack([torch.stack([M11, M12], -1), torch.stack([M12, M22], -1)], -2)

    def acceleration(self, q, qd, params=None, tau=None, check: bool = False):
        b, g = self.base, self.values["g"]
        M11, M12, M22 = self._mass(q)
        h = b["K"] * torch.sin(q[..., 1])
        w1, w2 = qd[..., 0], qd[..., 1]
        s1, s12 = torch.sin(q[..., 0]), torch.sin(q[..., 0] + q[..., 1])
        g2 = -g * b["P2"] * s12
        g1 = -g * b["P1"] * s1 + g2
        friction = -self.friction(q, qd)
        rhs1 = h * (2 * w1 * w2 + w2**2) + g1 - friction[..., 0]
        rhs2 = -h * w1**2 + g2 - friction[..., 1]
        if tau is not None:
            rhs1, rhs2 = rhs1 + tau[..., 0], rhs2 + tau[..., 1]
        det = M11 * M22 - M12 * M12
        return torch.stack([M22 * rhs1 - M12 * rhs2, M11 * rhs2 - M12 * rhs1], -1) / det[..., None]

    def inverse(self, q, qd, qdd, params=None):
        """Inverse dynamics: the joint torques ``(..., 2)`` that give accelerations ``qdd`` at ``(q, qd)``,
        ``M qdd + n - Q_f`` (through ``base_regressor``)."""
        beta = torch.tensor([self.base[k] for k in BASE], dtype=q.dtype, device=q.device)
        return base_regressor(q, qd, qdd, self.values["g"], self.coulomb_slope, self.coulomb_shape) @ beta

    def bias(self, q, qd, params=None):
        """``n (..., 2)``: Coriolis, centrifugal and gravity torques, no friction (N m)."""
        return self.inverse(q, qd, torch.zeros_like(qd)) + self.friction(q, qd)

    def gravity(self, q, params=None):
        """``g = n(q, 0) (..., 2)``: the torques that hold the arm still at ``q`` (N m)."""
        rest = torch.zeros_like(q)
        return self.inverse(q, rest, rest)

    def positions(self, q, params=None):
        """The elbow and the tip ``(..., 2, 2)`` (x right, y up; m) for drawing; None without ``l2``."""
        if self.l2 is None:
            return None
        a1, a12 = q[..., 0], q[..., 0] + q[..., 1]
        elbow = torch.stack([self.values["l1"] * torch.sin(a1), -self.values["l1"] * torch.cos(a1)], -1)
        tip = elbow + torch.stack([self.l2 * torch.sin(a12), -self.l2 * torch.cos(a12)], -1)
        return torch.stack([elbow, tip], -2)

    def friction(self, q, qd, params=None):
        """The joint friction as generalised forces: ``-(b qd + cf arctan(k qd))`` per joint (``tanh`` for
        ``coulomb_shape="tanh"``)."""
        b = self.base
        return -torch.stack([friction_torque(qd[..., j - 1], b[f"b{j}"], b[f"cf{j}"], 1.0 / self.coulomb_slope,
                                             self.coulomb_shape) for j in (1, 2)], -1)

    def energy(self, q, qd, params=None):
        """``T + V`` in J, the rotors' kinetic energy included (``V = 0`` with both links hanging down)."""
        b = self.base
        M = self.mass_matrix(q)
        T = 0.5 * torch.einsum("...i,...ij,...j->...", qd, M, qd)
        c1, c12 = torch.cos(q[..., 0]), torch.cos(q[..., 0] + q[..., 1])
        V = self.values["g"] * (b["P1"] * (1 - c1) + b["P2"] * (1 - c12))
        return T + V

    def rollout(self, q0, qd0, params, dt: float, num_steps: int, method: str = "rk4", tau=None):
        return rollout(lambda q, qd, p, *u: self.acceleration(q, qd, p, *u), q0, qd0, params, dt, num_steps, method,
                       tau=tau)
