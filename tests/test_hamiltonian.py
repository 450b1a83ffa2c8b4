"""The Hamiltonian network (``lnn_torch.networks.hamiltonian``): symplectic vector field, canonical and
velocity coordinates, conservation of its own Hamiltonian."""

import pytest
import torch

from lnn_torch.networks import SceneInfo, build_model
from lnn_torch.systems import InputError, get_system

from .conftest import random_batch
from .helpers import perturbed


def _hnn(coordinates, scene="double_pendulum", rng=None):
    system = get_system(scene)
    model = perturbed(build_model("hnn", system, hidden_dims=(16, 16), hnn_coordinates=coordinates).double(), 0.2)
    q, qd, params = random_batch(system, rng, 32)
    model.fit_normalizer({"q": q, "qd": qd, "qdd": system.acceleration(q, qd, params), "params": params,
                          "params_points": params})
    return system, model, (q, qd, params)


@pytest.mark.parametrize("coordinates", ["canonical", "velocity"])
def test_hnn_vector_field_is_the_symplectic_gradient(coordinates, rng):
    system, model, (q, qd, params) = _hnn(coordinates, rng=rng)
    q_n, _, p_n = model.normalize(q, qd, params)
    m_n = model.momentum_norm(q, qd, params).clone().requires_grad_(True)
    q_n = q_n.clone().requires_grad_(True)
    H, _, _ = model.hamiltonian_and_grads(q_n, m_n, p_n)
    dH_dq, dH_dm = torch.autograd.grad(H.sum(), (q_n, m_n))
    qdot, mdot = model.vector_field_norm(q_n, m_n, p_n)
    torch.testing.assert_close(qdot, dH_dm, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(mdot, -dH_dq, rtol=1e-12, atol=1e-12)
    if coordinates == "velocity":  # qdd = -dH/dq at m = qd
        a = model.acceleration(q, qd, params)
        torch.testing.assert_close(model.normalizer.accel_to_norm(a), -dH_dq, rtol=1e-12, atol=1e-12)


def test_hnn_canonical_acceleration_is_the_flows_by_finite_differences(rng):
    """qdd of the canonical HNN = d/dt of its velocity dH/dp along its own flow (central differences)."""
    system, model, (q, qd, params) = _hnn("canonical", rng=rng)
    q, qd, params = q[:4], qd[:4], params[:4]
    a = model.acceleration(q, qd, params)
    h = 1e-4
    _, qds = model.rollout(q, qd, params, h, 2, method="rk8")  # the model's velocity dH/dp at t = 0, h, 2h
    v0, v1, v2 = qds[:, 0], qds[:, 1], qds[:, 2]
    fd = (-3 * v0 + 4 * v1 - v2) / (2 * h)  # second-order one-sided difference, error ~ h^2
    assert (a - fd).abs().max() < 1e-5 * a.abs().max()


def test_hnn_rollout_conserves_its_own_hamiltonian(rng):
    system, model, (q, qd, params) = _hnn("canonical", rng=rng)
    qs, _ = model.rollout(q[:4], qd[:4], params[:4], 0.002, 500, method="rk8")
    # recover the momenta along the flow from the stored q and the integrator state: re-run the flow in (q, m)
    q_n, _, p_n = model.normalize(q[:4], qd[:4], params[:4])
    m_n = model.momentum_norm(q[:4], qd[:4], params[:4])
    from lnn_torch.mechanics.integrators import rollout_first_order

    tau = float(model.normalizer.time_scale)
    y = rollout_first_order(lambda z, p: torch.cat(model.vector_field_norm(z[:, :2], z[:, 2:], p), -1),
                            torch.cat([q_n, m_n], -1), p_n, 0.002 / tau, 500, "rk8")
    H = torch.stack([model.hamiltonian_and_grads(y[:, t, :2], y[:, t, 2:], p_n)[0] for t in range(y.shape[1])], 1)
    assert (H - H[:, :1]).abs().max() < 1e-9 * H.abs().max()
    torch.testing.assert_close(model.normalizer.state_to_phys(y[..., :2], y[..., :2])[0], qs)


def test_canonical_hnn_needs_the_scene_momentum_map():
    info = SceneInfo("double_pendulum", 2, (True, True), 4)
    with pytest.raises(InputError, match="momentum map"):
        build_model("hnn", info)
    build_model("hnn", info, hnn_coordinates="velocity")
