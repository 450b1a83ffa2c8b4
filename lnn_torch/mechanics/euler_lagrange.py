"""Euler-Lagrange solves: accelerations from a Lagrangian, never predicted directly.

For ``L(q, qd)`` and a generalised force ``Q`` (inputs, dissipation: ``lnn_torch.mechanics.forces``) the
Euler-Lagrange equations ``d/dt dL/dqd - dL/dq = Q`` give

    H qdd = dL/dq - J qd + Q,    H = d2L/dqd2 (dof x dof),  J[i, j] = d2L / dqd_i dq_j.

* ``generic_acceleration`` solves this for ANY scalar Lagrangian with ``torch.func`` (hessian,
  jacrev, vmap) and ``torch.linalg.solve_ex``. A singular or indefinite-at-machine-precision
  Hessian is reported (``SingularHessianError``), or regularised when asked for (``hessian_reg``).
* ``structured_acceleration`` solves ``M qdd = dL/dq - Mdot qd + Q`` for ``L = 1/2 qd^T M(q) qd - V(q)``
  with the model's own Cholesky factor of M (no Hessian of L).

Pure tensor functions: no networks, no Lightning.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable

import torch
from torch.func import hessian, jacrev, vmap

from ..errors import SingularHessianError

LagrangianFn = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


def _flatten(q, qd, params):
    if q.shape != qd.shape:
        raise ValueError(f"q and qd must have the same shape, got {tuple(q.shape)} and {tuple(qd.shape)}")
    if params.shape[:-1] != q.shape[:-1]:
        raise ValueError(f"params batch shape {tuple(params.shape[:-1])} differs from q's {tuple(q.shape[:-1])}")
    batch = q.shape[:-1]
    n = q.reshape(-1, q.shape[-1]).shape[0]
    return batch, q.reshape(n, q.shape[-1]), qd.reshape(n, q.shape[-1]), params.reshape(n, params.shape[-1])


def euler_lagrange_terms(lagrangian_fn: LagrangianFn, q, qd, params):
    """Velocity Hessian and right-hand side of the Euler-Lagrange equations.

    Args:
        lagrangian_fn: scalar ``L(q, qd, params)`` for ONE sample: ``(dof,), (dof,), (P,) -> ()``.
        q, qd: ``(B, dof)``; params: ``(B, P)``.

    Returns:
        ``H`` of shape ``(B, dof, dof)`` and ``rhs = dL/dq - J qd`` of shape ``(B, dof)``.
    """

    def single(q1, qd1, p1):
        H = hessian(lagrangian_fn, argnums=1)(q1, qd1, p1)
        dL_dq = jacrev(lagrangian_fn, argnums=0)(q1, qd1, p1)
        J = jacrev(jacrev(lagrangian_fn, argnums=1), argnums=0)(q1, qd1, p1)
        return H, dL_dq - J @ qd1

    return vmap(single)(q, qd, params)


def generic_acceleration(
    lagrangian_fn: LagrangianFn,
    q: torch.Tensor,
    qd: torch.Tensor,
    params: torch.Tensor,
    hessian_reg: float = 0.0,
    check: bool = True,
    force: torch.Tensor | None = None,
) -> torch.Tensor:
    """Accelerations of any Lagrangian by the generic Euler-Lagrange solve.

    Args:
        lagrangian_fn: scalar Lagrangian of one sample (see ``euler_lagrange_terms``).
        q, qd: ``(*batch, dof)``; params: ``(*batch, P)``.
        hessian_reg: the singular-Hessian policy. ``0`` (default) solves exactly and raises
            ``SingularHessianError`` where the solve fails; ``> 0`` solves
            ``H + hessian_reg (mean|diag H| + 1) I`` instead (Levenberg-style regularisation,
            relative to the Hessian's scale with a floor, in the units of ``lagrangian_fn``).
        check: raise ``SingularHessianError`` on singular Hessians (costs one sync). With
            ``check=False`` the accelerations of singular states are NaN (never silently wrong).
        force: a generalised force ``Q (*batch, dof)`` in the units of ``lagrangian_fn`` per
            coordinate, added to the right-hand side (None: none).

    Returns:
        ``qdd`` of shape ``(*batch, dof)``, same dtype and device as ``q``.
    """
    batch, qf, qdf, pf = _flatten(q, qd, params)
    H, rhs = euler_lagrange_terms(lagrangian_fn, qf, qdf, pf)
    if force is not None:
        rhs = rhs + force.reshape(rhs.shape)
    if hessian_reg > 0:
        # relative to the Hessian's scale, with a floor of 1 so that a vanishing Hessian is regularised too
        scale = H.diagonal(dim1=-2, dim2=-1).abs().mean(-1, keepdim=True) + 1
        H = H + hessian_reg * scale[..., None] * torch.eye(H.shape[-1], dtype=H.dtype, device=H.device)
    qdd, info = torch.linalg.solve_ex(H, rhs[..., None])
    qdd = qdd[..., 0]
    bad = (info != 0) | ~torch.isfinite(qdd).all(-1)  # (B,)
    if check and bad.any():
        n = int(bad.sum())
        raise SingularHessianError(
            f"the velocity Hessian d2L/dqd2 is singular for {n} of {bad.numel()} states; "
            "accelerations are undefined there (pass hessian_reg > 0 to regularise)"
        )
    qdd = torch.where(bad[:, None], torch.full_like(qdd, float("nan")), qdd)
    return qdd.reshape(*batch, q.shape[-1])


def structured_acceleration(
    chol_fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    potential_fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
    q: torch.Tensor,
    qd: torch.Tensor,
    params: torch.Tensor,
    eps: float = 0.0,
    force: torch.Tensor | None = None,
) -> torch.Tensor:
    """Accelerations of ``L = 1/2 qd^T M qd - V`` with ``M = chol chol^T + eps I`` (torch.func reference).

    ``M qdd = dT/dq - dV/dq - Mdot qd`` where ``Mdot qd`` comes from a jvp of ``M(q)`` along ``qd``
    and ``dT/dq = 1/2 d(qd^T M qd)/dq`` from a vjp. Solved by a LAPACK Cholesky factorisation of M
    and ``cholesky_solve``.

    Args:
        chol_fn: ``(q, params) -> chol`` for ONE sample, any factor ``(dof, r)`` of ``M - eps I``.
        potential_fn: ``(q, params) -> V`` for ONE sample, scalar.
        q, qd: ``(*batch, dof)``; params ``(*batch, P)``.
    """
    batch, qf, qdf, pf = _flatten(q, qd, params)
    dof = q.shape[-1]

    def mass_fn(q1, p1):
        c = chol_fn(q1, p1)
        return c @ c.mT + eps * torch.eye(dof, dtype=c.dtype, device=c.device)

    def single(q1, qd1, p1):
        M, dM = torch.func.jvp(lambda x: mass_fn(x, p1), (q1,), (qd1,))
        dT_dq = torch.func.grad(lambda x: 0.5 * qd1 @ mass_fn(x, p1) @ qd1)(q1)
        dV_dq = torch.func.grad(lambda x: potential_fn(x, p1))(q1)
        return M, dT_dq - dV_dq - dM @ qd1

    M, rhs = vmap(single)(qf, qdf, pf)
    if force is not None:
        rhs = rhs + force.reshape(rhs.shape)
    chol = torch.linalg.cholesky(M)
    qdd = torch.cholesky_solve(rhs[..., None], chol)[..., 0]
    return qdd.reshape(*batch, dof)


# Cholesky solves of SPD systems up to this size are unrolled over the matrix entries
SMALL_SPD = 4
# the largest system ``spd_solve`` unrolls now (``unrolled_solves`` raises it): a plain value, not a ContextVar, which
# torch.compile would not trace (each solve a graph break)
_UNROLLED = {"up_to": SMALL_SPD}


@contextlib.contextmanager
def unrolled_solves():
    """Within it, ``spd_solve`` and ``cholesky`` unroll systems of any size: a traced program (``torch.export``)
    then holds elementwise operators only, which every backend translates (ONNX has no Cholesky operator)."""
    before = _UNROLLED["up_to"]
    _UNROLLED["up_to"] = 10**9
    try:
        yield
    finally:
        _UNROLLED["up_to"] = before


def _unrolled_factor(M: torch.Tensor) -> tuple[list, list]:
    """The Cholesky factor of ``M (..., d, d)`` entry by entry (``potrf``'s algorithm as elementwise operators):
    ``L[i][j] (...)`` for ``j <= i`` and ``1 / L[j][j]``. NaN where ``M`` is not positive definite."""
    d = M.shape[-1]
    L = [[None] * d for _ in range(d)]
    inv = [None] * d  # 1 / L[j][j]
    for j in range(d):
        s = M[..., j, j]
        for k in range(j):
            s = torch.addcmul(s, L[j][k], L[j][k], value=-1)
        L[j][j] = torch.sqrt(s)
        inv[j] = torch.reciprocal(L[j][j])
        for i in range(j + 1, d):
            s = M[..., i, j]
            for k in range(j):
                s = torch.addcmul(s, L[i][k], L[j][k], value=-1)
            L[i][j] = s * inv[j]
    return L, inv


def cholesky(M: torch.Tensor) -> torch.Tensor:
    """The lower-triangular Cholesky factor of ``M (..., d, d)`` (positive definite): ``torch.linalg.cholesky``,
    or entry by entry within ``unrolled_solves`` (a traced program then needs no Cholesky operator)."""
    if _UNROLLED["up_to"] <= SMALL_SPD:  # outside unrolled_solves
        return torch.linalg.cholesky(M)
    d = M.shape[-1]
    L, _ = _unrolled_factor(M)
    zero = torch.zeros_like(M[..., 0, 0])
    return torch.stack([torch.stack([L[i][j] if j <= i else zero for j in range(d)], -1) for i in range(d)], -2)


def spd_solve(M: torch.Tensor, rhs: torch.Tensor) -> torch.Tensor:
    """Solve ``M x = rhs`` for symmetric positive definite ``M (B, d, d)``, ``rhs (B, d)``, by Cholesky.

    For ``d <= SMALL_SPD`` the factorisation (``potrf``) and the two triangular solves (``potrs``)
    are unrolled over the entries: the same algorithm as LAPACK's, as a few elementwise ops on
    ``(B,)`` columns instead of one LAPACK call per matrix (cheaper for batches of small systems;
    ``benchmarks/benchmark_dynamics.py`` times the whole solve). Larger systems use
    ``torch.linalg.cholesky_ex`` and ``torch.cholesky_solve`` (but within ``unrolled_solves``). Only the lower
    triangle of ``M`` is read. A matrix that is not positive definite gives NaN (never a silently wrong solution).
    """
    d = M.shape[-1]
    if d > _UNROLLED["up_to"]:
        factor, info = torch.linalg.cholesky_ex(M)
        x = torch.cholesky_solve(rhs[..., None], factor)[..., 0]
        return torch.where((info != 0)[..., None], torch.full_like(x, float("nan")), x)
    L, inv = _unrolled_factor(M)
    y = []  # L y = rhs
    for i in range(d):
        s = rhs[..., i]
        for k in range(i):
            s = torch.addcmul(s, L[i][k], y[k], value=-1)
        y.append(s * inv[i])
    x = [None] * d  # L^T x = y
    for i in reversed(range(d)):
        s = y[i]
        for k in range(i + 1, d):
            s = torch.addcmul(s, L[k][i], x[k], value=-1)
        x[i] = s * inv[i]
    return torch.stack(x, -1)


def structured_acceleration_from_factor(
    chol: torch.Tensor, dchol: torch.Tensor, qd: torch.Tensor, dV_dq: torch.Tensor, eps: float,
    return_kinetic: bool = False, force: torch.Tensor | None = None,
):
    """Accelerations of ``L = 1/2 qd^T M qd - V`` from a Cholesky factor and its q-derivatives.

    ``M = chol chol^T + eps I``. With ``u = chol^T qd`` and ``du_k = dchol_k^T qd``:
    ``dT/dq_k = u . du_k`` and ``Mdot qd = cdot u + chol cdot^T qd`` with
    ``cdot = sum_k qd_k dchol_k``; then ``M qdd = dT/dq - dV/dq - Mdot qd`` is solved by Cholesky
    (``spd_solve``: unrolled for small systems, ``cholesky_solve`` otherwise).

    Args:
        chol: ``(B, dof, r)``: any factor with ``M = chol chol^T + eps I`` (the lower-triangular
            Cholesky factor, ``r = dof``, or a rectangular one such as the rigid chain's).
        dchol: ``(dof, B, dof, r)``: ``dchol[k] = d chol / d q_k``.
        qd: ``(B, dof)``; dV_dq: ``(B, dof)``.
        return_kinetic: also return ``T = 1/2 qd^T M qd``, shape ``(B,)``.
        force: a generalised force ``(B, dof)`` added to the right-hand side (None: none).
    """
    qd_col = qd[..., None]  # (B, dof, 1)
    u = torch.bmm(chol.mT, qd_col)  # (B, dof, 1)
    du = dchol.mT @ qd_col  # (K, B, dof, 1)
    dT_dq = (du * u).sum((-2, -1)).mT  # (B, K)
    # (B, dof, r); as a product and a sum rather than an einsum: 4-6x faster at batch 512-4096 with 7 joints
    cdot = (dchol * qd.mT[..., None, None]).sum(0)
    mdot_qd = torch.baddbmm(cdot @ u, chol, cdot.mT @ qd_col)[..., 0]  # (B, dof)
    M = torch.bmm(chol, chol.mT)
    if torch.compiler.is_exporting():  # the same values without an in-place op on a view (ONNX's decompositions)
        M = M + eps * torch.eye(M.shape[-1], dtype=M.dtype, device=M.device)
    else:
        M.diagonal(dim1=-2, dim2=-1).add_(eps)
    rhs = dT_dq - dV_dq - mdot_qd
    qdd = spd_solve(M, rhs if force is None else rhs + force)
    if not return_kinetic:
        return qdd
    T = 0.5 * (u.square().sum((-2, -1)) + eps * qd.square().sum(-1))
    return qdd, T
