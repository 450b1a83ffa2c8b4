"""Mass on a linear spring (1-D harmonic oscillator).

Conventions: ``q = (x,)`` displacement from the spring's rest length, m; ``params = (m, k)`` in kg,
N/m. ``T = 1/2 m xd^2``, ``V = 1/2 k x^2``, ``xdd = -(k/m) x``.

V is unbounded, so drifts are divided by the largest potential the state distribution reaches:
``1/2 k x_max^2`` with ``x_max`` the larger end of the initial-position range plus the velocity
range times sqrt(m/k) (the amplitude bound of the sampled states).
"""

from __future__ import annotations

import numpy as np
import torch

from ..errors import InputError
from .base import System, as_range


class MassSpring(System):
    name = "mass_spring"
    dof = 1
    angle_mask = (False,)
    coord_names = ("x",)
    param_names = ("m", "k")
    param_units = ("kg", "N/m")
    quadratic_kinetic = True
    conventions = "q=(x,): displacement from rest, m; params=(m, k) in kg, N/m; no gravity"
    gravity = 0.0

    def scale_invariance(self) -> dict:
        """The common scale of its masses (``System.mass_scale``: every mass is a parameter)."""
        return self.mass_scale()

    def __init__(self, m_range=(0.5, 2.0), k_range=(0.5, 4.0), x_range=(-1.0, 1.0), v_range=(-1.0, 1.0)) -> None:
        self.m_range = as_range(m_range, "m_range")
        self.k_range = as_range(k_range, "k_range")
        self.x_range = as_range(x_range, "x_range")
        self.v_range = as_range(v_range, "v_range")
        for name in ("m_range", "k_range"):
            if getattr(self, name).low <= 0:
                raise InputError(f"mass_spring: {name} must be positive, got {getattr(self, name)}")

    def config(self) -> dict:
        return {k: [getattr(self, k).low, getattr(self, k).high] for k in ("m_range", "k_range", "x_range", "v_range")}

    def sample_params(self, rng, n):
        return np.stack([self.m_range.sample(rng, n), self.k_range.sample(rng, n)], axis=-1)

    def sample_state(self, rng, n):
        return self.x_range.sample(rng, (n, 1)), self.v_range.sample(rng, (n, 1))

    def mass_matrix(self, q, params):
        m, _ = params.unbind(-1)
        return m[..., None, None] + 0.0 * q[..., None, :]

    def potential(self, q, params):
        _, k = params.unbind(-1)
        return 0.5 * k * q[..., 0] ** 2

    def free_acceleration(self, q, qd, params):
        m, k = params.unbind(-1)
        return -(k / m)[..., None] * q + 0.0 * qd

    def energy_scale(self, params):
        m, k = params.unbind(-1)
        x_max = max(abs(self.x_range.low), abs(self.x_range.high))
        v_max = max(abs(self.v_range.low), abs(self.v_range.high))
        amplitude = x_max + v_max * torch.sqrt(m / k)
        return 0.5 * k * amplitude**2
