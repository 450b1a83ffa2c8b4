"""Part ``shared``: ONE network whose outputs are both the Cholesky entries and the potential, as Deep
Lagrangian Networks share their hidden layers. A single pass with forward tangents gives ``chol``,
``d chol / dq``, ``V`` and ``dV/dq`` (about half the work of two networks;
``results/cost_accuracy/README.md``). Its input is the features and the parameters (plus FiLM)."""

from __future__ import annotations

import torch
from torch import nn

from .. import reference
from ..layers import TangentMLP
from ..normalization import trusted
from .base import BuildContext, FiLMConditioned, KineticPart, PartInputs, PotentialPart, PotentialTerm, option
from .cholesky import chol_from, cholesky_scatter, reference_chol


class SharedMLP(FiLMConditioned, KineticPart, PotentialPart):
    """``shared``: the kinetic and the potential part in one network (outputs ``[Cholesky entries | V]``).
    Options (None: the model's default): ``hidden_dims``, ``activation``, ``film_mode``,
    ``film_hidden``, ``diag_shift``."""

    name = "shared"

    def __init__(self, ctx: BuildContext, hidden_dims=None, activation=None, film_mode=None, film_hidden=None,
                 diag_shift=None) -> None:
        nn.Module.__init__(self)
        dof = self.dof = ctx.dof
        self.hidden_dims = tuple(option(ctx, hidden_dims, "hidden_dims"))
        self.film_mode, self.film_hidden = option(ctx, film_mode, "film_mode"), option(ctx, film_hidden, "film_hidden")
        self.diag_shift = float(option(ctx, diag_shift, "diag_shift"))
        self.net = TangentMLP(ctx.num_features + ctx.num_params, list(self.hidden_dims), dof * (dof + 1) // 2 + 1,
                              option(ctx, activation, "activation"))
        self.register_buffer("scatter", cholesky_scatter(dof, extra=1), persistent=False)
        self.register_buffer("diag", torch.eye(dof, dtype=torch.bool).flatten(), persistent=False)

    def _outputs(self, inputs: PartInputs, cond):
        """``(chol, dchol, V, dV/dq)`` from one pass, once per evaluation."""
        def compute():
            n = self.dof ** 2
            x = torch.cat([inputs.phi, trusted(inputs.params_norm)], -1)
            y, dy = self.net(x, inputs.dphi, cond, out_map=self.scatter.to(x.dtype))
            chol, dchol = chol_from(y[:, :n], None if dy is None else dy[..., :n], self.diag, self.diag_shift, self.dof)
            return chol, dchol, y[:, n], (None if dy is None else dy[..., n].mT)

        return inputs.shared(self, compute)

    def factor(self, inputs: PartInputs, cond):
        chol, dchol, _, _ = self._outputs(inputs, cond)
        return chol, dchol

    def potential(self, inputs: PartInputs, cond, grad: bool) -> PotentialTerm:
        _, _, V, dV = self._outputs(inputs, cond)
        return PotentialTerm(V, dV_dq=dV if grad else None)

    def _reference_outputs(self, params_norm, phi):
        film = None if self.film is None else reference.film_pairs(self.film, trusted(params_norm))
        return reference.mlp(self.net, torch.cat([phi, trusted(params_norm)], -1), film)

    def reference_factor(self, q_norm, params_norm, phi):
        return reference_chol(self._reference_outputs(params_norm, phi)[..., :-1], self.dof, self.diag_shift)

    def reference_potential(self, q_norm, params_norm, phi, gravity):
        return self._reference_outputs(params_norm, phi)[..., -1]
