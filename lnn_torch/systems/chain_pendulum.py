"""Planar chain of N pendula: point masses on massless rods, each hanging from the previous mass.

Conventions (written into every dataset file):

* ``q = (theta_1, ..., theta_N)``: absolute angles of the rods from the downward vertical, rad,
  counter-clockwise positive (as for ``double_pendulum``).
* ``params = (m_1, ..., m_N, l_1, ..., l_N)`` in kg and m; gravity g = 9.81 m/s^2 along -y.
* Positions: ``x_i = sum_{k<=i} l_k sin theta_k``, ``y_i = -sum_{k<=i} l_k cos theta_k``.

Physics, with ``mu_ij = sum_{k >= max(i, j)} m_k`` (the mass hanging below both joints):

* ``M_ij = mu_ij l_i l_j cos(theta_i - theta_j)``, ``T = 1/2 qd^T M qd``
* ``V = -g sum_i mu_ii l_i cos theta_i`` (so V_max - V_min = 2 g sum_i mu_ii l_i)
* Euler-Lagrange: ``sum_j M_ij qdd_j = -sum_j mu_ij l_i l_j sin(theta_i - theta_j) qd_j^2
  - g mu_ii l_i sin theta_i``, solved for ``qdd`` (an N x N linear solve per state).

N = 2 is the double pendulum (a test checks it against ``double_pendulum``'s closed form).

Default sampler (N = 3): ``m_i = exp(0.3 N(0,1))``, ``l_i ~ U(0.5, 1.0)``,
``theta_0 ~ U(-pi/4, pi/4)^N``, ``thetad_0 ~ U(-pi/5, pi/5)^N``.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..errors import InputError
from .base import GRAVITY, System, as_range


class ChainPendulum(System):
    name = "chain_pendulum"
    quadratic_kinetic = True

    def __init__(self, num_links: int = 3, m_log_std: float = 0.3, l_range=(0.5, 1.0),
                 theta_range=(-math.pi / 4, math.pi / 4), omega_range=(-math.pi / 5, math.pi / 5)) -> None:
        try:
            num_links = int(num_links)
        except (TypeError, ValueError):
            raise InputError(f"chain_pendulum: num_links must be an integer, got {num_links!r}") from None
        if num_links < 1:
            raise InputError(f"chain_pendulum: num_links must be >= 1, got {num_links}")
        if not (math.isfinite(m_log_std) and m_log_std >= 0):
            raise InputError(f"chain_pendulum: m_log_std must be >= 0, got {m_log_std}")
        self.num_links = num_links
        self.m_log_std = float(m_log_std)
        self.l_range = as_range(l_range, "l_range")
        self.theta_range = as_range(theta_range, "theta_range")
        self.omega_range = as_range(omega_range, "omega_range")
        if self.l_range.low <= 0:
            raise InputError(f"chain_pendulum: l_range must be positive, got {self.l_range}")
        n = num_links
        self.dof = n
        self.angle_mask = (True,) * n
        self.coord_names = tuple(f"theta{i + 1}" for i in range(n))
        self.param_names = tuple(f"m{i + 1}" for i in range(n)) + tuple(f"l{i + 1}" for i in range(n))
        self.param_units = ("kg",) * n + ("m",) * n
        listed = (lambda x: f"{x}1" if n == 1 else f"{x}1..{x}{n}")  # noqa: E731 (a chain of one link: theta1)
        self.conventions = (
            f"q=({listed('theta')}): absolute angles from the downward vertical, counter-clockwise positive, rad; "
            f"params=({listed('m')}, {listed('l')}) in kg and m; point masses on massless rods; g=9.81 m/s^2"
        )
        # tail[i, k] = 1 if k >= i: mu_i = sum_k tail[i, k] m_k (mass at and below joint i)
        self._tail = torch.triu(torch.ones(n, n, dtype=torch.float64))

    def scale_invariance(self) -> dict:
        """The common scale of its masses (``System.mass_scale``: every mass is a parameter)."""
        return self.mass_scale()

    def config(self) -> dict:
        return {"num_links": self.num_links, "m_log_std": self.m_log_std,
                "l_range": [self.l_range.low, self.l_range.high],
                "theta_range": [self.theta_range.low, self.theta_range.high],
                "omega_range": [self.omega_range.low, self.omega_range.high]}

    def sample_params(self, rng, n):
        m = np.exp(self.m_log_std * rng.standard_normal((n, self.num_links)))
        return np.concatenate([m, self.l_range.sample(rng, (n, self.num_links))], axis=-1)

    def sample_state(self, rng, n):
        return self.theta_range.sample(rng, (n, self.num_links)), self.omega_range.sample(rng, (n, self.num_links))

    # ------------------------------------------------------------------ physics
    def _split(self, params):
        n = self.num_links
        m, l = params[..., :n], params[..., n:]
        mu = m @ self._tail.to(m).T  # (*batch, N): mu_i = sum_{k >= i} m_k
        return mu, l

    def _coupling(self, params):
        """``mu_ij l_i l_j`` with ``mu_ij = mu_max(i,j)``: ``(*batch, N, N)``."""
        mu, l = self._split(params)
        n = self.num_links
        ar = torch.arange(n, device=params.device)
        idx = torch.maximum(ar[:, None], ar[None, :])  # (N, N)
        mu_ij = mu[..., idx]  # (*batch, N, N)
        return mu_ij * l[..., :, None] * l[..., None, :]

    def mass_matrix(self, q, params):
        diff = q[..., :, None] - q[..., None, :]
        return self._coupling(params) * torch.cos(diff)

    def potential(self, q, params):
        mu, l = self._split(params)
        return -GRAVITY * (mu * l * torch.cos(q)).sum(-1)

    def free_acceleration(self, q, qd, params):
        diff = q[..., :, None] - q[..., None, :]
        K = self._coupling(params)
        M = K * torch.cos(diff)
        mu, l = self._split(params)
        rhs = -(K * torch.sin(diff) * (qd * qd)[..., None, :]).sum(-1) - GRAVITY * mu * l * torch.sin(q)
        return torch.linalg.solve(M, rhs[..., None])[..., 0]

    def energy_scale(self, params):
        mu, l = self._split(params)
        return 2 * GRAVITY * (mu * l).sum(-1)

    def positions(self, q, params):
        """Cartesian positions of the masses, shape ``(*batch, N, 2)`` in m."""
        _, l = self._split(params)
        x = torch.cumsum(l * torch.sin(q), -1)
        y = -torch.cumsum(l * torch.cos(q), -1)
        return torch.stack([x, y], -1)
