"""Classical identification of a serial arm: inverse dynamics linear in the inertial parameters, the
regressor, and the base parameters (the combinations a trajectory can identify).

Each moving body's inertia enters the joint torques linearly through its pseudo-inertia ``J_i``
(``lnn_torch.robots.kinematics``): with ``D_ki = dT_i/dq_k = S_k T_i`` and the pose acceleration
``Tdd_i = A_i T_i``, ``A_i = sum_{l <= i} S_l qdd_l + sum_{l, m <= i} S_min(l,m) S_max(l,m) qd_l qd_m``,

    tau_k = sum_{i >= k} [ tr(D_ki J_i Tdd_i^T) - g~^T D_ki J_i e_4 ] + armature_k qdd_k + damping_k qd_k

(``g~ = (g, 0)``). The parameter vector ``pi`` has, per link, ``(Ixx, Iyy, Izz, Ixy, Ixz, Iyz, m cx, m
cy, m cz, m)`` (inertia about the link frame's origin, first moment, mass; the classical ten), then the
armature and the viscous damping of every joint: ``tau = Y(q, qd, qdd) pi``.

A trajectory excites only some combinations of ``pi``: ``base_parameters`` finds them by QR with
column pivoting of the stacked regressor (Gautier's numerical base parameters): ``r`` independent
columns ``B`` and the others ``D = B K``, so ``tau = Y_B (pi_B + K pi_D)``: the base parameters
``beta = pi_B + K pi_D``; a parameter outside every combination gets no number.
"""

from __future__ import annotations

import numpy as np
import torch

from ..errors import InputError
from .kinematics import SerialChain, payload_at_flange, payload_pseudo_inertia, poses_and_twists

LINK_NAMES = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz", "mcx", "mcy", "mcz", "m")


def parameter_names(chain: SerialChain) -> list[str]:
    links = [f"{name}.{p}" for name in chain.joint_names for p in LINK_NAMES]
    return links + [f"{n}.armature" for n in chain.joint_names] + [f"{n}.damping" for n in chain.joint_names]


def pseudo_inertia_of(pi_links: torch.Tensor) -> torch.Tensor:
    """``J (..., n, 4, 4)`` from the classical ten per link ``(..., n, 10)``."""
    ixx, iyy, izz, ixy, ixz, iyz, hx, hy, hz, m = pi_links.unbind(-1)
    I = torch.stack([torch.stack([ixx, ixy, ixz], -1), torch.stack([ixy, iyy, iyz], -1),
                     torch.stack([ixz, iyz, izz], -1)], -2)
    tr = (ixx + iyy + izz)[..., None, None]
    sigma = 0.5 * tr * torch.eye(3, dtype=pi_links.dtype) - I
    h = torch.stack([hx, hy, hz], -1)
    return torch.cat([torch.cat([sigma, h[..., None]], -1), torch.cat([h, m[..., None]], -1)[..., None, :]], -2)


def classical_of(J: torch.Tensor) -> torch.Tensor:
    """The classical ten per link ``(..., n, 10)`` from pseudo-inertias ``(..., n, 4, 4)``."""
    sigma = J[..., :3, :3]
    I = sigma.diagonal(dim1=-2, dim2=-1).sum(-1)[..., None, None] * torch.eye(3, dtype=J.dtype) - sigma
    return torch.stack([I[..., 0, 0], I[..., 1, 1], I[..., 2, 2], I[..., 0, 1], I[..., 0, 2], I[..., 1, 2],
                        J[..., 0, 3], J[..., 1, 3], J[..., 2, 3], J[..., 3, 3]], -1)


def parameter_vector(J: torch.Tensor, armature: torch.Tensor, damping: torch.Tensor) -> torch.Tensor:
    """``pi (12 n,)``: the classical ten of each link, armature, damping."""
    return torch.cat([classical_of(J).reshape(-1), armature, damping])


def inverse_dynamics(chain: SerialChain, q, qd, qdd, pi: torch.Tensor) -> torch.Tensor:
    """``tau (B, n)`` at states ``(B, n)`` for the parameter vector ``pi (12 n,)`` (module docstring)."""
    n = chain.dof
    J = pseudo_inertia_of(pi[: 10 * n].reshape(n, 10))
    armature, damping = pi[10 * n: 11 * n], pi[11 * n:]
    return rigid_body_torque(chain, q, qd, qdd, J) + armature * qdd + damping * qd


def payload_torque(chain: SerialChain, q, qd, qdd, payload: torch.Tensor) -> torch.Tensor:
    """``tau (B, n)``: the joint torques that carrying a payload at the flange adds, one payload per row
    ``(B, 4)`` (mass, centre of mass in the flange frame) or ``(B, 10)`` (and its inertia about the centre
    of mass): its rigid body's inverse dynamics, exact (zero without a flange or with a zero payload)."""
    q, qd, qdd, payload = (torch.as_tensor(x, dtype=torch.float64) for x in (q, qd, qdd, payload))
    if chain.flange is None or payload.shape[-1] == 0:
        return torch.zeros_like(q)
    J = q.new_zeros(q.shape[0], chain.dof, 4, 4)
    J[:, -1] = payload_at_flange(chain.flange, payload)
    return rigid_body_torque(chain, q, qd, qdd, J)


def payload_ten(payload: torch.Tensor) -> torch.Tensor:
    """A payload's classical ten ``(B, 10)`` in the flange frame about the flange's origin (``LINK_NAMES``'
    order: inertia about the origin, first moment ``m c``, mass) from its rows ``(B, 4 or 10)`` (mass,
    centre of mass, [inertia about the centre of mass]): what its torques are linear in."""
    return classical_of(payload_pseudo_inertia(payload))


def flange_map(chain: SerialChain) -> torch.Tensor:
    """``G (10, 10)``: the last link's classical ten of a payload whose classical ten at the flange is ``p``
    (``payload_ten``) is ``G p`` (the pseudo-inertia carried from the flange's frame to the link's,
    ``X J X^T``: linear)."""
    Xf = chain.flange.to(torch.float64)
    basis = pseudo_inertia_of(torch.eye(10, dtype=torch.float64))  # (10, 4, 4): J of each unit parameter
    return classical_of(Xf @ basis @ Xf.T).T


def payload_regressor(chain: SerialChain, q, qd, qdd, Y: torch.Tensor | None = None) -> torch.Tensor:
    """``Y_p (B, n, 10)`` with the torques a payload adds ``= Y_p payload_ten(row)`` (exact: the last link's
    columns of ``regressor`` through ``flange_map``; ``Y``: that regressor where already computed)."""
    if chain.flange is None:
        raise InputError("payload regressor: the robot description has no flange to carry a payload")
    n = chain.dof
    Y = regressor(chain, q, qd, qdd) if Y is None else Y
    return Y[..., 10 * (n - 1): 10 * n] @ flange_map(chain).to(Y.dtype)


def _motion(chain: SerialChain, q, qd, qdd):
    """``(D (B, k, i, 4, 4), Tdd (B, i, 4, 4), upto (k, i))``: the module docstring's ``D_ki``, ``Tdd_i`` and
    the mask ``k <= i``."""
    n = chain.dof
    T, S = poses_and_twists(chain, q)
    idx = torch.arange(n)
    upto = (idx[:, None] <= idx[None, :]).to(q.dtype)  # [l, i]: l <= i
    # A_i = sum over l, m <= i of S_min(l,m) S_max(l,m) qd_l qd_m + sum over l <= i of S_l qdd_l: each pair l <= h once
    # (twice off the diagonal), gathered at h = max(l, m), then summed up to i (a running sum over h; the sum over
    # every (l, m, i) at once took four fifths of the regressor's time)
    lo, hi = torch.triu_indices(n, n, device=q.device)
    weight = torch.where(lo < hi, 2.0, 1.0).to(q.dtype) * qd[:, lo] * qd[:, hi]  # (B, pairs)
    pairs = (S[:, lo] @ S[:, hi]) * weight[..., None, None]
    gather = (hi == torch.arange(n, device=q.device)[:, None]).to(q.dtype)  # (h, pairs): out of place, vmap runs
    at = torch.einsum("hp,bpxy->bhxy", gather, pairs) + S * qdd[..., None, None]
    A = torch.cumsum(at, 1)  # (B, i, 4, 4)
    return torch.einsum("bkxy,biyz->bkixz", S, T), A @ T, upto


def rigid_body_torque(chain: SerialChain, q, qd, qdd, J: torch.Tensor) -> torch.Tensor:
    """``tau (B, n)`` of the links alone (no armature, no damping) with pseudo-inertias ``J (n, 4, 4)``, or
    one set per row ``(B, n, 4, 4)``."""
    D, Tdd, upto = _motion(chain, q, qd, qdd)
    Jb = J.expand(q.shape[0], -1, -1, -1) if J.ndim == 3 else J  # (B, n, 4, 4)
    inertial = torch.einsum("bkixy,biyz,bixz->bki", D, Jb, Tdd)  # tr(D J Tdd^T)
    g = torch.cat([chain.gravity.to(q.dtype), q.new_zeros(1)])
    weight = torch.einsum("x,bkixy,biy->bki", g, D, Jb[:, :, :, 3])
    return ((inertial - weight) * upto[None]).sum(-1)


ROWS = 2048  # states per block of the regressor (its memory: about 50 kB per state for seven joints)


def regressor(chain: SerialChain, q, qd, qdd) -> torch.Tensor:
    """``Y (B, n, 12 n)`` with ``tau = Y pi`` (exact: the torques are linear in ``pi``): in closed form,
    ``d tau_k / d J_i = D_ki^T Tdd_i - (D_ki^T g~) e_4^T`` (``k <= i``) mapped to the classical ten by the
    linear ``pseudo_inertia_of``, then ``qdd_k`` and ``qd_k`` for the armature and damping; computed in
    blocks of ``ROWS`` states (``reference_regressor``: the same by forward-mode derivatives)."""
    q, qd, qdd = (torch.as_tensor(x) for x in (q, qd, qdd))
    n = chain.dof
    # d J / d pi of one link: (16, 10), the same linear map for every link
    dJ = pseudo_inertia_of(torch.eye(10, dtype=q.dtype)).reshape(10, 16).T
    g = torch.cat([chain.gravity.to(q.dtype), q.new_zeros(1)])
    e4 = torch.zeros(4, dtype=q.dtype)
    e4[3] = 1.0
    eye = torch.eye(n, dtype=q.dtype)
    blocks = []
    for lo in range(0, q.shape[0], ROWS):
        rows = slice(lo, lo + ROWS)
        D, Tdd, upto = _motion(chain, q[rows], qd[rows], qdd[rows])
        W = (torch.einsum("bkixy,bixz->bkiyz", D, Tdd)
             - torch.einsum("x,bkixy,z->bkiyz", g, D, e4)) * upto[None, :, :, None, None]  # (B, k, i, 4, 4)
        links = (W.flatten(-2) @ dJ).flatten(-2)  # (B, k, 10 n)
        blocks.append(torch.cat([links, eye * qdd[rows, :, None], eye * qd[rows, :, None]], -1))
    return torch.cat(blocks) if blocks else q.new_zeros(0, n, 12 * n)


def reference_regressor(chain: SerialChain, q, qd, qdd) -> torch.Tensor:
    """``regressor`` by its definition: the forward-mode derivatives of ``inverse_dynamics`` along each
    parameter (84 passes of the recursion per state: for tests)."""
    p = 12 * chain.dof
    zero = torch.zeros(p, dtype=q.dtype)
    basis = torch.eye(p, dtype=q.dtype)
    _, cols = torch.func.vmap(
        lambda e: torch.func.jvp(lambda x: inverse_dynamics(chain, q, qd, qdd, x), (zero,), (e,)))(basis)
    return cols.permute(1, 2, 0)


# a parameter whose regressor column is under this fraction of the largest column's norm moves no torque that data
# can show, nor does a combination whose column beyond the others' span is under it: left out of the base parameters
# (kept at the description's value; a combination as the dependent columns are). Round-off is 1e-16 of it; joint axes
# a description writes a few microradians off (``rpy="3.1416 0 0"``: 7e-6 rad) gave columns and combinations of 1e-7
# to 6e-6 that became base parameters of hundreds or thousands of kg m (link 1's centre of mass of a near-vertical
# first joint); on the shipped and tried arms the smallest column that motion moves is 2e-3 of the largest (viscous
# friction at a twentieth of the usual speeds)
NEGLIGIBLE = 1e-4


def base_parameters(Y: torch.Tensor, rtol: float = 1e-6) -> dict:
    """The identifiable combinations of a stacked regressor ``Y (N, p)``: ``{"independent": indices B (r,),
    "dependent": D, "K": (r, p - r), "rank": r, "map": P (r, p)}`` with ``beta = P pi = pi_B + K pi_D``
    (QR with column pivoting of the unit-scaled columns; ``rtol``: the rank tolerance relative to the largest
    ``|R_jj|``; a pivot whose unscaled column beyond the earlier pivots' span is under ``NEGLIGIBLE`` of the largest
    column's norm is dependent too)."""
    import scipy.linalg

    Yn = Y.detach().double().cpu().numpy()
    scale = np.linalg.norm(Yn, axis=0)
    top = scale.max() if scale.size else 0.0  # (before the zero columns' scale is set to 1)
    zero = scale <= NEGLIGIBLE * top  # a parameter that moves no torque worth the name
    scale[zero] = 1.0
    Ys = np.where(zero[None, :], 0.0, Yn / scale)
    _, R, piv = scipy.linalg.qr(Ys, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int((d > rtol * d[0]).sum())  # the pivots beyond round-off
    # of those, the independent ones: not a pivot whose unscaled column beyond the earlier pivots' span moves under
    # NEGLIGIBLE of the largest column's torque (scaled up from a small column, a tilt's microradians reach 3e-3 of a
    # unit pivot); the rest are dependent, expressed in the independent ones by least squares (in R's coordinates)
    keep = np.zeros(len(d), dtype=bool)
    keep[:rank] = d[:rank] * scale[piv[:rank]] > NEGLIGIBLE * top
    while True:  # a dependent column the kept ones leave more than NEGLIGIBLE of (a larger column sharing a dropped
        # small pivot's direction) is kept too, the worst first
        K = np.linalg.lstsq(R[:, keep], R[:, ~keep], rcond=None)[0] if keep.any() else np.zeros((0, (~keep).sum()))
        left = np.linalg.norm(R[:, ~keep] - R[:, keep] @ K, axis=0) * scale[piv[~keep]]
        if not left.size or left.max() <= NEGLIGIBLE * top:
            break
        keep[np.flatnonzero(~keep)[int(np.argmax(left))]] = True
    r = int(keep.sum())
    B, D = piv[keep], piv[~keep]
    K = K * scale[D][None, :] / scale[B][:, None]  # back to unscaled columns: Y_D = Y_B K
    P = np.zeros((r, Yn.shape[1]))
    P[np.arange(r), B] = 1.0
    P[:, D] += K
    return {"independent": B, "dependent": D, "K": K, "rank": r, "map": P}
