"""Potential part ``harmonic``: ``V = sum_k c_k(theta) phi_k(q)``, linear in the first-harmonic
features ``sin, cos`` of the angles and the scene's angle combinations.

This is the exact form of the gravitational potential of any chain of rigid links on revolute joints
in a uniform field (each centre of mass's height is a sum of ``l cos`` and ``l sin`` of absolute link
angles, which the angle combinations supply for joint-relative angles); unlike an MLP it cannot bend
where the data never went. Its coefficients are constants for a system without parameters, else the
output of a small network of them. Beside the rigid chain's own gravity it is a residual (forces of
springs, cables or a tilted base) and decays under weight decay; otherwise its coefficients are
physical and exempt.
"""

from __future__ import annotations

import torch
from torch import nn

from .base import BuildContext, PartInputs, PotentialPart, PotentialTerm, option

# The coefficients are stored divided by this gain: Adam moves a parameter by about the learning rate
# per step, and gravity-sized coefficients in the normalised units of a forced system are O(10) (on
# the real double pendulum a gain of 1 reached about 60 % of the lab model's gravity torques in 6,000
# steps; 10, 30 and 100 fitted alike).
HARMONIC_GAIN = 10.0


class HarmonicSeries(PotentialPart):
    """``harmonic``: ``V = c(theta) . phi(q)``. Option ``film_hidden``: the width of the coefficients'
    network (None: the model's default)."""

    name = "harmonic"
    needs_angles = True

    def __init__(self, ctx: BuildContext, film_hidden=None, residual: bool = False) -> None:
        super().__init__()
        self.film_hidden = option(ctx, film_hidden, "film_hidden")
        self.residual = bool(residual)
        self.coef = None

    def build_conditioning(self, ctx: BuildContext):
        """The coefficients' network of the parameters (owned by the model); without parameters, the
        coefficients themselves (the part's own constants)."""
        if ctx.num_params:
            return nn.Sequential(nn.Linear(ctx.num_params, self.film_hidden), nn.Tanh(),
                                 nn.Linear(self.film_hidden, ctx.num_features))
        self.coef = nn.Parameter(torch.zeros(ctx.num_features))
        return None

    def coefficients(self, params_norm: torch.Tensor) -> torch.Tensor:
        """The coefficients ``(B, F)`` (or ``(F,)`` without parameters)."""
        if self.coef is not None:
            return HARMONIC_GAIN * self.coef.to(params_norm.dtype)
        return HARMONIC_GAIN * self.conditioning_net(params_norm)

    def coefficient_parameters(self):
        return [] if self.residual or self.coef is None else [self.coef]

    def potential(self, inputs: PartInputs, cond, grad: bool) -> PotentialTerm:
        c = self.coefficients(inputs.params_norm)
        return PotentialTerm((inputs.phi * c).sum(-1), dV_dphi=c if grad else None)

    def reference_potential(self, q_norm, params_norm, phi, gravity):
        return (phi * self.coefficients(params_norm)).sum(-1)
