"""The readable form of the networks: plain formulas, torch's own activations, torch.func derivatives.

The fast paths (``TangentMLP``, ``FiLM``, the parts of ``StructuredLagrangian``) compute the same functions in
cheaper forms (tanh layers in sigmoid form, FiLM pairs mapped onto the weights, hand-carried
tangents, a hand-written reverse pass, an unrolled Cholesky solve); the tests compare them with the
functions here in float64. Nothing here is meant to be fast.

With ``h_0`` the input features and ``(gamma_i, beta_i)`` the FiLM pair of hidden layer ``i``:

    h_i = gamma_i * act(W_i h_{i-1} + b_i) + beta_i,   y = W_out h_n + b_out

and FiLM itself is ``[g | beta] = W_2 silu(W_1 cond + b_1) + b_2``, ``gamma = 1 + g``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ..mechanics.euler_lagrange import structured_acceleration

ACTIVATIONS = {"tanh": torch.tanh, "sigmoid": torch.sigmoid, "softplus": F.softplus,
               "isru": lambda z: z / torch.sqrt(1 + z * z)}


def film_pairs(film, cond: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """FiLM pairs ``[(gamma, beta), ...]`` of a ``FiLM`` module, each ``(B, size)``."""
    last = film.net[-1]
    if len(film.net) == 1:  # quadratic in the parameters
        n = cond.shape[-1]
        pairs = [cond[..., i] * cond[..., j] for i in range(n) for j in range(i, n)]
        hidden = torch.cat([cond, torch.stack(pairs, -1)], -1)
    else:
        first = film.net[0]
        hidden = F.silu(F.linear(cond, first.weight, first.bias))
    out = F.linear(hidden, last.weight, last.bias)
    n = sum(film.sizes)
    g, beta = out[..., :n], out[..., n:]
    gammas, betas = (1 + g).split(film.sizes, -1), beta.split(film.sizes, -1)
    return list(zip(gammas, betas, strict=True))


def mlp(net, x: torch.Tensor, film=None) -> torch.Tensor:
    """A ``TangentMLP``'s output ``(B, out)`` by the plain formula (``film``: ``film_pairs`` or None)."""
    act = ACTIVATIONS[net.activation]
    h = x
    for i, layer in enumerate(net.hidden):
        h = act(F.linear(h, layer.weight, layer.bias))
        if film is not None:
            gamma, beta = film[i]
            h = gamma * h + beta
    return F.linear(h, net.out.weight, net.out.bias)


def features(model, q_norm: torch.Tensor) -> torch.Tensor:
    """``[sin q_a, cos q_a, q_lin]`` of normalised coordinates ``(B, dof)`` -> ``(B, F)``; ``q_a``: the
    angle coordinates, then the scene's angle combinations (e.g. ``q1 + q2``)."""
    angles = [i for i, a in enumerate(model.scene.angle_mask) if a]
    linear = [i for i, a in enumerate(model.scene.angle_mask) if not a]
    qa = q_norm[..., angles]
    if model.scene.angle_combinations:
        combos = torch.tensor(model.scene.angle_combinations, dtype=q_norm.dtype, device=q_norm.device)
        qa = torch.cat([qa, (combos * q_norm[..., None, :]).sum(-1)], -1)
    return torch.cat([torch.sin(qa), torch.cos(qa), q_norm[..., linear]], -1)


def cholesky(model, q_norm: torch.Tensor, params_norm: torch.Tensor) -> torch.Tensor:
    """A structured model's mass-matrix factor ``F`` (``M = F F^T + eps I``): its kinetic parts'
    references side by side (``lnn_torch.networks.parts``)."""
    phi = features(model, q_norm)
    return torch.cat([part.reference_factor(q_norm, params_norm, phi) for part in model.kinetic.values()], -1)


def mass_matrix(model, q_norm, params_norm) -> torch.Tensor:
    """``M = F F^T + eps I``, ``(B, dof, dof)``."""
    chol = cholesky(model, q_norm, params_norm)
    return chol @ chol.mT + model.eps * torch.eye(model.scene.dof, dtype=chol.dtype, device=chol.device)


def potential(model, q_norm, params_norm) -> torch.Tensor:
    """A structured model's potential ``V (B,)``: the sum of its potential parts' references."""
    phi, g = features(model, q_norm), model.gravity_constant_norm(q_norm.dtype)
    return sum(part.reference_potential(q_norm, params_norm, phi, g) for part in model._potential_parts)


def lagrangian(model, q_norm, qd_norm, params_norm) -> torch.Tensor:
    """``L = 1/2 qd^T M qd - V`` of ONE sample ``(dof,), (dof,), (P,) -> ()`` (for the generic solve)."""
    M = mass_matrix(model, q_norm[None], params_norm[None])[0]
    return 0.5 * qd_norm @ M @ qd_norm - potential(model, q_norm[None], params_norm[None])[0]


def structured_model_acceleration(model, q_norm, qd_norm, params_norm, force_norm=None) -> torch.Tensor:
    """A structured model's normalised accelerations by torch.func (jvp of M, grads of T and V) and a
    LAPACK Cholesky solve: ``lnn_torch.mechanics.euler_lagrange.structured_acceleration`` on the plain networks,
    under the normalised generalised force ``force_norm`` (None: none)."""
    return structured_acceleration(lambda q1, p1: cholesky(model, q1[None], p1[None])[0],
                                   lambda q1, p1: potential(model, q1[None], p1[None])[0],
                                   q_norm, qd_norm, params_norm, eps=model.eps, force=force_norm)
