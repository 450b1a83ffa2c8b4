"""The force residual ``Q_r`` of the structured models (model option ``residual_force``,
``lnn_torch.networks.residual_force``) and the torque shares of a model's residuals
(``lnn_torch.networks.shares``): it starts at exactly zero and leaves the rest of a seeded model as
it was; it enters the forward and inverse dynamics and the power of the model's forces consistently
(the convention ``M qdd + n = B tau + Q_f + Q_r``) and nothing else; its penalty is the one stated;
it learns what the physics cannot; its share of the torque is what switching it off changes."""

import numpy as np
import pytest
import torch

from lnn_torch.networks import build_model
from lnn_torch.networks.shares import torque_shares
from lnn_torch.systems import InputError, get_system

from .conftest import random_batch, random_inputs

ADP = get_system("actuated_double_pendulum")


def _fit(model, system, rng, n=64):
    q, qd, params = random_batch(system, rng, n)
    tau = random_inputs(system, rng, n)
    qdd = system.acceleration(q, qd, params, tau)
    model.fit_normalizer({"q": q, "qd": qd, "qdd": qdd, "params": params, "params_points": params, "tau": tau})
    return q, qd, qdd, params, tau


def _excite(model, seed=0, scale=0.3):
    """Random weights in the residual's output layer (it starts at zero): its weight, then its bias."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.forces.residual.output_layer:
            p.copy_(torch.randn(p.shape, generator=gen, dtype=p.dtype) * scale)


def _train_residual(model, q, qd, qdd, params, extra, steps):
    """Train the residual alone (the physics frozen) on the model's own torques plus ``extra`` with Adam;
    returns the mean square torque error before and after."""
    with torch.no_grad():
        target = model.inverse(q, qd, qdd, params) + extra
    opt = torch.optim.Adam(model.forces.residual.parameters(), lr=1e-2)
    first = None
    for _ in range(steps):
        loss = (model.inverse(q, qd, qdd, params) - target).pow(2).mean()
        first = float(loss.detach()) if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    return first, float(loss.detach())


@pytest.mark.parametrize("variant", ["film_lnn", "delan"])
def test_a_force_residual_starts_at_zero_and_leaves_the_seeded_model_as_it_was(variant, rng):
    torch.manual_seed(0)
    plain = build_model(variant, ADP, hidden_dims=(16, 16)).double()
    torch.manual_seed(0)
    model = build_model(variant, ADP, hidden_dims=(16, 16), residual_force={"hidden": [8]}).double()
    theirs = plain.state_dict()
    for key, value in model.state_dict().items():  # every other weight as without it (built last)
        if ".residual." not in key:
            torch.testing.assert_close(value, theirs[key], rtol=0, atol=0)
    q, qd, qdd, params, tau = _fit(model, ADP, rng)
    _fit(plain, ADP, np.random.default_rng(1234))  # the same statistics
    torch.testing.assert_close(model.acceleration(q, qd, params, tau), plain.acceleration(q, qd, params, tau),
                               rtol=0, atol=0)
    torch.testing.assert_close(model.inverse(q, qd, qdd, params),
                               plain.inverse(q, qd, qdd, params), rtol=0, atol=0)
    assert (model.residual_force(q, qd, params) == 0).all()
    assert model.residual_names() == ("force",) and plain.residual_names() == ()
    # film_lnn modulates it by FiLM of the parameters; delan reads them as inputs
    residual = model.forces.residual
    assert (residual.film is not None) == (variant == "film_lnn")
    assert residual.num_inputs == model.num_features + 2 + (0 if variant == "film_lnn" else ADP.num_params)


def test_the_residual_is_in_the_forward_and_inverse_dynamics_and_nowhere_else(rng):
    torch.manual_seed(1)
    model = build_model("film_lnn", ADP, hidden_dims=(16, 16), residual_force={"hidden": [8, 8]}).double()
    q, qd, qdd, params, _ = _fit(model, ADP, rng)
    _excite(model)
    Q_r = model.residual_force(q, qd, params)
    assert Q_r.abs().min() > 1e-3  # it is there
    with model.residuals_off("force"):
        without = {"input": model.input_force(q, qd, qdd, params), "accel": model.acceleration(q, qd, params,
                   torch.zeros(len(q), 2, dtype=torch.float64)), "bias": model.bias(q, qd, params),
                   "gravity": model.gravity(q, params), "friction": model.friction(q, qd, params),
                   "M": model.mass_matrix(q, params), "residual": model.residual_force(q, qd, params)}
    assert (without["residual"] == 0).all()
    # inverse dynamics: B tau = M qdd + n - Q_f - Q_r
    torch.testing.assert_close(model.input_force(q, qd, qdd, params), without["input"] - Q_r, rtol=0, atol=1e-10)
    # forward dynamics: M (a - a_without) = Q_r
    zero = torch.zeros(len(q), 2, dtype=torch.float64)
    delta = model.acceleration(q, qd, params, zero) - without["accel"]
    torch.testing.assert_close(torch.einsum("bij,bj->bi", without["M"], delta), Q_r, rtol=0, atol=1e-9)
    # the round trip: the inputs of the inverse dynamics give back the accelerations
    tau = model.inverse(q, qd, qdd, params).detach()
    torch.testing.assert_close(model.acceleration(q, qd, params, tau), qdd, rtol=0, atol=1e-9)
    # not in n, g, Q_f or M
    for name, value in (("bias", model.bias(q, qd, params)), ("gravity", model.gravity(q, params)),
                        ("friction", model.friction(q, qd, params)), ("M", model.mass_matrix(q, params))):
        torch.testing.assert_close(value, without[name], rtol=0, atol=0, msg=name)


def test_harmonics_are_the_sin_and_cos_of_multiples_of_the_feature_angles(rng):
    model = build_model("film_lnn", ADP, hidden_dims=(16, 16), residual_force={"harmonics": 4}).double()
    residual = model.forces.residual
    q = torch.as_tensor(rng.uniform(-3, 3, (32, 2)))
    phi = model.features(q)[0]
    angles = q @ model.angle_features.sel_angle.double()  # the feature angles G q
    expected = torch.cat([phi, *[torch.cat([torch.sin(k * angles), torch.cos(k * angles)], -1) for k in (2, 3, 4)]],
                         -1)
    torch.testing.assert_close(residual._harmonics(phi), expected, rtol=0, atol=1e-12)
    assert residual.num_inputs == expected.shape[-1] + 2  # and the two velocities (FiLM takes the parameters)
    with pytest.raises(InputError, match="harmonics must be an integer >= 1"):
        build_model("film_lnn", ADP, residual_force={"harmonics": 0})


def test_the_power_of_the_models_forces_counts_the_residuals_work(rng):
    torch.manual_seed(2)
    model = build_model("film_lnn", ADP, hidden_dims=(16, 16), residual_force={}).double()
    q, qd, qdd, params, tau = _fit(model, ADP, rng)
    _excite(model)
    power = model.training_terms(q, qd, qdd, params, tau, energy=True)["power"]
    with model.residuals_off():
        without = model.training_terms(q, qd, qdd, params, tau, energy=True)["power"]
    q_n, qd_n = model.normalizer.state(q, qd)
    Q_r_norm = model.normalizer.force_to_norm(model.residual_force(q, qd, params))
    torch.testing.assert_close(power - without, (qd_n * Q_r_norm).sum(-1), rtol=0, atol=1e-10)


def test_its_penalty_is_the_weight_times_the_output_layers_squares(rng):
    torch.manual_seed(3)
    model = build_model("film_lnn", ADP, hidden_dims=(16, 16), residual_force={"weight": 0.01}).double()
    assert float(model.regularization().detach()) == 0.0  # zero at the start
    _excite(model)
    out = model.forces.residual.net.out
    expected = 0.01 * (out.weight.pow(2).sum() + out.bias.pow(2).sum())
    torch.testing.assert_close(model.regularization(), expected, rtol=1e-15, atol=0)
    free = build_model("film_lnn", ADP, hidden_dims=(16, 16), residual_force={"weight": 0})
    assert free.regularization() is None


def test_the_residual_learns_what_the_physics_cannot(rng):
    """A model's own inverse dynamics plus a torque its physics cannot write (a sensor offset and a
    cogging-like torque of q1): trained on the torques alone with the physics frozen, the force
    residual takes the torque error's mean square down by 1e3 at least (measured 2e-8 after 300 steps)."""
    torch.manual_seed(4)
    model = build_model("film_lnn", ADP, hidden_dims=(16, 16), residual_force={"hidden": [32, 32]}).double()
    q, qd, qdd, params, _ = _fit(model, ADP, rng, n=256)
    extra = 0.3 + 0.2 * torch.sin(3 * q[:, :1]).expand(-1, 2)
    first, last = _train_residual(model, q, qd, qdd, params, extra, 300)
    assert last < 1e-3 * first


def test_torque_shares_report_what_each_residual_carries(rng):
    pytest.importorskip("mujoco")
    arm = get_system("robot_arm")
    torch.manual_seed(5)
    model = build_model("film_lnn", arm, kinetic={"spatial": {}, "mlp": {}}, potential={"spatial": {}, "mlp": {}},
                        eps=0.0, hidden_dims=(8, 8), residual_force={"hidden": [8]}).double()
    q, qd, params = (torch.as_tensor(x) for x in (*arm.sample_state(rng, 16), arm.sample_params(rng, 16)))
    qdd = torch.as_tensor(rng.uniform(-2, 2, (16, 7)))
    tau = arm.arm.inverse(q, qd, qdd, params)
    model.fit_normalizer({"q": q, "qd": qd, "qdd": qdd, "params": params, "params_points": params, "tau": tau})
    assert model.residual_names() == ("force", "kinetic", "potential")
    start = torque_shares(model, q, qd, qdd, params, tau)
    assert start["residuals"]["force"]["rms"] == [0.0] * 7 and start["residuals"]["potential"]["rms"] == [0.0] * 7
    _excite(model)
    with torch.no_grad():
        model.potential["mlp"].net.out.weight.normal_(0, 0.5)
    shares = torque_shares(model, q, qd, qdd, params, tau)
    rms = model.residual_force(q, qd, params).pow(2).mean(0).sqrt()
    torch.testing.assert_close(torch.tensor(shares["residuals"]["force"]["rms"], dtype=torch.float64), rms,
                               rtol=1e-12, atol=0)
    assert min(shares["residuals"]["potential"]["rms"]) > 0 and min(shares["residuals"]["kinetic"]["rms"]) > 0
    with model.residuals_off():
        physics = model.inverse(q, qd, qdd, params)
    torch.testing.assert_close(torch.tensor(shares["physics_rms"], dtype=torch.float64),
                               physics.pow(2).mean(0).sqrt(), rtol=1e-12, atol=0)
    torch.testing.assert_close(torch.tensor(shares["data_rms"], dtype=torch.float64), tau.pow(2).mean(0).sqrt(),
                               rtol=1e-12, atol=0)
    # the grey box with every residual off is the description at its start: the engine's torques but for
    # the learned friction's small starting Coulomb level (1e-4 of the torque unit: measured 1.6e-3 N m)
    torch.testing.assert_close(physics, tau, rtol=0, atol=5e-3)
    for name, s in shares["residuals"].items():
        assert s["share_mean"] == pytest.approx(np.mean(s["share"])), name


def test_bad_options_are_refused():
    with pytest.raises(InputError, match="takes no option 'width'"):
        build_model("film_lnn", ADP, residual_force={"width": 8})
    with pytest.raises(InputError, match="takes a dict of options"):
        build_model("film_lnn", ADP, residual_force=[8])
    with pytest.raises(InputError, match="needs a scene with generalised forces"):
        build_model("film_lnn", get_system("double_pendulum"), residual_force={})
    with pytest.raises(InputError, match="weight must be a number >= 0"):
        build_model("film_lnn", ADP, residual_force={"weight": -1})
    with pytest.raises(InputError, match="takes no option 'residual_force'"):
        build_model("lnn", ADP, residual_force={})
    with pytest.raises(InputError, match="has no residual 'kinetic'"):
        with build_model("film_lnn", ADP, residual_force={}).residuals_off("kinetic"):
            pass


def test_a_saved_model_with_a_residual_loads_its_units_and_weights(rng):
    torch.manual_seed(6)
    model = build_model("film_lnn", ADP, hidden_dims=(16, 16), residual_force={}).double()
    q, qd, qdd, params, tau = _fit(model, ADP, rng)
    _excite(model)
    assert not torch.allclose(model.forces.residual.unit, torch.ones(2, dtype=torch.float64))
    other = build_model("film_lnn", ADP, hidden_dims=(16, 16), residual_force={}).double()
    other.load_state_dict(model.state_dict())
    torch.testing.assert_close(other.acceleration(q, qd, params, tau), model.acceleration(q, qd, params, tau),
                               rtol=0, atol=0)


def test_a_local_residual_is_a_network_per_joint_of_its_own_angle_velocity_and_the_parameters(rng):
    """``local: true``: ``Q_r,j`` is the ``j``-th network of ``[sin k q_j, cos k q_j (k <= K), qd_j / rms,
    params]`` alone, written out here with plain matrix products per joint; its Jacobians in ``q`` and
    ``qd`` are diagonal; it starts at zero and its penalty is the weight times its output layer's squares."""
    torch.manual_seed(6)
    model = build_model("delan", ADP, hidden_dims=(16, 16),
                        residual_force={"local": True, "harmonics": 3, "hidden": [8, 8], "weight": 0.01}).double()
    q, qd, qdd, params, tau = _fit(model, ADP, rng)
    assert (model.residual_force(q, qd, params) == 0).all() and float(model.regularization().detach()) == 0.0
    _excite(model)
    residual = model.forces.residual
    got = model.residual_force(q, qd, params)
    _, qd_n, p_n = model.normalize(q, qd, params)
    expected = []
    for j in range(2):
        v = qd_n[:, j:j + 1] / residual.velocity_rms[j]
        h = torch.cat([*[f(k * q[:, j:j + 1]) for k in (1, 2, 3) for f in (torch.sin, torch.cos)], v,
                       p_n.expand(len(q), -1)], -1)
        for i, (w, b) in enumerate(zip(residual.net.weights, residual.net.biases, strict=True)):
            h = h @ w[j] + b[j]
            h = torch.tanh(h) if i < len(residual.net.weights) - 1 else h
        expected.append(h[:, 0] * residual.unit[j])
    torch.testing.assert_close(got, torch.stack(expected, -1), rtol=1e-12, atol=1e-14)
    assert got.abs().min() > 0
    w, b = residual.net.out_layer
    torch.testing.assert_close(model.regularization(), 0.01 * (w.pow(2).sum() + b.pow(2).sum()), rtol=1e-15, atol=0)
    for argnum in (0, 1):
        J = torch.func.vmap(torch.func.jacrev(lambda a, b, p: model.residual_force(a[None], b[None], p[None])[0],
                                              argnums=argnum))(q[:8], qd[:8], params[:8])
        off = J * (1 - torch.eye(2, dtype=J.dtype))
        assert (off == 0).all() and J.diagonal(dim1=-2, dim2=-1).abs().min() > 0
    with pytest.raises(InputError, match="local must be true or false"):
        build_model("film_lnn", ADP, residual_force={"local": "yes"})


def test_a_local_residual_learns_a_joints_cogging_offset_and_stribeck_friction(rng):
    """The torque a drive adds to each joint beside the model's physics (an offset, a cogging torque of
    its own angle, a Stribeck breakaway of its own rate): the local residual alone, trained on the
    torques with the physics frozen, takes the error's mean square down by 1e3 at least."""
    torch.manual_seed(7)
    model = build_model("film_lnn", ADP, hidden_dims=(16, 16),
                        residual_force={"local": True, "harmonics": 6, "hidden": [32]}).double()
    q, qd, qdd, params, _ = _fit(model, ADP, rng, n=256)
    extra = (torch.tensor([0.3, -0.2], dtype=torch.float64) + 0.2 * torch.sin(6 * q + 1.0)
             + 0.3 * torch.tanh(qd / 0.1) * torch.exp(-(qd / 0.5) ** 2))
    first, last = _train_residual(model, q, qd, qdd, params, extra, 600)
    assert last < 1e-3 * first
