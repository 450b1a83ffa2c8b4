"""Kinetic part ``mlp``: the mass matrix's Cholesky factor from an MLP of the features (FiLM on the
parameters, or the parameters as inputs), with forward tangents carried by hand.

``chol`` is lower-triangular with ``softplus(.) + diag_shift`` on its diagonal, so ``M = chol chol^T +
eps I`` is positive definite by construction. Beside another kinetic part (the rigid chain) it is a
residual that starts near zero (``chol ~ 0.02 I``).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ...errors import InputError
from .. import reference
from .._kernels import one
from ..layers import TangentMLP
from ..normalization import trusted
from .base import BuildContext, FiLMConditioned, KineticPart, PartInputs, option


def cholesky_scatter(dof: int, extra: int = 0) -> torch.Tensor:
    """``(n_chol + extra, dof^2 + extra)``: the Cholesky entries (diagonal first) scattered into a
    row-major lower-triangular matrix, the ``extra`` outputs passed through (folded into a network's
    output layer, which so outputs the ``dof^2`` matrix directly)."""
    rows, cols = torch.tril_indices(dof, dof)
    order = torch.cat([torch.nonzero(rows == cols)[:, 0], torch.nonzero(rows != cols)[:, 0]])
    n_chol = dof * (dof + 1) // 2
    scatter = torch.zeros(n_chol + extra, dof * dof + extra)
    scatter[torch.arange(n_chol), rows[order] * dof + cols[order]] = 1.0
    for i in range(extra):
        scatter[n_chol + i, dof * dof + i] = 1.0
    return scatter


def chol_from(raw: torch.Tensor, draw: torch.Tensor | None, diag: torch.Tensor, shift: float, dof: int):
    """The factor ``(B, dof, dof)`` and its tangents ``(K, B, dof, dof)`` from a network's ``(B, dof^2)``
    outputs (0 above the diagonal) and their tangents ``(K, B, dof^2)``: softplus + shift on the
    diagonal (computed on every entry, kept on the diagonal)."""
    B = raw.shape[0]
    chol = torch.where(diag, F.softplus(raw) + shift, raw).view(B, dof, dof)
    if draw is None:
        return chol, None
    dchol = draw * torch.where(diag, torch.sigmoid(raw), one(raw))  # d softplus = sigmoid
    return chol, dchol.reshape(-1, B, dof, dof)


def reference_chol(entries: torch.Tensor, dof: int, shift: float) -> torch.Tensor:
    """The plain form of ``chol_from``: entries ``(B, n_chol)`` (the dof diagonal entries, then the rest
    row-major) -> ``(B, dof, dof)``."""
    rows, cols = torch.tril_indices(dof, dof, device=entries.device)
    diagonal = rows == cols
    rows = torch.cat([rows[diagonal], rows[~diagonal]])
    cols = torch.cat([cols[diagonal], cols[~diagonal]])
    values = torch.cat([F.softplus(entries[..., :dof]) + shift, entries[..., dof:]], -1)
    flat = entries.new_zeros(*entries.shape[:-1], dof * dof).index_copy(-1, rows * dof + cols, values)
    return flat.view(*entries.shape[:-1], dof, dof)


class CholeskyMLP(FiLMConditioned, KineticPart):
    """``mlp``: ``chol (B, dof, dof)`` from a ``TangentMLP`` of the features.

    Options (None: the model's default): ``hidden_dims``, ``activation``, ``film_mode``,
    ``film_hidden``, ``diag_shift``; ``mass_invariant``: coordinates (indices) that the mass matrix
    does not depend on (the network then reads only the features that do not involve them, e.g.
    ``[0]`` for a serial arm in joint angles).
    """

    name = "mlp"

    def __init__(self, ctx: BuildContext, hidden_dims=None, activation=None, film_mode=None, film_hidden=None,
                 diag_shift=None, mass_invariant: list[int] | None = None, residual: bool = False) -> None:
        super().__init__()
        dof, P = ctx.dof, ctx.num_params
        self.dof = dof
        self.hidden_dims = tuple(option(ctx, hidden_dims, "hidden_dims"))
        self.film_mode, self.film_hidden = option(ctx, film_mode, "film_mode"), option(ctx, film_hidden, "film_hidden")
        self.diag_shift = float(option(ctx, diag_shift, "diag_shift"))
        self._feature_index(ctx, mass_invariant)
        Fk = ctx.num_features if self.index is None else len(self.index)
        self.net = TangentMLP(Fk if ctx.film else Fk + P, list(self.hidden_dims), dof * (dof + 1) // 2,
                              option(ctx, activation, "activation"))
        self.register_buffer("scatter", cholesky_scatter(dof), persistent=False)
        self.register_buffer("diag", torch.eye(dof, dtype=torch.bool).flatten(), persistent=False)
        self.residual = bool(residual)
        if self.residual:  # beside another kinetic part: starts at chol ~ 0.02 I
            with torch.no_grad():
                self.net.out.weight.zero_()
                self.net.out.bias.zero_()
                self.net.out.bias[:dof] = -4.0

    def _feature_index(self, ctx: BuildContext, invariant) -> None:
        """Registers ``index``: the features the network reads when the mass matrix does not depend on
        the coordinates ``invariant`` (None: all features)."""
        if invariant is None:
            self.index = None
            return
        invariant = sorted({int(i) for i in invariant})
        if any(not 0 <= i < ctx.dof for i in invariant):
            raise InputError(f"mass_invariant must list coordinate indices in [0, {ctx.dof}), got {invariant}")
        G = ctx.sel_angle.T  # (n_angles, dof): the feature angles in terms of q
        na = G.shape[0]
        angles = [i for i in range(na) if not G[i, invariant].any()]
        linear = [k for k, j in enumerate(ctx.linear_idx) if j not in invariant]
        index = angles + [na + i for i in angles] + [2 * na + k for k in linear]
        if not index:
            raise InputError(f"mass_invariant {invariant} leaves the kinetic network no feature to read")
        self.register_buffer("index", torch.tensor(index, dtype=torch.long), persistent=False)

    def coefficient_parameters(self):
        # a residual's output bias: decay towards 0 would grow a diagonal that starts at softplus(-4)
        return [self.net.out.bias] if self.residual else []

    def _inputs(self, phi, params_norm):
        return phi if self.film is not None else torch.cat([phi, trusted(params_norm)], -1)

    def factor(self, inputs: PartInputs, cond):
        phi, dphi = inputs.phi, inputs.dphi
        if self.index is not None:  # only the features the mass matrix depends on
            phi = phi[..., self.index]
            dphi = None if dphi is None else dphi[..., self.index]
        # (B, dof^2), (K, B, dof^2); 0 above the diagonal
        raw, draw = self.net(self._inputs(phi, inputs.params_norm), dphi, cond, out_map=self.scatter.to(phi.dtype))
        return chol_from(raw, draw, self.diag, self.diag_shift, self.dof)

    def reference_factor(self, q_norm, params_norm, phi):
        if self.index is not None:
            phi = phi[..., self.index]
        film = None if self.film is None else reference.film_pairs(self.film, trusted(params_norm))
        entries = reference.mlp(self.net, self._inputs(phi, params_norm), film)  # (B, n_chol)
        return reference_chol(entries, self.dof, self.diag_shift)
