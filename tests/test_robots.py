"""Robot descriptions through MuJoCo (``lnn_torch.robots``): the shipped Panda loads with its licence,
and its dynamics obey independent references — the inverse undoes the forward dynamics, the mass
matrix is symmetric positive definite with the armature on its diagonal, the payload's holding torque
is the gradient of its potential energy (finite differences of its position), and a payload set at run
time gives the same dynamics as a description written with it."""

import numpy as np
import pytest
import torch

mujoco = pytest.importorskip("mujoco")

from lnn_torch.errors import InputError  # noqa: E402
from lnn_torch.robots import DESCRIPTIONS  # noqa: E402
from lnn_torch.robots.mujoco_arm import MujocoArm  # noqa: E402

PAYLOAD = [1.5, 0.03, -0.02, 0.06]


@pytest.fixture(scope="module")
def arm():
    return MujocoArm("franka_panda")


def _states(arm, n=6, seed=0):
    rng = np.random.default_rng(seed)
    return arm.sample_q(rng, n), rng.normal(size=(n, arm.dof)), rng.normal(size=(n, arm.dof))


def test_the_shipped_panda_loads_with_its_licence_and_conventions(arm):
    folder = DESCRIPTIONS["franka_panda"].parent
    assert "Apache License" in (folder / "LICENSE").read_text() and "Menagerie" in (folder / "NOTICE.md").read_text()
    assert arm.dof == 7 and arm.joint_names == tuple(f"joint{i}" for i in range(1, 8))
    assert torch.allclose(arm.joint_range[3], torch.tensor([-3.0718, -0.0698], dtype=torch.float64))
    assert torch.allclose(arm.gravity_vector, torch.tensor([0.0, 0.0, -9.81], dtype=torch.float64))


def test_inverse_dynamics_undoes_the_forward_dynamics(arm):
    q, qd, tau = _states(arm)
    qdd = arm.forward(q, qd, tau, PAYLOAD)
    torch.testing.assert_close(arm.inverse(q, qd, qdd, PAYLOAD), torch.from_numpy(tau), rtol=0, atol=1e-9)
    # and M qdd + bias = tau + passive
    M, b = arm.mass_matrix(q, PAYLOAD), arm.bias(q, qd, PAYLOAD)
    torch.testing.assert_close(torch.einsum("bij,bj->bi", M, qdd) + b, torch.from_numpy(tau) + arm.friction(q, qd))


def test_the_mass_matrix_is_symmetric_positive_definite_with_the_armature_on_its_diagonal(arm):
    q, _, _ = _states(arm)
    M = arm.mass_matrix(q)
    torch.testing.assert_close(M, M.transpose(1, 2), rtol=0, atol=1e-12)
    assert torch.linalg.eigvalsh(M)[:, 0].min() > 0
    bare = MujocoArm("franka_panda")
    bare.model.dof_armature[:] = 0
    torch.testing.assert_close(M - bare.mass_matrix(q), torch.diag_embed(arm.armature.expand(len(q), -1)))


def test_the_payloads_holding_torque_is_the_gradient_of_its_potential(arm):
    """tau(m) - tau(0) at rest = d(m g z_c)/dq, z_c the payload's centre of mass (central differences
    of its world position, an independent path through the kinematics alone)."""
    q, _, _ = _states(arm, n=3)
    m = PAYLOAD[0]
    extra = arm.gravity(q, PAYLOAD) - arm.gravity(q, [0.0, *PAYLOAD[1:]])
    h = 1e-6
    grad = np.zeros_like(q)
    for j in range(arm.dof):
        dq = np.zeros_like(q)
        dq[:, j] = h
        grad[:, j] = ((arm.payload_position(q + dq, PAYLOAD) - arm.payload_position(q - dq, PAYLOAD))[:, 2]
                      / (2 * h)).numpy()
    torch.testing.assert_close(extra, torch.from_numpy(m * 9.81 * grad), rtol=1e-6, atol=1e-7)


def test_a_payload_set_at_run_time_equals_one_written_in_the_description(arm, tmp_path):
    """Including a full inertia (and a centre of mass off the flange origin: MuJoCo ignores such edits
    of a body compiled with its centre of mass at its origin unless told not to)."""
    payload = [*PAYLOAD, 0.004, 0.003, 0.002, 0.0005, -0.0003, 0.0002]
    text = DESCRIPTIONS["franka_panda"].read_text().replace(
        '<inertial mass="0" pos="0 0 0" diaginertia="0 0 0"/>',
        '<inertial mass="1.5" pos="0.03 -0.02 0.06" fullinertia="0.004 0.003 0.002 0.0005 -0.0003 0.0002"/>')
    assert "fullinertia=\"0.004" in text
    written = tmp_path / "panda_with_payload.xml"
    written.write_text(text)
    q, qd, _ = _states(arm)
    other = MujocoArm(written)
    torch.testing.assert_close(arm.mass_matrix(q, payload), other.mass_matrix(q), rtol=0, atol=1e-12)
    torch.testing.assert_close(arm.bias(q, qd, payload), other.bias(q, qd), rtol=0, atol=1e-10)


def test_bad_input_is_refused_in_one_line(arm, tmp_path):
    with pytest.raises(InputError, match="not a shipped one"):
        MujocoArm("ur5")
    with pytest.raises(InputError, match="q must have shape"):
        arm.mass_matrix(np.zeros((2, 6)))
    with pytest.raises(InputError, match="payload must be"):
        arm.set_payload([-1.0, 0, 0, 0])
    two = tmp_path / "two_ends.xml"
    two.write_text("<mujoco><worldbody><body name='a'><joint/><geom size='0.1'/></body>"
                   "<body name='b'><geom size='0.1'/></body></worldbody></mujoco>")
    with pytest.raises(InputError, match="name the flange .* the chain ends in a, b"):
        MujocoArm(two)
    with pytest.raises(InputError, match="no body or site 'c' for the flange"):
        MujocoArm({"source": str(two), "flange": "c"})


def test_a_description_without_a_payload_body_gets_one_at_its_flange(tmp_path):
    """The payload attaches at the flange a description names (a body: its origin; a site: its frame), by
    default at the chain's last body; the description file itself is not changed."""
    path = tmp_path / "one.xml"
    text = ("<mujoco><worldbody><body name='a'><joint axis='0 1 0'/><geom size='0.1'/>"
            "<site name='tip' pos='0.3 0 0'/></body></worldbody></mujoco>")
    path.write_text(text)
    for flange, tip in ((None, 0.0), ("a", 0.0), ("tip", 0.3)):
        arm = MujocoArm({"source": str(path), "flange": flange} if flange else path)
        parent = arm.body_names[arm.model.body_parentid[arm.payload_id]]
        assert parent == "a" and arm.model.body_pos[arm.payload_id][0] == pytest.approx(tip)
        # 1 kg at the flange: its gravity torque about the joint is m g x at q = 0 (x along the arm)
        loaded = arm.gravity(np.zeros((1, 1)), [1.0, 0.0, 0.0, 0.0]) - arm.gravity(np.zeros((1, 1)))
        assert float(loaded) == pytest.approx(-9.81 * tip, abs=1e-12)
    assert path.read_text() == text


def test_the_payload_regressor_gives_the_torques_a_payload_adds_and_least_squares_recovers_it(arm):
    """``inverse(payload) - inverse(none) = Y pi`` at random states (moving: every term of Newton-Euler
    matters), and classical least squares on 40 noise-free samples recovers the ten parameters."""
    payload = [*PAYLOAD, 0.004, 0.003, 0.002, 0.0005, -0.0003, 0.0002]
    pi = MujocoArm.inertial_parameters(payload)
    rng = np.random.default_rng(4)
    q, qd, qdd = arm.sample_q(rng, 40), rng.normal(size=(40, 7)), rng.normal(size=(40, 7))
    Y = arm.payload_regressor(q, qd, qdd)
    added = arm.inverse(q, qd, qdd, payload) - arm.inverse(q, qd, qdd)
    torch.testing.assert_close(Y @ pi, added, rtol=0, atol=1e-10)
    estimate = torch.linalg.lstsq(Y.reshape(-1, 10), added.reshape(-1, 1)).solution[:, 0]
    torch.testing.assert_close(estimate, pi, rtol=1e-8, atol=1e-10)
