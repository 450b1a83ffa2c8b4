"""Classical identification of the arm (``lnn_torch.robots.regressor``): the inverse dynamics linear in
the classical inertial parameters equals MuJoCo's, the regressor reproduces it, and least squares on
the numerical base parameters recovers their true values from noise-free torques (and only those: a
parameter that moves no torque, such as the first link's mass, is in no combination)."""

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco")

from lnn_torch.identification.classical_arm import base_least_squares  # noqa: E402
from lnn_torch.robots import kinematics, regressor  # noqa: E402
from lnn_torch.robots.mujoco_arm import MujocoArm  # noqa: E402


@pytest.fixture(scope="module")
def setup():
    arm = MujocoArm("franka_panda")
    chain = kinematics.read_chain(arm.model)
    rng = np.random.default_rng(3)
    n = 40
    q = torch.tensor(arm.sample_q(rng, n))
    qd, qdd = (torch.tensor(rng.normal(size=(n, 7))) for _ in range(2))
    return arm, chain, q, qd, qdd


def test_linear_inverse_dynamics_is_the_engines(setup):
    arm, chain, q, qd, qdd = setup
    pi = regressor.parameter_vector(chain.J, chain.armature, chain.damping)
    true = arm.inverse(q, qd, qdd)
    assert (regressor.inverse_dynamics(chain, q, qd, qdd, pi) - true).abs().max() <= 1e-10 * true.abs().max()
    Y = regressor.regressor(chain, q, qd, qdd)
    assert Y.shape == (40, 7, 84)
    torch.testing.assert_close(Y, regressor.reference_regressor(chain, q, qd, qdd), rtol=0,
                               atol=1e-12 * float(Y.abs().max()))
    assert ((Y @ pi) - true).abs().max() <= 1e-10 * true.abs().max()
    J_back = regressor.pseudo_inertia_of(regressor.classical_of(chain.J))
    torch.testing.assert_close(J_back, chain.J, rtol=1e-14, atol=1e-14)


def test_least_squares_recovers_the_base_parameters(setup):
    arm, chain, q, qd, qdd = setup
    pi = regressor.parameter_vector(chain.J, chain.armature, chain.damping)
    Y = regressor.regressor(chain, q, qd, qdd).reshape(-1, 84)
    base = regressor.base_parameters(Y)
    names = regressor.parameter_names(chain)
    assert 14 < base["rank"] < 84
    assert names.index("joint1.m") not in base["independent"]  # the first link's mass moves no torque
    assert not base["map"][:, names.index("joint1.m")].any()
    beta = base_least_squares(Y, arm.inverse(q, qd, qdd), base)
    np.testing.assert_allclose(beta, base["map"] @ pi.numpy(), rtol=1e-8, atol=1e-10)


def test_the_regressor_in_blocks_is_the_regressor_at_once(setup, monkeypatch):
    _, chain, q, qd, qdd = setup
    whole = regressor.regressor(chain, q, qd, qdd)
    monkeypatch.setattr(regressor, "ROWS", 16)  # 40 states: blocks of 16, 16 and 8
    torch.testing.assert_close(regressor.regressor(chain, q, qd, qdd), whole, rtol=0, atol=0)
