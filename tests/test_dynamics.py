"""The Euler-Lagrange solves of ``lnn_torch.mechanics.euler_lagrange``: the generic Hessian solve (singular Hessians,
double backward) and the SPD solve."""

import pytest
import torch

from lnn_torch.mechanics.euler_lagrange import SingularHessianError, generic_acceleration


def test_generic_solve_reports_singular_hessian():
    def lagrangian(q, qd, params):  # depends on qd1 + qd2 only: d2L/dqd2 has rank 1
        return 0.5 * (qd[0] + qd[1]) ** 2 - q[0] ** 2

    q = torch.randn(5, 2, dtype=torch.float64)
    qd = torch.randn(5, 2, dtype=torch.float64)
    params = torch.ones(5, 1, dtype=torch.float64)
    with pytest.raises(SingularHessianError, match="singular for 5 of 5"):
        generic_acceleration(lagrangian, q, qd, params)
    regularised = generic_acceleration(lagrangian, q, qd, params, hessian_reg=1e-3)
    assert torch.isfinite(regularised).all()
    with pytest.raises(TypeError):  # "damping" means physical dissipation: no option of the solve
        generic_acceleration(lagrangian, q, qd, params, damping=1e-3)


def test_generic_solve_double_backward():
    """The generic solve is differentiable (training the black-box LNN needs the double backward)."""
    k = torch.tensor(2.0, dtype=torch.float64, requires_grad=True)

    def lagrangian(q, qd, params):
        return 0.5 * params[0] * qd @ qd - 0.5 * k * q @ q

    q = torch.randn(3, 2, dtype=torch.float64)
    qd = torch.randn(3, 2, dtype=torch.float64)
    params = torch.full((3, 1), 0.5, dtype=torch.float64)
    a = generic_acceleration(lagrangian, q, qd, params)
    torch.testing.assert_close(a, -k.detach() / 0.5 * q)
    (g,) = torch.autograd.grad(a.sum(), k)
    torch.testing.assert_close(g, -(q / 0.5).sum())


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 5, 7])
def test_spd_solve_equals_linalg_solve(dof):
    """The Cholesky solve (unrolled up to SMALL_SPD, LAPACK beyond) equals torch.linalg.solve on
    random and ill-conditioned (cond ~1e8) SPD systems in float64; non-SPD input gives NaN."""
    from lnn_torch.mechanics.euler_lagrange import spd_solve

    gen = torch.Generator().manual_seed(dof)
    A = torch.randn(64, dof, dof, generator=gen, dtype=torch.float64)
    Q = torch.linalg.qr(A)[0]
    eig = torch.logspace(-8, 0, dof, dtype=torch.float64) if dof > 1 else torch.ones(1, dtype=torch.float64)
    for M in (A @ A.mT + 0.1 * torch.eye(dof, dtype=torch.float64), Q @ torch.diag_embed(eig.expand(64, -1)) @ Q.mT):
        rhs = torch.randn(64, dof, generator=gen, dtype=torch.float64)
        ref = torch.linalg.solve(M, rhs)
        x = spd_solve(M, rhs)
        residual = (M @ x[..., None])[..., 0] - rhs
        assert residual.abs().max() <= 1e-13 * M.abs().max() * x.abs().max()  # backward stable
        assert (x - ref).abs().max() <= 1e-12 * torch.linalg.cond(M).max() * ref.abs().max()
    bad = -torch.eye(dof, dtype=torch.float64).expand(3, -1, -1)
    assert torch.isnan(spd_solve(bad, torch.ones(3, dof, dtype=torch.float64))).all(-1).any()
    M = (A @ A.mT + torch.eye(dof, dtype=torch.float64))[:2].requires_grad_(True)
    rhs = torch.randn(2, dof, dtype=torch.float64, requires_grad=True)
    sym = lambda m, r: spd_solve(0.5 * (m + m.mT), r)  # noqa: E731  (the solve reads the lower triangle)
    assert torch.autograd.gradcheck(sym, (M, rhs))


@pytest.mark.parametrize("dof", [2, 6, 7])
def test_unrolled_solves_give_lapacks_factor_and_solution_without_its_operators(dof):
    """Within ``unrolled_solves`` (how programs are traced for export: ONNX has no Cholesky operator) the
    factor and the solve of any size are elementwise operators, equal to LAPACK's in float64; a traced
    program holds no Cholesky operator; outside, the factor is LAPACK's."""
    from lnn_torch.mechanics.euler_lagrange import cholesky, spd_solve, unrolled_solves

    gen = torch.Generator().manual_seed(dof)
    A = torch.randn(16, dof, dof, generator=gen, dtype=torch.float64)
    M, rhs = A @ A.mT + 0.1 * torch.eye(dof, dtype=torch.float64), torch.randn(16, dof, generator=gen,
                                                                               dtype=torch.float64)
    with unrolled_solves():
        L, x = cholesky(M), spd_solve(M, rhs)
        graph = torch.export.export(_Solve(), (M, rhs)).graph_module.code
    torch.testing.assert_close(L, torch.linalg.cholesky(M), rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(x, torch.linalg.solve(M, rhs), rtol=1e-10, atol=1e-12)
    assert "cholesky" not in graph and "sqrt" in graph
    assert "cholesky" in torch.export.export(_Solve(), (M, rhs)).graph_module.code  # (LAPACK's outside)


class _Solve(torch.nn.Module):
    def forward(self, M, rhs):
        from lnn_torch.mechanics.euler_lagrange import cholesky, spd_solve

        return cholesky(M), spd_solve(M, rhs)
