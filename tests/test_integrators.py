"""Fixed-step integrators (``lnn_torch.mechanics.integrators``): the methods, the written-out RK4 against its
tableau, and the convergence orders."""

import numpy as np
import pytest
import torch

from lnn_torch import rollout


def test_rollout_function_methods_and_no_grad():
    from lnn_torch.systems import get_system

    system = get_system("pendulum")
    params = torch.tensor([[1.0, 1.0]], dtype=torch.float64)
    q0 = torch.tensor([[0.1]], dtype=torch.float64)
    qd0 = torch.zeros_like(q0)
    exact_period = 2 * np.pi / np.sqrt(9.81)
    for method in ("rk4", "leapfrog", "semi_implicit_euler", "rk8"):
        with torch.no_grad():
            q, qd = rollout(system.acceleration, q0, qd0, params, 0.001, 1000, method=method)
        assert q.shape == (1, 1001, 1) and not q.requires_grad
        assert abs(q[0, -1, 0].item() - 0.1 * np.cos(2 * np.pi / exact_period)) < 5e-3
    with pytest.raises(ValueError, match="unknown integrator 'euler2'"):
        rollout(system.acceleration, q0, qd0, params, 0.01, 1, method="euler2")


def test_written_out_rk4_equals_the_tableau_form():
    from lnn_torch.mechanics.integrators import explicit_rk_step, rk4_step
    from lnn_torch.systems import get_system

    system = get_system("double_pendulum")
    rng = np.random.default_rng(0)
    params = torch.tensor(system.sample_params(rng, 16))
    q, qd = (torch.tensor(x) for x in system.sample_state(rng, 16))
    q1, qd1 = rk4_step(system.acceleration, q, qd, params, 0.01)
    y = explicit_rk_step("rk4", lambda y, p: torch.cat([y[:, 2:], system.acceleration(y[:, :2], y[:, 2:], p)], -1),
                         torch.cat([q, qd], -1), params, 0.01)
    torch.testing.assert_close(torch.cat([q1, qd1], -1), y, rtol=0, atol=1e-14)


@pytest.mark.parametrize("method, order", [("rk4", 4), ("leapfrog", 2), ("semi_implicit_euler", 1), ("rk8", 8)])
def test_integrator_convergence_orders(method, order):
    """Halving dt divides the global error by 2^order (harmonic oscillator, exact solution)."""
    from lnn_torch.systems import get_system

    system = get_system("mass_spring")
    params = torch.tensor([[1.0, 4.0]], dtype=torch.float64)  # omega = 2
    q0, qd0 = torch.tensor([[1.0]], dtype=torch.float64), torch.tensor([[0.0]], dtype=torch.float64)
    errs = []
    base = {1: 0.01, 2: 0.02, 4: 0.05, 8: 0.2}[order]
    for dt in (base, base / 2):
        n = int(round(2.0 / dt))
        q, _ = rollout(system.acceleration, q0, qd0, params, dt, n, method=method)
        errs.append(abs(q[0, -1, 0].item() - np.cos(2 * 2.0)))
    measured = np.log2(errs[0] / errs[1])
    assert abs(measured - order) < 0.35, measured
