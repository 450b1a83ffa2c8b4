"""Potential part ``products``: ``V = sum_k c_k(theta) prod_j u_{j, k_j}(q_j)`` with ``u_j = (1, cos q_j,
sin q_j)``, linear in the tensor products of the joints' first harmonics.

This is the exact form of the gravitational potential of a serial chain of rigid links on revolute
joints, spatial or planar, in its joint angles: each link's centre of mass is its joints' rotations
applied in turn to constant vectors, each rotation linear in ``(cos q_j, sin q_j)``, so its height is a
multilinear polynomial of them; a payload at the flange adds its mass times the flange's height and its
first moment times the flange's orientation, again multilinear. Joints whose axis is along gravity
(an arm's first joint) change no height: ``skip`` leaves them out (``3^n`` terms for the ``n`` others).
Unlike the MLP potential it cannot bend where the data never went, and unlike the ``harmonic`` series
(features of single angles and the scene's angle combinations: a planar chain's exact form) it spans
a spatial arm's.

The coefficients are constants for a system without parameters, else the output of a network of the
normalised parameters: with ``film_hidden: 0`` a quadratic polynomial of them (exact where a payload's
mass and its first moment, mass times centre of mass, are what the parameters set: both are quadratic
in the normalised mass and centre of mass), else a one-hidden-layer tanh network of that width. They
start at zero (no potential).
"""

from __future__ import annotations

import itertools
import math

import torch
from torch import nn

from ...errors import InputError
from ..layers import QuadraticFeatures
from .base import BuildContext, PotentialPart, PotentialTerm, option

MAX_TERMS = 3**8  # 6561 coefficients: nine joints and more take a network instead
# The coefficients are stored divided by GAIN / sqrt(terms): Adam moves every stored coefficient by about
# the learning rate per step, so V moves by about the gain times the root of the number of terms. On the
# arm (729 terms) a gain of 0.1 per coefficient fitted the torques five times better after 800 steps
# than a gain of 1 (and 10, the harmonic series' gain, did not learn the gravity in 6,000 steps).
GAIN = 2.7  # 0.1 per coefficient for 729 terms (an arm of six joints after the vertical one), as measured


class ProductSeries(PotentialPart):
    """``products``: ``V = c(theta) . phi(q)`` over the products of ``(1, cos q_j, sin q_j)``. Options:
    ``skip`` (joint indices left out, e.g. ``[0]`` for an arm's vertical first axis), ``film_hidden``
    (the coefficients' network: 0 quadratic in the parameters; None: the model's default)."""

    name = "products"
    needs_angles = True

    def __init__(self, ctx: BuildContext, skip=None, film_hidden=None) -> None:
        super().__init__()
        skip = sorted({int(j) for j in (skip or [])})
        bad = [j for j in skip if not 0 <= j < ctx.dof]
        if bad:
            raise InputError(f"potential part 'products': skip {bad} is not a joint index of the scene's "
                             f"{ctx.dof} coordinates")
        joints = [j for j in range(ctx.dof) if j not in skip]
        if not joints or 3 ** len(joints) > MAX_TERMS:
            raise InputError(f"potential part 'products' over {len(joints)} joints would have "
                             f"{3 ** len(joints)} terms (1 to {MAX_TERMS}); skip joints or use the 'mlp' potential")
        self.num_terms = 3 ** len(joints)
        self.gain = GAIN / math.sqrt(self.num_terms)
        self.film_hidden = option(ctx, film_hidden, "film_hidden")
        self.register_buffer("joint_idx", torch.tensor(joints, dtype=torch.long), persistent=False)
        self.coef = None

    def build_conditioning(self, ctx: BuildContext):
        """The coefficients' network of the parameters (owned by the model), zero at the start; without
        parameters, the coefficients themselves (the part's own constants)."""
        if not ctx.num_params:
            self.coef = nn.Parameter(torch.zeros(self.num_terms))
            return None
        if self.film_hidden == 0:
            quad = QuadraticFeatures(ctx.num_params)
            net = nn.Sequential(quad, nn.Linear(quad.size, self.num_terms))
        else:
            net = nn.Sequential(nn.Linear(ctx.num_params, self.film_hidden), nn.Tanh(),
                                nn.Linear(self.film_hidden, self.num_terms))
        nn.init.zeros_(net[-1].weight)
        nn.init.zeros_(net[-1].bias)
        return net

    def coefficients(self, params_norm: torch.Tensor) -> torch.Tensor:
        """The coefficients ``(B, 3^n)`` (``(3^n,)`` without parameters)."""
        if self.coef is not None:
            return self.gain * self.coef.to(params_norm.dtype)
        return self.gain * self.conditioning_net(params_norm)

    def coefficient_parameters(self):
        return [] if self.coef is None else [self.coef]

    def _factors(self, q_norm: torch.Tensor):
        """``u (n, B, 3)`` = ``(1, cos, sin)`` of the joints' angles and ``du/dq (n, B, 3)``."""
        a = q_norm[..., self.joint_idx].T
        s, c = torch.sin(a), torch.cos(a)
        one, zero = torch.ones_like(a), torch.zeros_like(a)
        return torch.stack([one, c, s], -1), torch.stack([zero, -s, c], -1)

    @staticmethod
    def _contract(coef: torch.Tensor, factors) -> torch.Tensor:
        """``sum_k coef_k prod_j factors[j][k_j]``: ``coef (B, 3^n)`` or ``(3^n,)``, factors ``(B, 3)`` each
        (the first joint's index varies slowest), contracted from the last joint to the first."""
        B = factors[0].shape[0]
        t = coef.expand(B, -1) if coef.dim() == 1 else coef
        for f in reversed(factors):
            t = (t.reshape(B, -1, 3) * f[:, None, :]).sum(-1)
        return t[:, 0]

    def potential(self, inputs, cond, grad: bool) -> PotentialTerm:
        c = self.coefficients(inputs.params_norm)
        u, du = self._factors(inputs.q_norm)
        n = u.shape[0]
        V = self._contract(c, list(u))
        if not grad:
            return PotentialTerm(V)
        cols = [self._contract(c, [du[j] if i == j else u[i] for i in range(n)]) for j in range(n)]
        dV = torch.zeros_like(inputs.q_norm).index_copy(-1, self.joint_idx, torch.stack(cols, -1))
        return PotentialTerm(V, dV_dq=dV)

    def reference_potential(self, q_norm, params_norm, phi, gravity):
        """Every term written out: ``c_k`` times the product of its factors."""
        c = self.coefficients(params_norm).expand(q_norm.shape[0], -1)
        a = q_norm[..., self.joint_idx]
        table = [(torch.ones_like(a[:, j]), torch.cos(a[:, j]), torch.sin(a[:, j])) for j in range(a.shape[1])]
        V = torch.zeros_like(q_norm[:, 0])
        for k, idx in enumerate(itertools.product(range(3), repeat=a.shape[1])):
            term = c[:, k]
            for j, i in enumerate(idx):
                term = term * table[j][i]
            V = V + term
        return V
