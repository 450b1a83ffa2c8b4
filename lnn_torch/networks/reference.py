"""The readable form of the networks: plain formulas, torch's own activations, torch.func derivatives.

The fast paths (``TangentMLP``, ``FiLM``, ``StructuredLagrangian``) compute the same functions in
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

from ..dynamics import structured_acceleration

ACTIVATIONS = {"tanh": torch.tanh, "sigmoid": torch.sigmoid, "softplus": F.softplus,
               "isru": lambda z: z / torch.sqrt(1 + z * z)}


def film_pairs(film, cond: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """FiLM pairs ``[(gamma, beta), ...]`` of a ``FiLM`` module, each ``(B, size)``."""
    first, _, last = film.net
    out = F.linear(F.silu(F.linear(cond, first.weight, first.bias)), last.weight, last.bias)
    n = sum(film.sizes)
    g, beta = out[..., :n], out[..., n:]
    gammas, betas = (1 + g).split(film.sizes, -1), beta.split(film.sizes, -1)
    return list(zip(gammas, betas))


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
        combos = torch.tensor(model.scene.angle_combinations, dtype=q_norm.dtype)
        qa = torch.cat([qa, (combos * q_norm[..., None, :]).sum(-1)], -1)
    return torch.cat([torch.sin(qa), torch.cos(qa), q_norm[..., linear]], -1)


def _shared_outputs(model, q_norm, params_norm) -> torch.Tensor:
    """The shared network's outputs ``(B, n_chol + 1)``: the Cholesky entries, then ``V``."""
    film = None if model.trunk_film is None else film_pairs(model.trunk_film, params_norm)
    return mlp(model.trunk, torch.cat([features(model, q_norm), params_norm], -1), film)


def chain_positions(chain, q_norm: torch.Tensor, params_norm: torch.Tensor) -> torch.Tensor:
    """The centres of mass ``(B, n, 2)`` of a ``RigidChainKinetic``'s links, written out: joint k + 1 is
    at ``sum_{j <= k} l_j (sin phi_j, -cos phi_j)``, link i's centre of mass ``a_i`` along and ``b_i``
    across its own direction from joint i."""
    p = chain.parameters_of(params_norm)
    phi = q_norm @ chain.link_map.to(q_norm.dtype).T
    out, joint = [], torch.zeros(*q_norm.shape[:-1], 2, dtype=q_norm.dtype)
    for i in range(chain.num_links):
        s, c = torch.sin(phi[..., i]), torch.cos(phi[..., i])
        along, across = p["along"][..., i], p["across"][..., i]
        out.append(joint + torch.stack([along * s + across * c, -along * c + across * s], -1))
        if i < chain.num_links - 1:
            joint = joint + p["length"][..., i, None] * torch.stack([s, -c], -1)
    return torch.stack(out, -2)


def chain_factor(chain, q_norm: torch.Tensor, params_norm: torch.Tensor) -> torch.Tensor:
    """``F (B, dof, r)`` with ``F F^T = sum_i m_i J_i^T J_i + K``, ``J_i = dp_i/dq`` by torch.func and
    ``K = L_K L_K^T`` the constant part (``M = F F^T`` is the chain's mass matrix)."""
    p = chain.parameters_of(params_norm)

    def one(q1, p1):
        return chain_positions(chain, q1[None], p1[None])[0].flatten()  # (2 n,)

    J = torch.func.vmap(torch.func.jacrev(one))(q_norm, params_norm.expand(q_norm.shape[0], -1))  # (B, 2n, dof)
    B = q_norm.shape[0]
    mass = p["mass"].expand(B, -1).repeat_interleave(2, -1)  # (B, 2n): x and y of each link
    return torch.cat([(mass.sqrt()[..., None] * J).mT, p["const"].expand(B, -1, -1)], -1)


def cholesky(model, q_norm: torch.Tensor, params_norm: torch.Tensor) -> torch.Tensor:
    """A structured model's mass-matrix factor ``F`` (``M = F F^T + eps I``): the Cholesky MLP's
    ``(B, dof, dof)``, lower-triangular, diagonal first in the network's outputs, ``softplus(.) +
    diag_shift`` on the diagonal; the rigid chain's ``chain_factor`` (``kinetic: chain``); both side
    by side (``chain+mlp``)."""
    if model.chain is not None:
        Fc = chain_factor(model.chain, q_norm, params_norm)
        if model.kinetic_net is None:
            return Fc
        return torch.cat([Fc, _mlp_cholesky(model, q_norm, params_norm)], -1)
    return _mlp_cholesky(model, q_norm, params_norm)


def _mlp_cholesky(model, q_norm: torch.Tensor, params_norm: torch.Tensor) -> torch.Tensor:
    dof = model.scene.dof
    if model.shared:
        entries = _shared_outputs(model, q_norm, params_norm)[..., :-1]
    else:
        phi = features(model, q_norm)
        if model.kinetic_index is not None:  # a mass matrix independent of some coordinates
            phi = phi[..., model.kinetic_index]
        film = None if model.kinetic_film is None else film_pairs(model.kinetic_film, params_norm)
        x = phi if model.kinetic_film is not None else torch.cat([phi, params_norm], -1)
        entries = mlp(model.kinetic_net, x, film)  # (B, n_chol): the dof diagonal entries, then the rest
    rows, cols = torch.tril_indices(dof, dof)
    diagonal = rows == cols
    rows = torch.cat([rows[diagonal], rows[~diagonal]])
    cols = torch.cat([cols[diagonal], cols[~diagonal]])
    values = torch.cat([F.softplus(entries[..., :dof]) + model.diag_shift, entries[..., dof:]], -1)
    flat = entries.new_zeros(*entries.shape[:-1], dof * dof).index_copy(-1, rows * dof + cols, values)
    return flat.view(*entries.shape[:-1], dof, dof)


def mass_matrix(model, q_norm, params_norm) -> torch.Tensor:
    """``M = chol chol^T + eps I``, ``(B, dof, dof)``."""
    chol = cholesky(model, q_norm, params_norm)
    return chol @ chol.mT + model.eps * torch.eye(model.scene.dof, dtype=chol.dtype, device=chol.device)


def potential(model, q_norm, params_norm) -> torch.Tensor:
    """A structured model's potential ``V (B,)``."""
    if model.shared:
        return _shared_outputs(model, q_norm, params_norm)[..., -1]
    phi, V = features(model, q_norm), 0.0
    if model.potential_net is not None:
        film = None if model.potential_film is None else film_pairs(model.potential_film, params_norm)
        V = mlp(model.potential_net, torch.cat([phi, params_norm], -1), film)[..., 0]
    if model.harmonic:  # plus c(theta) . [sin a, cos a]
        V = V + (phi * model.harmonic_coefficients(params_norm)).sum(-1)
    if model.chain_gravity:  # g times each centre of mass's height, weighted by its mass
        heights = chain_positions(model.chain, q_norm, params_norm)[..., 1]
        V = V + model.gravity_norm(q_norm.dtype) * (model.chain.parameters_of(params_norm)["mass"] * heights).sum(-1)
    return V


def lagrangian(model, q_norm, qd_norm, params_norm) -> torch.Tensor:
    """``L = 1/2 qd^T M qd - V`` of ONE sample ``(dof,), (dof,), (P,) -> ()`` (for the generic solve)."""
    M = mass_matrix(model, q_norm[None], params_norm[None])[0]
    return 0.5 * qd_norm @ M @ qd_norm - potential(model, q_norm[None], params_norm[None])[0]


def structured_model_acceleration(model, q_norm, qd_norm, params_norm, force_norm=None) -> torch.Tensor:
    """A structured model's normalised accelerations by torch.func (jvp of M, grads of T and V) and a
    LAPACK Cholesky solve: ``lnn_torch.dynamics.structured_acceleration`` on the plain networks,
    under the normalised generalised force ``force_norm`` (None: none)."""
    return structured_acceleration(lambda q1, p1: cholesky(model, q1[None], p1[None])[0],
                                   lambda q1, p1: potential(model, q1[None], p1[None])[0],
                                   q_norm, qd_norm, params_norm, eps=model.eps, force=force_norm)
