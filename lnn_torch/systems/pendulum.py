"""Simple planar pendulum: a point mass on a massless rod.

Conventions: ``q = (theta,)`` angle from the downward vertical, counter-clockwise positive, rad;
``params = (m, l)`` in kg, m; g = 9.81 m/s^2.

``T = 1/2 m l^2 thetad^2``, ``V = -m g l cos theta``, ``thetadd = -(g / l) sin theta``.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..errors import InputError
from .base import GRAVITY, System, as_range


class Pendulum(System):
    name = "pendulum"
    dof = 1
    angle_mask = (True,)
    coord_names = ("theta",)
    param_names = ("m", "l")
    param_units = ("kg", "m")
    quadratic_kinetic = True
    conventions = (
        "q=(theta,): angle from the downward vertical, counter-clockwise positive, rad; "
        "params=(m, l) in kg, m; point mass on a massless rod; g=9.81 m/s^2"
    )

    def scale_invariance(self) -> dict:
        """The common scale of its masses (``System.mass_scale``: every mass is a parameter)."""
        return self.mass_scale()

    def __init__(self, m_range=(0.5, 2.0), l_range=(0.5, 2.0), theta_range=(-math.pi / 2, math.pi / 2),
                 omega_range=(-1.0, 1.0)) -> None:
        self.m_range = as_range(m_range, "m_range")
        self.l_range = as_range(l_range, "l_range")
        self.theta_range = as_range(theta_range, "theta_range")
        self.omega_range = as_range(omega_range, "omega_range")
        for name in ("m_range", "l_range"):
            if getattr(self, name).low <= 0:
                raise InputError(f"pendulum: {name} must be positive, got {getattr(self, name)}")

    def config(self) -> dict:
        return {k: [getattr(self, k).low, getattr(self, k).high]
                for k in ("m_range", "l_range", "theta_range", "omega_range")}

    def sample_params(self, rng, n):
        return np.stack([self.m_range.sample(rng, n), self.l_range.sample(rng, n)], axis=-1)

    def sample_state(self, rng, n):
        return self.theta_range.sample(rng, (n, 1)), self.omega_range.sample(rng, (n, 1))

    def mass_matrix(self, q, params):
        m, l = params.unbind(-1)
        return (m * l**2)[..., None, None] + 0.0 * q[..., None, :]

    def potential(self, q, params):
        m, l = params.unbind(-1)
        return -m * GRAVITY * l * torch.cos(q[..., 0])

    def free_acceleration(self, q, qd, params):
        _, l = params.unbind(-1)
        return (-(GRAVITY / l) * torch.sin(q[..., 0]))[..., None] + 0.0 * qd

    def energy_scale(self, params):
        m, l = params.unbind(-1)
        return 2 * m * GRAVITY * l

    def positions(self, q, params):
        """Cartesian position of the mass, ``(*batch, 1, 2)`` in m."""
        _, l = params.unbind(-1)
        return torch.stack([l * torch.sin(q[..., 0]), -l * torch.cos(q[..., 0])], -1)[..., None, :]
