"""A relativistic particle in a uniform potential (the LNN paper's second task), in units c = 1.

Conventions (written into every dataset file):

* ``q = (x,)``: position; ``qd`` its velocity as a fraction of the speed of light (|qd| < 1).
* ``params = (g,)``: strength of the uniform potential (force per unit rest mass, c = 1 units).
* Natural units: c = 1 and rest mass 1, so lengths, times and energies are in those units (not SI).

The Lagrangian is the one the LNN paper states (Cranmer et al., section 5):

* ``L = (1 - qd^2)^(-1/2) - 1 + g x``
* canonical momentum ``p = dL/dqd = qd (1 - qd^2)^(-3/2)``
* ``d2L/dqd2 = (1 + 2 qd^2) (1 - qd^2)^(-5/2)``, hence ``qdd = g (1 - qd^2)^(5/2) / (1 + 2 qd^2)``
* conserved energy ``E = p qd - L = qd^2 (1 - qd^2)^(-3/2) - (1 - qd^2)^(-1/2) + 1 - g x``

The kinetic term is not quadratic in ``qd``: no mass matrix, and structured models (``film_lnn``,
``delan``) refuse this scene. ``(q, qd)`` are not canonical coordinates (``p != qd``), which is why
a Hamiltonian network fed ``(x, qd)`` cannot represent these dynamics. Energy drifts are reported
relative to the rest energy ``m c^2 = 1``.

Default sampler: ``g ~ U(0.05, 0.25)``, ``x0 ~ U(-1, 1)``, ``qd0 ~ U(-0.6, 0.6)``; over the default
10 s the speed stays below about 0.96 c.
"""

from __future__ import annotations

import torch

from ..errors import InputError
from .base import System, as_range


class RelativisticParticle(System):
    name = "relativistic_particle"
    dof = 1
    angle_mask = (False,)
    coord_names = ("x",)
    param_names = ("g",)
    param_units = ("c=1 units",)
    quadratic_kinetic = False
    conventions = (
        "q=(x,): position; qd: velocity in units of c (|qd| < 1); params=(g,): uniform potential "
        "strength; natural units c=1, rest mass 1; L = (1 - qd^2)^(-1/2) - 1 + g x"
    )
    gravity = 0.0
    speed_limit = 1.0

    def __init__(self, g_range=(0.05, 0.25), x_range=(-1.0, 1.0), v_range=(-0.6, 0.6)) -> None:
        self.g_range = as_range(g_range, "g_range")
        self.x_range = as_range(x_range, "x_range")
        self.v_range = as_range(v_range, "v_range")
        if self.g_range.low <= 0:
            raise InputError(f"relativistic_particle: g_range must be positive, got {self.g_range}")
        if max(abs(self.v_range.low), abs(self.v_range.high)) >= 1:
            raise InputError(f"relativistic_particle: v_range must lie inside (-1, 1) (c = 1), got {self.v_range}")

    @property
    def coord_units(self) -> tuple[str, ...]:
        return ("c=1 units",)

    def config(self) -> dict:
        return {k: [getattr(self, k).low, getattr(self, k).high] for k in ("g_range", "x_range", "v_range")}

    def sample_params(self, rng, n):
        return self.g_range.sample(rng, (n, 1))

    def sample_state(self, rng, n):
        return self.x_range.sample(rng, (n, 1)), self.v_range.sample(rng, (n, 1))

    # ------------------------------------------------------------------ physics
    def kinetic(self, q, qd, params):
        """The velocity part of L, ``(1 - qd^2)^(-1/2) - 1``, shape ``(*batch,)``."""
        return torch.rsqrt(1 - qd[..., 0] ** 2) - 1

    def potential(self, q, params):
        return -params[..., 0] * q[..., 0]

    def momentum(self, q, qd, params):
        v = qd[..., 0]
        return (v * (1 - v * v) ** -1.5)[..., None]

    def energy(self, q, qd, params):
        v = qd[..., 0]
        w = 1 - v * v
        return v * v * w**-1.5 - torch.rsqrt(w) + 1 - params[..., 0] * q[..., 0]

    def free_acceleration(self, q, qd, params):
        v = qd[..., 0]
        w = 1 - v * v
        return (params[..., 0] * w**2.5 / (1 + 2 * v * v))[..., None]

    def energy_scale(self, params):
        """The rest energy m c^2 = 1, shape ``(*batch,)``."""
        return torch.ones_like(params[..., 0])

    def check_state(self, q, qd=None) -> None:
        super().check_state(q, qd)
        if qd is not None and (qd.abs() >= 1).any():
            raise InputError(f"{self.name}: invalid state: |qd| >= 1 (the speed of light is c = 1); "
                             f"max |qd| = {qd.abs().max().item():.6g}")
