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


def test_a_first_axis_written_microradians_off_vertical_adds_no_base_parameter(setup):
    """A description that writes ``rpy="3.1416 0 0"`` tilts its first joint 7e-6 rad: the first link's centre of
    mass then moves a torque of a few millionths of the others', which became two base parameters (values of
    hundreds of kg m on a real trial, corrupting the joint's offset). Such a column is now no base parameter: the
    tilted arm has the exact arm's base parameters, and least squares on its noise-free torques recovers them."""
    import copy

    import mujoco

    arm, chain, q, qd, qdd = setup
    model = copy.deepcopy(arm.model)
    link1 = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "link1")
    half = 0.5 * 7.3e-6
    tilt = np.array([np.cos(half), np.sin(half), 0.0, 0.0])  # about x
    mujoco.mju_mulQuat(model.body_quat[link1], model.body_quat[link1].copy(), tilt)
    tilted = kinematics.read_chain(model)
    names = regressor.parameter_names(chain)
    Y, Y_tilted = (regressor.regressor(c, q, qd, qdd).reshape(-1, 84) for c in (chain, tilted))
    mcx = names.index("joint1.mcx")
    assert 0 < float(Y_tilted[:, mcx].norm()) < 1e-4 * float(Y_tilted.norm(dim=0).max())  # (moves a little now)
    exact, base = regressor.base_parameters(Y), regressor.base_parameters(Y_tilted)
    assert base["rank"] == exact["rank"]
    assert mcx not in base["independent"] and names.index("joint1.mcy") not in base["independent"]
    pi = regressor.parameter_vector(tilted.J, tilted.armature, tilted.damping)
    tau = Y_tilted @ pi
    beta = base_least_squares(Y_tilted, tau, base)
    predicted = torch.as_tensor(Y_tilted[:, base["independent"]].numpy() @ beta)
    assert float((predicted - tau).abs().max()) < 1e-5 * float(tau.abs().max())
    assert np.abs(beta).max() < 10 * np.abs(base["map"] @ pi.numpy()).max()  # no combination blown up


def test_base_parameters_keep_what_a_larger_column_shares_with_a_dropped_small_one_and_ignore_units():
    """A small column pivoted first and left out (under ``NEGLIGIBLE`` of the largest) must not take with it a
    direction a larger column shares: that column is kept. The threshold is relative to the largest column, whatever
    the units (a zero column beside it changes nothing)."""
    rng = np.random.default_rng(0)
    basis = np.linalg.qr(rng.normal(size=(50, 3)))[0]
    a, c = basis[:, 0], basis[:, 1]
    for Y, big in ((torch.tensor(np.stack([a, 1e-5 * c, c], 1)), 2), (torch.tensor(np.stack([a, c, 1e-5 * c], 1)), 1)):
        base = regressor.base_parameters(Y)  # (a tie of the unit-scaled columns: either may be pivoted first)
        assert base["rank"] == 2 and 0 in base["independent"]
        fit = Y[:, base["independent"]].numpy() @ base["map"]
        gap = np.abs(fit - Y.numpy()).max(0)  # per column: c represented (kept), the small one under NEGLIGIBLE
        assert gap.max() < regressor.NEGLIGIBLE and gap[[0, big]].max() < 1e-9, gap
    small = torch.tensor(np.stack([0.01 * a, 1e-5 * c, 0 * a], 1))  # 1e-3 of the largest: a parameter
    for scaled in (small, 100 * small, small[:, :2]):
        assert sorted(regressor.base_parameters(scaled)["independent"].tolist()) == [0, 1]


def test_the_regressor_runs_under_vmap_and_a_cached_one_keeps_gradients(setup):
    from lnn_torch.identification import classical_arm as classical

    _, chain, q, qd, qdd = setup
    whole = regressor.regressor(chain, q, qd, qdd)
    one = torch.func.vmap(lambda a, b, c: regressor.regressor(chain, a[None], b[None], c[None])[0])(q, qd, qdd)
    torch.testing.assert_close(one, whole, rtol=1e-12, atol=1e-12)
    many = [x.repeat(8, 1) for x in (q, qd, qdd)]  # 320 rows: cached
    drive = classical.DriveModel.of("viscous")
    classical._regressor(chain, *many, drive)
    x = many[0].clone().requires_grad_()
    Y = classical._regressor(chain, x, *many[1:], drive)
    assert Y.requires_grad
    Y.sum().backward()
    assert x.grad is not None and torch.isfinite(x.grad).all()
