"""Generalised forces (inputs and friction): scenes against independent references, power balance of
the data, learned dissipation that never injects energy, inverse dynamics, refusals."""

import math

import numpy as np
import pytest
import torch

from lnn_torch import rollout
from lnn_torch.data import DatasetSpec, generate_arrays, generate_dataset, read_dataset
from lnn_torch.evaluation.metrics import power_balance_error
from lnn_torch.networks import build_model
from lnn_torch.systems import InputError, get_system
from lnn_torch.systems.excitation import sample as sample_excitation
from lnn_torch.systems.excitation import validate as validate_excitation
from lnn_torch.systems.ground_truth import integrate_ground_truth, power_balance_residual

from .conftest import random_batch, random_inputs
from .helpers import perturbed

ADP = get_system("actuated_double_pendulum")


def point_mass_params(dp_params):
    """Actuated-double-pendulum parameters of a double pendulum's point masses, frictionless."""
    m1, m2, l1, l2 = dp_params.unbind(-1)
    zero = torch.zeros_like(m1)
    return torch.stack([m1, m2, l1, l1, l2, m1 * l1**2, m2 * l2**2, zero, zero, zero, zero], -1)


def fitted(model, system, rng, n=64):
    q, qd, params = random_batch(system, rng, n)
    tau = random_inputs(system, rng, n)
    model.fit_normalizer({"q": q, "qd": qd, "qdd": system.acceleration(q, qd, params, tau), "params": params,
                          "params_points": params, "tau": tau})
    return q, qd, params, tau


# ---------------------------------------------------------------------------- scenes
def test_point_masses_are_the_double_pendulum_in_joint_angles(rng):
    """r = l, I = m l^2, no friction, no inputs: the actuated scene is the double pendulum with
    q2 = theta2 - theta1 (accelerations, energy, positions)."""
    dp = get_system("double_pendulum")
    th, thd, dp_params = random_batch(dp, rng, 128)
    params = point_mass_params(dp_params)
    q = torch.stack([th[:, 0], th[:, 1] - th[:, 0]], -1)
    qd = torch.stack([thd[:, 0], thd[:, 1] - thd[:, 0]], -1)
    zero = torch.zeros(128, 2, dtype=torch.float64)
    a = ADP.acceleration(q, qd, params, zero)
    a_dp = dp.acceleration(th, thd, dp_params)
    torch.testing.assert_close(a, torch.stack([a_dp[:, 0], a_dp[:, 1] - a_dp[:, 0]], -1), rtol=0, atol=1e-10)
    torch.testing.assert_close(ADP.energy(q, qd, params), dp.energy(th, thd, dp_params), rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(ADP.positions(q, params), dp.positions(th, dp_params), rtol=0, atol=1e-12)


def test_damped_double_pendulum_friction_acts_on_the_joint_rates(rng):
    """Joint damping of the absolute-angle double pendulum: the elbow's rate is thetad2 - thetad1, so
    with thetad1 = thetad2 (a rigid swing) only the pivot damps; the power is -sum b r^2."""
    dp = get_system("double_pendulum", joint_damping=(0.3, 0.2))
    q, qd, params = random_batch(dp, rng, 16)
    Q = dp.dissipative_force(q, qd, params)
    rates = torch.stack([qd[:, 0], qd[:, 1] - qd[:, 0]], -1)
    torch.testing.assert_close((qd * Q).sum(-1), -(torch.tensor([0.3, 0.2], dtype=torch.float64) * rates**2).sum(-1))
    rigid = qd[:, :1].expand(-1, 2)
    Q_rigid = dp.dissipative_force(q, rigid, params)
    torch.testing.assert_close(Q_rigid, torch.stack([-0.3 * rigid[:, 0], torch.zeros(16, dtype=torch.float64)], -1))
    assert not get_system("double_pendulum").has_forces  # off by default: the scene is unchanged


def test_friction_only_ever_removes_energy_and_coulomb_saturates():
    rates = torch.linspace(-3, 3, 601, dtype=torch.float64)[:, None].expand(-1, 2)
    params = torch.tensor(ADP.sample_params(np.random.default_rng(0), 1)).expand(601, -1)
    f = ADP.friction_torque(rates, params)
    assert ((rates * f) >= 0).all()  # the dissipated power r . f >= 0
    b, c = ADP.friction_coefficients(params[:1])
    fast = ADP.friction_torque(torch.full((1, 2), 50.0, dtype=torch.float64), params[:1])
    torch.testing.assert_close(fast, 50 * b + c, rtol=1e-12, atol=1e-12)  # tanh(50 / 0.05) = 1


def test_actuation_mask_pendubot_and_acrobot(rng):
    q, qd, params = random_batch(ADP, rng, 8)
    for actuated, column in (((True, False), 0), ((False, True), 1)):
        scene = get_system("actuated_double_pendulum", actuated=actuated)
        assert scene.num_inputs == 1 and scene.input_names == (f"tau{column + 1}",)
        tau = torch.randn(8, 1, dtype=torch.float64)
        full = torch.zeros(8, 2, dtype=torch.float64)
        full[:, column] = tau[:, 0]
        torch.testing.assert_close(scene.acceleration(q, qd, params, tau), ADP.acceleration(q, qd, params, full))


# ---------------------------------------------------------------------------- data
def test_generated_data_satisfies_power_balance_and_matches_dop853():
    """Power balance of the stored data to 1e-10 of the energy scale, and the states against scipy's
    DOP853 on the same equations with the same held inputs (independent integrator)."""
    from scipy.integrate import solve_ivp

    spec = DatasetSpec(scene="actuated_double_pendulum", num_trajectories=3, duration=1.0, seed=2)
    arrays = generate_arrays(spec)
    q, qd, params, work = (torch.from_numpy(arrays[k]) for k in ("q", "qd", "params", "work"))
    residual = power_balance_residual(ADP, q, qd, params, work.sum(-1))
    assert residual.max() <= 1e-10, residual.max()
    assert np.abs(arrays["work"][..., 1]).max() > 1e-3  # friction did work: the check is not trivial
    tau = arrays["tau"]
    assert np.abs(tau).max(axis=(0, 1)).tolist() <= [1.0, 0.5] and np.abs(tau).max() > 0.1
    for i in range(3):
        t_knots = arrays["t"]
        p = torch.from_numpy(arrays["params"][i])

        def f(t, y, k, i=i, p=p):  # this trajectory's inputs and parameters
            yt = torch.from_numpy(y)
            u = torch.from_numpy(tau[i, k])
            return np.concatenate([y[2:], ADP.acceleration(yt[:2], yt[2:], p, u).numpy()])

        y = np.concatenate([arrays["q"][i, 0], arrays["qd"][i, 0]])
        for k in range(20):  # the first 0.1 s, interval by interval (the inputs change at each sample)
            y = solve_ivp(f, (t_knots[k], t_knots[k + 1]), y, method="DOP853", rtol=1e-12, atol=1e-12,
                          args=(k,)).y[:, -1]
        ours = np.concatenate([arrays["q"][i, 20], arrays["qd"][i, 20]])
        assert np.abs(ours - y).max() < 1e-8, np.abs(ours - y).max()


def test_without_forces_the_generator_is_unchanged():
    """joint_damping = 0 is today's double pendulum: identical arrays; and a frictionless, unforced
    actuated scene conserves energy (its power balance is energy conservation)."""
    a = generate_arrays(DatasetSpec(num_trajectories=3, duration=0.5, seed=1))
    b = generate_arrays(DatasetSpec(num_trajectories=3, duration=0.5, seed=1, scene_config={"joint_damping": [0, 0]}))
    assert a.keys() == b.keys() and "tau" not in a and "work" not in a
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    spec = DatasetSpec(scene="actuated_double_pendulum", num_trajectories=3, duration=1.0, seed=1,
                       scene_config={"viscous_range": [0, 1e-12], "coulomb_range": [0, 1e-12]},
                       excitation={"kind": "none"})
    arrays = generate_arrays(spec)
    assert np.abs(arrays["tau"]).max() == 0
    E = arrays["energy"]
    scale = ADP.energy_scale(torch.from_numpy(arrays["params"])).numpy()
    assert (np.abs(E - E[:, :1]).max(1) / scale).max() < 1e-10


def test_inputs_round_trip_through_the_file_and_old_files_read_as_unactuated(tmp_path):
    spec = DatasetSpec(scene="actuated_double_pendulum", num_trajectories=4, duration=0.5, seed=3,
                       excitation={"kind": ["steps", "chirp"], "amplitude": [0.4, 0.2]})
    path = generate_dataset(spec, tmp_path / "a.h5")
    f = read_dataset(path)
    assert f.num_inputs == 2
    data = f.trajectories(None)
    assert data.tau.shape == (4, 101, 2) and data.tau.abs().amax((0, 1)).tolist() <= [0.4, 0.2]
    import json

    inputs = json.loads(f.attrs["inputs"])
    assert inputs["names"] == ["tau1", "tau2"] and "zero-order" in inputs["hold"]
    tolerances = json.loads(f.attrs["tolerances"])
    assert tolerances["check"].startswith("power-balance") and tolerances["max_power_balance_residual_rel"] <= 1e-10
    old = read_dataset(generate_dataset(DatasetSpec(num_trajectories=2, duration=0.2), tmp_path / "old.h5"))
    assert old.num_inputs == 0 and old.trajectories(None).tau is None


def test_excitation_signals_are_seeded_and_limited():
    t = np.arange(2001) * 0.005
    for kind in ("multisine", "steps", "chirp"):
        ex = {"kind": kind, "amplitude": [0.7, 0.2], "band": [0.2, 3.0]}
        a = sample_excitation(ex, np.random.default_rng(4), t, 2)
        b = sample_excitation(ex, np.random.default_rng(4), t, 2)
        np.testing.assert_array_equal(a, b)
        assert (np.abs(a).max(0) <= [0.7, 0.2]).all() and np.abs(a).max() > 0.1, kind
        assert not np.allclose(a, sample_excitation(ex, np.random.default_rng(5), t, 2))
    for bad, message in (({"kind": "square"}, "kind must be one of"), ({"amplitude": [1, 2, 3]}, "one per input"),
                         ({"band": [2.0, 1.0]}, "band"), ({"amplitude": -1.0}, "amplitude")):
        with pytest.raises(InputError, match=message):
            validate_excitation(bad, 2)
    with pytest.raises(InputError, match="has no inputs"):
        DatasetSpec(excitation={"kind": "multisine"})


# ---------------------------------------------------------------------------- models
@pytest.mark.parametrize("variant", ["film_lnn", "delan", "lnn", "hnn"])
@pytest.mark.parametrize("dissipation", ["joint", "joint+rayleigh", "joint+stiction"])
def test_learned_dissipation_never_injects_energy(variant, dissipation, rng):
    """The dissipative force (with static friction: its kinetic part, which fades at rest; the holding
    torque is bounded in tests/test_stiction.py)."""
    if dissipation == "joint+stiction" and variant in ("hnn", "lnn"):
        pytest.skip("static friction needs a positive definite mass matrix (refused for hnn and lnn)")
    model = perturbed(build_model(variant, ADP, hidden_dims=(8, 8), dissipation=dissipation).double(), scale=1.0)
    fitted(model, ADP, rng)
    q, qd, params = random_batch(ADP, rng, 512)
    q_n, qd_n, p_n = model.normalize(q, qd * 3, params)
    phi = model.features(q_n)[0]
    Q = model.forces.dissipative_force(qd * 3, p_n, phi, qd_n)
    power = ((qd * 3) * Q).sum(-1)
    assert (power <= 1e-12).all() and power.min() < -1e-3


def test_conservative_scenes_build_no_forces_and_zero_dissipation_is_the_conservative_model(rng):
    """A model of a conservative scene has no force module (its parameter count is the one of a model
    without forces); a model of the forced scene with its friction coefficients at exactly zero and
    zero inputs accelerates like its own conservative solve, to the bit."""
    for relative_angle, count in ((False, 52_899), (True, 52_899 + 2 * 2 * 128)):
        dp = get_system("double_pendulum", relative_angle=relative_angle)
        model = build_model("film_lnn", dp, hidden_dims=(128, 128))
        assert model.forces is None and not any("forces" in k for k in model.state_dict())
        # the count before forces existed (128 x 128); the relative angle adds two inputs to each network
        assert sum(p.numel() for p in model.parameters()) == count
    forced = perturbed(build_model("film_lnn", ADP, hidden_dims=(16, 16)).double(), scale=0.1)
    fitted(forced, ADP, rng)
    with torch.no_grad():
        forced.forces.coefficient_net[-1].weight.zero_()
        forced.forces.coefficient_net[-1].bias.fill_(-1e4)  # softplus -> exactly 0
    q, qd, params = random_batch(ADP, rng, 32)
    q_n, qd_n, p_n = forced.normalize(q, qd, params)
    zero = torch.zeros(32, 2, dtype=torch.float64)
    assert (forced.force_norm(q_n, qd_n, p_n, zero) == 0).all()
    torch.testing.assert_close(forced.acceleration_norm(q_n, qd_n, p_n, zero), forced.solve_norm(q_n, qd_n, p_n, None),
                               rtol=0, atol=0)


@pytest.mark.parametrize("variant", ["film_lnn", "delan"])
def test_inverse_dynamics_inverts_the_forward_model(variant, rng):
    """tau -> qdd (forward) -> tau (inverse dynamics) round trip, float64; for the pendubot too
    (one input: the least-squares inverse is exact on forces the model itself produced)."""
    for scene in (ADP, get_system("actuated_double_pendulum", actuated=(True, False))):
        model = perturbed(build_model(variant, scene, hidden_dims=(16, 16)).double(), scale=0.1)
        fitted(model, scene, rng)
        q, qd, params = random_batch(scene, rng, 64)
        tau = random_inputs(scene, rng, 64)
        qdd = model.acceleration(q, qd, params, tau)
        torch.testing.assert_close(model.inverse(q, qd, qdd, params), tau, rtol=1e-9, atol=1e-9)


def test_gradcheck_through_the_forced_structured_solve(rng):
    model = perturbed(build_model("film_lnn", ADP, hidden_dims=(4, 4)).double(), scale=0.3)
    fitted(model, ADP, rng)
    q, qd, params = (x[:3] for x in random_batch(ADP, rng, 3))
    q_n, qd_n, p_n = (x.clone().requires_grad_(True) for x in model.normalize(q, qd, params))
    tau_n = torch.randn(3, 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b, u: model.acceleration_norm(a, b, p_n, u), (q_n, qd_n, tau_n))
    names = ("forces.coefficient_net.2.weight", "kinetic.mlp.net.hidden.0.weight")
    weights = tuple(dict(model.named_parameters())[n].detach().clone().requires_grad_(True) for n in names)
    tau = torch.randn(3, 2, dtype=torch.float64)

    def accel(*ws):
        return torch.func.functional_call(model, dict(zip(names, ws, strict=True)), (q, qd, params, tau))

    assert torch.autograd.gradcheck(accel, weights)


@pytest.mark.slow
def test_learned_model_obeys_its_own_power_balance(rng):
    """Along its own rollout (inputs held), a structured model's energy changes by the work of its own
    generalised force: H(t) - H(0) = int qd . Q dt (trapezoid on a fine grid; measured 2e-6 relative)."""
    model = perturbed(build_model("film_lnn", ADP, hidden_dims=(16, 16)).double(), scale=0.1)
    fitted(model, ADP, rng)
    q, qd, params = random_batch(ADP, rng, 4)
    n, dt = 400, 0.0005
    tau = torch.tensor(rng.uniform(-0.5, 0.5, (4, 1, 2))).expand(-1, n, -1)
    qs, qds = model.rollout(q, qd, params, dt, n, "rk8", tau=tau)
    flat = lambda x: x.reshape(-1, 2)  # noqa: E731
    pp = params[:, None].expand(-1, n + 1, -1).reshape(-1, params.shape[-1])
    q_n, qd_n, p_n = model.normalize(flat(qs), flat(qds), pp)
    tau_n = model.tau_norm(torch.cat([tau, tau[:, -1:]], 1).reshape(-1, 2))
    with torch.no_grad():
        H = model.energy_norm(q_n, qd_n, p_n)[0].reshape(4, n + 1)
        power = (qd_n * model.force_norm(q_n, qd_n, p_n, tau_n)).sum(-1).reshape(4, n + 1)
    dt_n = dt / float(model.normalizer.time_scale)
    steps = (0.5 * dt_n * (power[:, 1:] + power[:, :-1])).cumsum(1)
    work = torch.cat([torch.zeros(4, 1, dtype=torch.float64), steps], 1)
    residual = (H - H[:, :1] - work).abs().max() / (H.max() - H.min())
    assert residual < 1e-4, residual


# ---------------------------------------------------------------------------- refusals
def test_bad_inputs_are_refused_clearly(rng):
    q, qd, params = random_batch(ADP, rng, 4)
    tau = random_inputs(ADP, rng, 4)
    dp = get_system("double_pendulum")
    q2, qd2, p2 = random_batch(dp, rng, 4)
    model = build_model("film_lnn", ADP, hidden_dims=(8, 8)).double()
    fitted(model, ADP, rng)
    for fn in (ADP.acceleration, model.acceleration):
        with pytest.raises(InputError, match=r"actuated \(2 inputs\): tau of shape \(4, 2\) is missing"):
            fn(q, qd, params)
        with pytest.raises(InputError, match=r"tau must have shape \(4, 2\), got \(4, 3\)"):
            fn(q, qd, params, torch.zeros(4, 3, dtype=torch.float64))
    with pytest.raises(InputError, match="tau given, but .* not actuated"):
        dp.acceleration(q2, qd2, p2, tau)
    with pytest.raises(InputError, match="tau given, but the system has no inputs"):
        build_model("film_lnn", dp, hidden_dims=(8,)).double().acceleration(q2, qd2, p2, tau)
    with pytest.raises(InputError, match=r"tau must have shape \(4, 5, 2\) \(batch, num_steps, inputs: each held over "
                                         r"its step\) for scene '.*', got \(4, 4, 2\)$"):
        model.rollout(q, qd, params, 0.01, 5, tau=tau[:, None].expand(-1, 4, -1))  # one step short
    from lnn_torch.training import LNNModule

    module = LNNModule(scene="actuated_double_pendulum", variant="film_lnn", hidden_dims=[8, 8])
    for roll in (model.rollout, module.rollout):  # the network, and the Lightning module load_model gives
        for given, shown in ((tau, r"got \(4, 2\)"), (None, "got none")):  # one step's inputs; none at all
            with pytest.raises(InputError, match=rf"tau must have shape \(4, 5, 2\) .*, {shown}$"):
                roll(q, qd, params, 0.01, 5, tau=given)
    bad = params.clone()
    bad[1, 8] = -0.01  # negative viscous friction b2
    with pytest.raises(InputError, match=r"friction coefficients must be >= 0; negative values in \['b2'\]"):
        ADP.check_params(bad)
    with pytest.raises(InputError, match="friction coefficients must be >= 0"):
        model.acceleration(q, qd, bad, tau)
    with pytest.raises(InputError, match="joint_damping must be two coefficients >= 0"):
        get_system("double_pendulum", joint_damping=(0.1, -0.2))
    with pytest.raises(InputError, match="NaN"):
        model.acceleration(q, qd, params, tau * float("nan"))


@pytest.mark.slow
def test_power_balance_error_of_the_exact_rollout_is_small_and_of_a_wrong_model_large(rng):
    spec = DatasetSpec(scene="actuated_double_pendulum", num_trajectories=4, duration=2.0, seed=6)
    arrays = generate_arrays(spec)
    q, qd, params, tau = (torch.from_numpy(arrays[k]) for k in ("q", "qd", "params", "tau"))
    err = power_balance_error(ADP, q, qd, params, tau[:, :-1], spec.dt)
    # the floor of the metric: the trapezoid of the dissipated power at dt = 5 ms (measured 4.5e-5;
    # the smoothed Coulomb term turns quickly at zero velocity)
    assert err.max() < 2e-4, err.max()
    # a rollout without friction, driven by the same inputs, violates the true power balance
    frictionless = params.clone()
    frictionless[:, 7:] = 0
    qf, qdf = rollout(ADP.acceleration, q[:, 0], qd[:, 0], frictionless, spec.dt, q.shape[1] - 1, "rk4",
                      tau=tau[:, :-1])
    assert power_balance_error(ADP, qf, qdf, params, tau[:, :-1], spec.dt).max() > 100 * err.max()
    with pytest.raises(ValueError, match="tau"):
        integrate_ground_truth(ADP, q[:, 0], qd[:, 0], params, 0.005, 10, tau=tau[:, :5])
    assert math.isfinite(float(err.mean()))


# ---------------------------------------------------------------------------- use: train, evaluate, simulate
@pytest.fixture(scope="module")
def actuated_checkpoint(tmp_path_factory):
    """A small film_lnn trained a few steps on a small actuated dataset (torque loss on), saved."""
    import lightning as L

    from lnn_torch import LNNModule, TrajectoryDataModule

    root = tmp_path_factory.mktemp("adp")
    spec = dict(scene="actuated_double_pendulum", num_trajectories=12, duration=1.0, seed=3)
    dm = TrajectoryDataModule(path=str(root / "d.h5"), spec=spec, chunk_len=8, chunks_per_batch=8, steps_per_epoch=20,
                              eval_stride=5)
    model = LNNModule(scene="actuated_double_pendulum", hidden_dims=[16, 16], val_rollouts=2, val_rollout_seconds=0.5,
                      torque_weight=0.1, energy_weight=0.01)
    trainer = L.Trainer(max_epochs=1, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                        enable_model_summary=False, inference_mode=False, num_sanity_val_steps=0)
    trainer.fit(model, dm)
    metrics = trainer.validate(model, dm, verbose=False)[0]
    path = root / "model.ckpt"
    trainer.save_checkpoint(path)
    return path, root / "d.h5", metrics, model


def test_training_with_inputs_logs_power_balance_and_the_torque_term(actuated_checkpoint):
    _, _, metrics, model = actuated_checkpoint
    assert {"val/acc_rel_err", "val/power_balance", "val/divergence_time"} <= set(metrics)
    assert "val/energy_drift" not in metrics
    assert all(math.isfinite(v) for v in metrics.values())
    assert model.model.forces is not None and model.data_dt == pytest.approx(0.005)
    with pytest.raises(ValueError, match=r"torque_weight 0.1 \(needs inverse dynamics"):
        type(model)(scene="actuated_double_pendulum", variant="mlp", torque_weight=0.1, hidden_dims=[8])
    # data without torques (a bag imported without its efforts): said so, not "film_lnn needs film_lnn"
    with pytest.raises(ValueError, match=r"^variant 'film_lnn' cannot use: torque_weight 1 \(fits measured torques, "
                                         r"and scene 'double_pendulum' has no inputs: .*set torque_weight 0\)$"):
        type(model)(scene="double_pendulum", variant="film_lnn", torque_weight=1.0, hidden_dims=[8])


def test_evaluate_reports_the_forced_sections(actuated_checkpoint, tmp_path):
    import json

    from lnn_torch.cli import main

    ckpt, data, _, _ = actuated_checkpoint
    out = tmp_path / "eval"
    assert main(["evaluate", str(ckpt), "--data", str(data), "--split", "train", "--horizon", "0.5", "--threads", "1",
                 "--stability-seconds", "0.2", "--long-horizon-steps", "0", "-o", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("acc_rel_err", "power_balance_error", "torque_nrmse", "friction", "free_decay", "ood", "stability"):
        assert key in metrics, key
    assert "energy_drift" not in metrics and set(metrics["torque_nrmse"]) == {"mean", "tau1", "tau2"}
    report = (out / "report.md").read_text()
    assert "power-balance error" in report and "inverse-dynamics torque error" in report
    for png in ("friction.png", "free_decay.png", "power_balance.png"):
        assert (out / png).stat().st_size > 1000, png


def test_simulate_with_inputs_from_a_file_or_an_excitation(actuated_checkpoint, tmp_path, capsys):
    from lnn_torch.cli import main

    ckpt = actuated_checkpoint[0]
    params = [str(x) for x in ADP.sample_params(np.random.default_rng(0), 1)[0]]
    base = ["simulate", "--checkpoint", str(ckpt), "--params", *params, "--q0", "0.3", "-0.2", "--duration", "0.5",
            "--dt", "0.01"]
    assert main(base + ["--excitation", '{"kind": "multisine", "amplitude": [0.5, 0.2]}', "-o",
                        str(tmp_path / "a.csv")]) == 0
    assert "power-balance error" in capsys.readouterr().out
    header = [line for line in (tmp_path / "a.csv").read_text().splitlines() if not line.startswith("#")][0]
    assert "tau1" in header and "tau2" in header
    inputs = tmp_path / "u.csv"
    inputs.write_text("t,tau1,tau2\n0.0,0.1,0.0\n0.25,-0.1,0.05\n0.5,0.0,0.0\n")
    assert main(base + ["--inputs", str(inputs), "-o", str(tmp_path / "b.csv")]) == 0
    rows = [line for line in (tmp_path / "b.csv").read_text().splitlines() if not line.startswith("#")]
    data = np.loadtxt(rows[1:], delimiter=",")  # after the header row
    cols = header.split(",")
    tau1 = data[:, cols.index("tau1")]
    assert tau1[0] == pytest.approx(0.1) and tau1[30] == pytest.approx(-0.1)  # held from each row's time
    assert main(base + ["-o", str(tmp_path / "c.csv")]) == 2
    assert "is actuated (tau1, tau2): pass --inputs CSV or --excitation JSON" in capsys.readouterr().err
    inputs.write_text("t,tau1\n0.0,0.1\n")
    assert main(base + ["--inputs", str(inputs), "-o", str(tmp_path / "d.csv")]) == 2
    assert "missing input column(s) tau2" in capsys.readouterr().err
    inputs.write_text("t,tau1,tau2\n0.0,0.1,0.0\n0.3,oops,0\n0.6,0,0\n")
    assert main(base + ["--inputs", str(inputs), "-o", str(tmp_path / "e.csv")]) == 2
    assert "row 3 is malformed" in capsys.readouterr().err
    # a file on its own grid whose last row's interval covers the last step (0.49 s here): held there
    inputs.write_text("t,tau1,tau2\n" + "".join(f"{0.02 * k:.2f},0.1,0\n" for k in range(25)))  # to 0.48 s
    assert main(base + ["--inputs", str(inputs), "-o", str(tmp_path / "f.csv")]) == 0
    inputs.write_text("t,tau1,tau2\n" + "".join(f"{0.02 * k:.2f},0.1,0\n" for k in range(24)))  # to 0.46 s: short
    assert main(base + ["--inputs", str(inputs), "-o", str(tmp_path / "g.csv")]) == 2
    assert "t covers [0, 0.46] s (its last row held to 0.48 s), the simulation's steps start in [0, 0.49] s" in (
        capsys.readouterr().err)
    # a time column in ms: its first row was held over the whole simulation without a word
    inputs.write_text("t,tau1,tau2\n" + "".join(f"{20 * k},0.1,0\n" for k in range(26)))  # 0..500 ms
    assert main(base + ["--inputs", str(inputs), "-o", str(tmp_path / "h.csv")]) == 2
    assert "column t runs over 500 s in steps of 20, the simulation over 0.49 s in steps of 0.01: t is in seconds " \
           "(a column in ms?)" in capsys.readouterr().err
    # the comment names the columns the file has
    text = (tmp_path / "f.csv").read_text().splitlines()
    described = [line for line in text if line.startswith("# columns:")][0]
    columns = [line for line in text if not line.startswith("#")][0].split(",")
    assert "tau1, tau2: the inputs held over each step" in described
    for named, column in (("*_exact", "q1_exact"), ("energy_drift:", "energy_drift")):
        assert (named in described) == (column in columns), (named, columns)


def test_combined_angle_features_tangents_and_pullback_match_autograd(rng):
    """The actuated scene's models also read sin/cos of q1 + q2 (the scene's angle combination): the
    hand-carried feature tangents and the reverse pass equal autograd's (float64)."""
    model = build_model("film_lnn", ADP, hidden_dims=(8, 8)).double()
    assert model.num_features == 6
    q = torch.tensor(rng.uniform(-3, 3, (5, 2)), requires_grad=True)
    phi, dphi = model.features(q, tangents=True)
    absolute = q[:, 0] + q[:, 1]
    torch.testing.assert_close(phi[:, [2, 5]], torch.stack([torch.sin(absolute), torch.cos(absolute)], -1))
    jac = torch.func.vmap(torch.func.jacrev(lambda x: model.features(x[None])[0][0]))(q.detach())  # (B, F, dof)
    torch.testing.assert_close(dphi.permute(1, 2, 0), jac, rtol=1e-12, atol=1e-12)
    g = torch.randn(5, 6, dtype=torch.float64)
    (auto,) = torch.autograd.grad((phi * g).sum(), q)
    torch.testing.assert_close(model.features_vjp(q.detach(), g), auto, rtol=1e-12, atol=1e-12)


def test_stiff_friction_slopes_are_bounded_and_training_through_them_keeps_finite_gradients(rng):
    """A Coulomb step 50 times sharper than the default (``v_c`` = 1 ms^-1 rad: ``tanh(1000 qd)``) and a
    sigmoid whose raw slope starts far beyond any data (softplus(1e4) / v_c): the slope is bounded
    (``SLOPE_LIMIT / v_c``), and 40 Adam steps of the acceleration loss through it keep every gradient
    and parameter finite."""
    from lnn_torch.mechanics.friction import SLOPE_LIMIT
    from lnn_torch.training.losses import acceleration_loss

    system = get_system("actuated_double_pendulum", coulomb_velocity=1e-3)
    model = build_model("film_lnn", system, friction="viscous+coulomb+sigmoid").double()
    q, qd, params, tau = fitted(model, system, rng, 128)
    qd = qd * torch.where(torch.rand_like(qd) < 0.5, 1e-3, 1.0)  # half the rates inside the steps
    qdd = system.acceleration(q, qd, params, tau)
    forces = model.forces
    with torch.no_grad():
        forces.coefficient_net[-1].bias[2 * forces.num_joints + forces.num_joints:][:forces.num_joints] = 1e4
    coefficients = forces.drive_coefficients(model.normalizer.params(params))
    assert float(coefficients["phi2"].max()) <= SLOPE_LIMIT / 1e-3 * (1 + 1e-12)
    assert float(coefficients["phi2"].max()) > 0.99 * SLOPE_LIMIT / 1e-3
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    for _ in range(40):
        optimizer.zero_grad()
        loss = acceleration_loss(model.acceleration(q, qd, params, tau, check=False), qdd, 1.0)
        loss.backward()
        assert torch.isfinite(loss)
        assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)
        optimizer.step()
    assert all(torch.isfinite(p).all() for p in model.parameters())


def test_learned_saturating_friction_starts_where_told_and_never_injects_energy(rng):
    """A learned drive with saturating friction (``d``, the Coulomb level's move over ``v_d``): started at a
    falling level (``d < 0``, down to its floor ``-k c``) it returns those coefficients, and at any weights of its
    coefficient network (raw values from -8 to 8) the joint friction only takes energy out."""
    system = get_system("actuated_double_pendulum")
    model = build_model("film_lnn", system, friction="viscous+coulomb+saturating").double()
    q, qd, params, _ = fitted(model, system, rng, 256)
    forces, n = model.forces, model.forces.num_joints
    c = torch.tensor([0.3, 0.2], dtype=torch.float64)[:n]
    k = forces.drive.saturation_floor()
    start = {"b": torch.full((n,), 0.05, dtype=torch.float64), "c": c, "d": -0.999 * k * c}
    forces.start_with(start)
    p_n = model.normalizer.params(params)
    got = forces.drive_coefficients(p_n)
    for name, value in start.items():
        torch.testing.assert_close(got[name], value.expand_as(got[name]), rtol=1e-9, atol=1e-12)
    with torch.no_grad():
        for _ in range(5):
            forces.coefficient_net[-1].bias.uniform_(-8.0, 8.0)
            forces.coefficient_net[-1].weight.normal_(0.0, 1.0)
            rates = qd * torch.where(torch.rand_like(qd) < 0.5, 0.01, 3.0)
            power = (rates * forces.friction_torque(rates, p_n)).sum(-1)
            assert (power >= -1e-12).all()


def test_predict_on_an_actuated_scene_uses_the_recorded_inputs(tmp_path):
    """``predict`` (the Lightning command's per-point accelerations) under each point's recorded torques, which it
    left out (a 587 % error on the shipped arm's own data), with the inputs and the points' mask in its output."""
    import lightning as L

    from lnn_torch.networks.calls import model_accelerations
    from lnn_torch.training import LNNModule, TrajectoryDataModule

    path = generate_dataset(DatasetSpec(scene="actuated_double_pendulum", num_trajectories=4, duration=0.5, seed=3,
                                        split=[0.5, 0.0, 0.5]), tmp_path / "a.h5")
    module = LNNModule(scene="actuated_double_pendulum", hidden_dims=[8], torque_weight=1.0)
    dm = TrajectoryDataModule(path=str(path), eval_stride=5)
    module.model.fit_normalizer(dm.normalization_data())
    (out,) = L.Trainer(logger=False, enable_progress_bar=False, enable_model_summary=False,
                       inference_mode=False).predict(module, datamodule=dm)
    assert out["tau"].shape[:2] == out["q"].shape[:2] and out["valid"].all()
    with_inputs = model_accelerations(module.model, out["q"], out["qd"], out["params"], out["tau"])
    without = model_accelerations(module.model, out["q"], out["qd"], out["params"])
    torch.testing.assert_close(out["qdd_pred"], with_inputs, rtol=0, atol=0)
    assert (out["qdd_pred"] - without).abs().max() > 1e-3
