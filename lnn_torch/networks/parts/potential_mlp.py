"""Potential part ``mlp``: ``V`` from an MLP of the features and the parameters (FiLM on its hidden
layers too, unless ``potential_film`` is off), its gradient by a hand-written reverse pass. Beside the
spatial arm's gravity it is a residual that starts at zero."""

from __future__ import annotations

import torch

from .. import reference
from ..layers import TangentMLP
from ..normalization import trusted
from .base import BuildContext, FiLMConditioned, PartInputs, PotentialPart, PotentialTerm, option


class PotentialMLP(FiLMConditioned, PotentialPart):
    """``mlp``: ``V (B,)`` from a ``TangentMLP`` of ``[phi, params]`` (no output bias: an energy is
    defined up to a constant). Options (None: the model's default): ``hidden_dims``, ``activation``,
    ``film_mode``, ``film_hidden``, ``potential_film`` (FiLM on this network too)."""

    name = "mlp"

    def __init__(self, ctx: BuildContext, hidden_dims=None, activation=None, film_mode=None, film_hidden=None,
                 potential_film: bool | None = None, residual: bool = False) -> None:
        super().__init__()
        self.hidden_dims = tuple(option(ctx, hidden_dims, "hidden_dims"))
        self.film_mode, self.film_hidden = option(ctx, film_mode, "film_mode"), option(ctx, film_hidden, "film_hidden")
        self.use_film = bool(option(ctx, potential_film, "potential_film"))
        self.num_features = ctx.num_features
        self.net = TangentMLP(ctx.num_features + ctx.num_params, list(self.hidden_dims), 1,
                              option(ctx, activation, "activation"), out_bias=False)
        self.residual = bool(residual)
        if self.residual:  # beside a physical potential (the arm's gravity): starts at V = 0
            torch.nn.init.zeros_(self.net.out.weight)

    def potential(self, inputs: PartInputs, cond, grad: bool) -> PotentialTerm:
        x = torch.cat([inputs.phi, trusted(inputs.params_norm)], -1)
        if not grad:
            return PotentialTerm(self.net(x, None, cond)[0][..., 0])
        V, dV_dphi = self.net.value_and_input_grad(x, cond, num_grad_inputs=self.num_features)
        return PotentialTerm(V, dV_dphi=dV_dphi)

    def reference_potential(self, q_norm, params_norm, phi, gravity):
        film = None if self.film is None else reference.film_pairs(self.film, trusted(params_norm))
        return reference.mlp(self.net, torch.cat([phi, trusted(params_norm)], -1), film)[..., 0]
