"""The identified two-link model (``lnn_torch.identification.two_link``): its base-parameter regressor against its own
forward dynamics, the round trip through base parameters, and classical least squares recovering a known
model from its own noise-free data (float64)."""

import math

import pytest
import torch

from lnn_torch.identification.two_link import BASE, RigidArmModel, acceleration_errors, base_regressor

TRUE = RigidArmModel(m1=0.62, m2=0.55, l1=0.21, r1=0.18, r2=0.31, I1=0.027, I2=0.051, Ir=1e-4, gr=6.0, b1=0.004,
                     b2=0.002, cf1=0.09, cf2=0.07)


def states(n: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    q = (torch.rand(n, 2, generator=g, dtype=torch.float64) - 0.5) * 2 * math.pi
    qd = torch.randn(n, 2, generator=g, dtype=torch.float64) * 3
    tau = torch.randn(n, 2, generator=g, dtype=torch.float64) * 0.5
    return q, qd, tau


def test_the_regressor_inverts_the_forward_dynamics():
    q, qd, tau = states(200)
    qdd = TRUE.acceleration(q, qd, None, tau)
    beta = torch.tensor([TRUE.base[k] for k in BASE], dtype=torch.float64)
    torch.testing.assert_close(base_regressor(q, qd, qdd) @ beta, tau, rtol=0, atol=1e-12)
    torch.testing.assert_close(TRUE.inverse(q, qd, qdd), tau, rtol=0, atol=1e-12)


def test_the_base_parameters_are_the_physical_ones_combined():
    v = TRUE.values
    assert TRUE.base["A"] == pytest.approx(v["I1"] + v["I2"] + v["m2"] * v["l1"] ** 2 + (v["gr"] ** 2 + 1) * v["Ir"])
    assert TRUE.base["B"] == pytest.approx(v["I2"] - v["gr"] * v["Ir"])
    assert TRUE.base["K"] == pytest.approx(v["m2"] * v["l1"] * v["r2"])
    assert TRUE.base["P1"] == pytest.approx(v["m1"] * v["r1"] + v["m2"] * v["l1"])


def test_a_model_from_base_parameters_has_the_same_dynamics_and_energy():
    q, qd, tau = states(100, seed=1)
    other = RigidArmModel.from_base(TRUE.base)
    torch.testing.assert_close(other.acceleration(q, qd, None, tau), TRUE.acceleration(q, qd, None, tau),
                               rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(other.energy(q, qd), TRUE.energy(q, qd), rtol=1e-12, atol=1e-12)
    # its physical values are one consistent set: built from them again, the same base parameters
    again = RigidArmModel(**{k: v for k, v in other.values.items()})
    for k in BASE:
        assert again.base[k] == pytest.approx(TRUE.base[k], rel=1e-12, abs=1e-15), k


def test_least_squares_recovers_the_model_from_its_own_data():
    q, qd, tau = states(500, seed=2)
    qdd = TRUE.acceleration(q, qd, None, tau)
    fitted = RigidArmModel.least_squares(q, qd, qdd, tau)
    for k in BASE:
        assert fitted.base[k] == pytest.approx(TRUE.base[k], rel=1e-8, abs=1e-12), k
    q2, qd2, tau2 = states(50, seed=3)
    torch.testing.assert_close(fitted.acceleration(q2, qd2, None, tau2), TRUE.acceleration(q2, qd2, None, tau2),
                               rtol=1e-8, atol=1e-8)
    # and with noise on the torques it stays close, not exact
    noisy = RigidArmModel.least_squares(q, qd, qdd, tau + 0.01 * torch.randn_like(tau))
    assert noisy.base["P1"] == pytest.approx(TRUE.base["P1"], rel=0.02)
    assert noisy.base["P1"] != TRUE.base["P1"]


def test_least_squares_refuses_what_the_data_cannot_determine():
    q = torch.zeros(50, 2, dtype=torch.float64)
    with pytest.raises(ValueError, match="determine"):
        RigidArmModel.least_squares(q, q, q, q)
    # torques of a model whose mass matrix is not positive definite (C < 0) fit a model no better
    q, qd, tau = states(300, seed=6)
    wrong = RigidArmModel.from_base({**TRUE.base, "C": -0.05})
    Y = base_regressor(q, qd, TRUE.acceleration(q, qd, None, tau))
    beta = torch.tensor([wrong.base[k] for k in BASE], dtype=torch.float64)
    with pytest.raises(ValueError, match="positive definite"):
        RigidArmModel.least_squares(q, qd, TRUE.acceleration(q, qd, None, tau), Y @ beta)
    bad = torch.full((50, 2), float("nan"), dtype=torch.float64)
    with pytest.raises(ValueError, match="NaN"):
        RigidArmModel.least_squares(bad, bad, bad, bad)


def test_least_squares_in_accelerations_recovers_the_model_and_weighs_by_the_mass_matrix():
    q, qd, tau = states(500, seed=4)
    qdd = TRUE.acceleration(q, qd, None, tau)
    exact = RigidArmModel.least_squares(q, qd, qdd, tau, space="acceleration")
    for k in BASE:
        assert exact.base[k] == pytest.approx(TRUE.base[k], rel=1e-8, abs=1e-12), k
    # with noise on the accelerations, each fit minimises its own criterion: the acceleration fit has the
    # smaller acceleration error, the torque fit the smaller torque error
    noisy = qdd + 2.0 * torch.randn(qdd.shape, generator=torch.Generator().manual_seed(5), dtype=torch.float64)
    by_torque = RigidArmModel.least_squares(q, qd, noisy, tau)
    by_acc = RigidArmModel.least_squares(q, qd, noisy, tau, space="acceleration")

    def acc_err(m):
        return float((m.acceleration(q, qd, None, tau) - noisy).pow(2).sum())

    def torque_err(m):
        return float((m.inverse(q, qd, noisy) - tau).pow(2).sum())

    assert acc_err(by_acc) < acc_err(by_torque)
    assert torque_err(by_torque) < torque_err(by_acc)
    # a minimum of the acceleration error: its gradient there is zero to round-off (at the torque fit it is not)
    Y, cos_q2 = base_regressor(q, qd, noisy), torch.cos(q[:, 1])

    def gradient(model):
        beta = torch.tensor([model.base[k] for k in BASE], dtype=torch.float64, requires_grad=True)
        acceleration_errors(beta, Y, tau, cos_q2).pow(2).sum().backward()
        return beta.grad

    scale = torch.tensor([TRUE.base[k] for k in BASE], dtype=torch.float64).abs()
    assert float((gradient(by_acc) * scale).abs().max()) < 1e-6 * float((gradient(by_torque) * scale).abs().max())
    with pytest.raises(ValueError, match="space"):
        RigidArmModel.least_squares(q, qd, qdd, tau, space="energy")


def test_the_tanh_smoothing_of_coulomb_friction_is_a_model_of_its_own_that_least_squares_recovers():
    """``coulomb_shape="tanh"``: the regressor inverts that model's dynamics, least squares recovers it,
    and it is not the arctan model (the friction differs at moderate speeds); an unknown shape is refused."""
    true = RigidArmModel(**TRUE.values, coulomb_slope=50.0, coulomb_shape="tanh")
    q, qd, tau = states(300, seed=4)
    qdd = true.acceleration(q, qd, None, tau)
    beta = torch.tensor([true.base[k] for k in BASE], dtype=torch.float64)
    torch.testing.assert_close(base_regressor(q, qd, qdd, coulomb_slope=50.0, coulomb_shape="tanh") @ beta, tau,
                               rtol=0, atol=1e-12)
    fitted = RigidArmModel.least_squares(q, qd, qdd, tau, coulomb_slope=50.0, coulomb_shape="tanh")
    for k in BASE:
        assert fitted.base[k] == pytest.approx(true.base[k], rel=1e-8, abs=1e-12), k
    arctan = RigidArmModel(**TRUE.values, coulomb_slope=50.0)
    assert (arctan.acceleration(q, qd, None, tau) - qdd).abs().max() > 1e-2
    with pytest.raises(ValueError, match="coulomb_shape must be one of tanh, arctan"):
        RigidArmModel(**TRUE.values, coulomb_shape="sign")
