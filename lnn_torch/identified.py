"""A classical identified rigid-body model of a two-link arm: the physicist's baseline for measured
recordings, behind the model interface (``acceleration``, ``rollout``), so that
``lnn_torch.evaluation.evaluate_model`` evaluates it exactly as it evaluates a learned model.

The equations are those of the rigid-body model that the lab identified for its double pendulum
(``shared/data/real_double_pendulum/README.md``): joint angles (``q2`` relative to link 1), links of
mass ``m``, length ``l``, centre of mass ``r`` and inertia ``I`` about their own joints, a motor rotor
of inertia ``Ir`` behind a gear ratio ``gr`` at each joint, and per-joint viscous ``b`` and Coulomb
``cf`` friction smoothed as ``cf arctan(k qd)`` (``k = 100`` s/rad):

    M11 = I1 + I2 + m2 l1^2 + 2 m2 l1 r2 cos q2 + gr^2 Ir + Ir,  M12 = I2 + m2 l1 r2 cos q2 - gr Ir,
    M22 = I2 + gr^2 Ir,  M qdd = G(q) + tau - c(q, qd) - b qd - cf arctan(k qd).
"""

from __future__ import annotations

from pathlib import Path

import torch

from .integrators import rollout

KEYS = ("m1", "m2", "l1", "r1", "r2", "I1", "I2", "Ir", "gr", "b1", "b2", "cf1", "cf2", "g")


class RigidArmModel:
    """The identified model; ``params`` arguments are ignored (a measured system has none)."""

    variant = "identified rigid-body model"

    def __init__(self, m1, m2, l1, r1, r2, I1, I2, Ir=0.0, gr=1.0, b1=0.0, b2=0.0, cf1=0.0, cf2=0.0, g=9.81,
                 coulomb_slope: float = 100.0, l2: float | None = None) -> None:
        self.values = dict(m1=m1, m2=m2, l1=l1, r1=r1, r2=r2, I1=I1, I2=I2, Ir=Ir, gr=gr, b1=b1, b2=b2, cf1=cf1,
                           cf2=cf2, g=g)
        self.coulomb_slope = float(coulomb_slope)
        self.l2 = None if l2 is None else float(l2)  # for drawing only (link 2's length is not in its dynamics)

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
        v = self.values
        c2 = torch.cos(q[..., 1])
        k = v["m2"] * v["l1"] * v["r2"]
        rotor = v["gr"] ** 2 * v["Ir"]
        M11 = v["I1"] + v["I2"] + v["m2"] * v["l1"] ** 2 + 2 * k * c2 + rotor + v["Ir"]
        M12 = v["I2"] + k * c2 - v["gr"] * v["Ir"]
        M22 = v["I2"] + rotor + 0 * c2
        return M11, M12, M22

    def mass_matrix(self, q, params=None):
        M11, M12, M22 = self._mass(q)
        return torch.stack([torch.stack([M11, M12], -1), torch.stack([M12, M22], -1)], -2)

    def acceleration(self, q, qd, params=None, tau=None, check: bool = False):
        v = self.values
        M11, M12, M22 = self._mass(q)
        h = v["m2"] * v["l1"] * v["r2"] * torch.sin(q[..., 1])
        w1, w2 = qd[..., 0], qd[..., 1]
        s1, s12 = torch.sin(q[..., 0]), torch.sin(q[..., 0] + q[..., 1])
        g2 = -v["g"] * v["m2"] * v["r2"] * s12
        g1 = -v["g"] * (v["m1"] * v["r1"] + v["m2"] * v["l1"]) * s1 + g2
        friction = [v[f"b{j}"] * qd[..., j - 1] + v[f"cf{j}"] * torch.atan(self.coulomb_slope * qd[..., j - 1])
                    for j in (1, 2)]
        rhs1 = h * (2 * w1 * w2 + w2**2) + g1 - friction[0]
        rhs2 = -h * w1**2 + g2 - friction[1]
        if tau is not None:
            rhs1, rhs2 = rhs1 + tau[..., 0], rhs2 + tau[..., 1]
        det = M11 * M22 - M12 * M12
        return torch.stack([M22 * rhs1 - M12 * rhs2, M11 * rhs2 - M12 * rhs1], -1) / det[..., None]

    def positions(self, q, params=None):
        """The elbow and the tip ``(..., 2, 2)`` (x right, y up; m) for drawing; None without ``l2``."""
        if self.l2 is None:
            return None
        a1, a12 = q[..., 0], q[..., 0] + q[..., 1]
        elbow = torch.stack([self.values["l1"] * torch.sin(a1), -self.values["l1"] * torch.cos(a1)], -1)
        tip = elbow + torch.stack([self.l2 * torch.sin(a12), -self.l2 * torch.cos(a12)], -1)
        return torch.stack([elbow, tip], -2)

    def friction_force(self, q, qd, params=None):
        """The joint friction as generalised forces: ``-(b qd + cf arctan(k qd))`` per joint."""
        v = self.values
        return -torch.stack([v[f"b{j}"] * qd[..., j - 1] + v[f"cf{j}"] * torch.atan(self.coulomb_slope * qd[..., j - 1])
                             for j in (1, 2)], -1)

    def energy(self, q, qd, params=None):
        """``T + V`` in J, the rotors' kinetic energy included (``V = 0`` with both links hanging down)."""
        v = self.values
        M = self.mass_matrix(q)
        T = 0.5 * torch.einsum("...i,...ij,...j->...", qd, M, qd)
        c1, c12 = torch.cos(q[..., 0]), torch.cos(q[..., 0] + q[..., 1])
        V = v["g"] * ((v["m1"] * v["r1"] + v["m2"] * v["l1"]) * (1 - c1) + v["m2"] * v["r2"] * (1 - c12))
        return T + V

    def rollout(self, q0, qd0, params, dt: float, num_steps: int, method: str = "rk4", tau=None):
        return rollout(lambda q, qd, p, *u: self.acceleration(q, qd, p, *u), q0, qd0, params, dt, num_steps, method,
                       tau=tau)
