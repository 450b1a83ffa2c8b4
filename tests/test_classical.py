"""Classical identification of an arm beside every model (``lnn_torch.identification.classical_arm``,
``lnn_torch.identification.arm_comparison``), against the engine: torques of the Panda without its hand (armature
and damping zero, as the real robot was logged) plus a known drive model per joint. Least squares
(ordinary and weighted) recovers the torques and the friction coefficients exactly from noise-free data;
the physically consistent fit explains them with positive masses; the sigmoid friction's nonlinear
constants come back by variable projection; an identified model's forward dynamics is the engine's; and
the open-loop time of a model driven by the recorded torques is the horizon for the truth and short for
a wrong model."""

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco")

from lnn_torch.identification import arm_comparison as ai  # noqa: E402
from lnn_torch.identification import classical_arm as classical  # noqa: E402
from lnn_torch.mechanics.friction import DriveModel  # noqa: E402
from lnn_torch.mechanics.integrators import held, rk4_step  # noqa: E402
from lnn_torch.robots.kinematics import read_chain  # noqa: E402
from lnn_torch.robots.mujoco_arm import MujocoArm  # noqa: E402

ROBOT = {"source": "franka_panda", "remove": ["hand"], "armature": "zero", "damping": "zero"}
FRICTION = {"b": torch.linspace(0.05, 0.3, 7, dtype=torch.float64),
            "c": torch.linspace(0.6, 0.1, 7, dtype=torch.float64),
            "o": torch.tensor([0.1, -0.2, 0.05, 0.3, -0.05, 0.02, 0.01], dtype=torch.float64)}
DRIVE = "viscous+coulomb+offset"


@pytest.fixture(scope="module")
def arm():
    arm = MujocoArm(ROBOT)
    return arm, read_chain(arm.model)


def samples(arm, n: int, seed: int, drive=DRIVE, coefficients=None):
    rng = np.random.default_rng(seed)
    q = torch.tensor(arm.sample_q(rng, n))
    qd, qdd = (torch.tensor(rng.normal(size=(n, 7))) for _ in range(2))
    tau = arm.inverse(q, qd, qdd) + DriveModel.of(drive).torque(qd, coefficients or FRICTION)
    return q, qd, qdd, tau


@pytest.mark.parametrize("weighted", [False, True])
def test_least_squares_with_friction_gives_the_torques_and_the_coefficients(arm, weighted):
    arm, chain = arm
    fit = classical.least_squares(chain, *samples(arm, 300, 0), drive=DRIVE, weighted=weighted)
    q, qd, qdd, tau = samples(arm, 50, 1)  # held out
    assert (fit.inverse(q, qd, qdd) - tau).abs().max() <= 1e-7 * tau.abs().max()
    for key in ("c", "o"):  # viscous friction is in the regressor's damping column (with the armature)
        np.testing.assert_allclose(fit.friction_coefficients[key], FRICTION[key].numpy(), rtol=1e-6, atol=1e-8)
    # ... each joint's a base parameter of its own, reported as the viscous coefficient (it read NaN: the base map's
    # round-off counted as a share of other parameters)
    np.testing.assert_allclose(fit.friction_coefficients["b"], FRICTION["b"].numpy(), rtol=1e-6, atol=1e-8)
    assert fit.report()["base_parameters"] < 84


def test_saturating_friction_is_fitted_by_least_squares_and_never_puts_energy_in(arm):
    """Friction whose Coulomb level moves by d over v_d (``saturating``: d tanh(v / v_d)) beside the drive model's
    terms: least squares gives the torques and its coefficients back exactly; for d >= -k c the law only takes
    energy out (f(v) v >= 0 at any rate, offset aside), below it not; the drive model with other forms keeps its
    velocities."""
    arm, chain = arm
    drive = DriveModel.of(DRIVE + "+saturating", saturation_velocity=0.3)
    coefficients = {**FRICTION, "d": torch.linspace(1.0, 0.2, 7, dtype=torch.float64)}
    fit = classical.least_squares(chain, *samples(arm, 300, 0, drive, coefficients), drive=drive)
    q, qd, qdd, tau = samples(arm, 50, 1, drive, coefficients)
    assert (fit.inverse(q, qd, qdd) - tau).abs().max() <= 1e-7 * tau.abs().max()
    np.testing.assert_allclose(fit.friction_coefficients["d"], coefficients["d"].numpy(), rtol=1e-6)
    plain = classical.least_squares(chain, *samples(arm, 300, 0, drive, coefficients), drive=DRIVE)
    assert (plain.inverse(q, qd, qdd) - tau).abs().max() > 1e-3 * tau.abs().max()  # without the term it cannot
    v = torch.linspace(-3, 3, 6001, dtype=torch.float64)[:, None].expand(-1, 7)
    passive = drive.with_forms("viscous+coulomb+saturating")
    assert passive.saturation_velocity == 0.3 and passive.passive
    assert (passive.torque(v, coefficients) * v >= 0).all()
    # falling too (a breakaway): down to d = -k c, k = min(1, v_d / v_c), the law still takes energy out; below, not
    for v_d in (0.005, 0.3):
        law = DriveModel.of("coulomb+saturating", coulomb_velocity=0.02, saturation_velocity=v_d)
        k = law.saturation_floor()
        assert k == min(1.0, v_d / 0.02)
        floor = {"c": coefficients["c"], "d": -k * coefficients["c"]}
        assert (law.torque(v, floor) * v >= -1e-15).all()
        assert (law.torque(v, {"c": coefficients["c"], "d": -1.2 * k * coefficients["c"]}) * v < 0).any()


@pytest.mark.slow
def test_the_consistent_fit_explains_the_torques_with_a_physical_arm(arm):
    arm, chain = arm
    data = samples(arm, 60, 2)
    fit = classical.consistent_fit(chain, *data, drive=DRIVE, prior=1e-6)
    assert fit.info["converged"], fit.info  # a stationary point (to round-off)
    assert not classical.consistent_fit(chain, *data, drive=DRIVE, prior=1e-6, max_iterations=2).info["converged"]
    q, qd, qdd, tau = samples(arm, 50, 3)
    error = (fit.inverse(q, qd, qdd) - tau).pow(2).mean().sqrt() / tau.std()
    assert error < 1e-2, float(error)
    report = fit.report()
    assert min(report["mass"]) > 0 and min(report["armature"]) >= 0
    coefficients = fit.friction_coefficients
    assert (torch.as_tensor(coefficients["b"]) >= 0).all() and (torch.as_tensor(coefficients["c"]) >= 0).all()
    # every physical parameter has an interval; those the data cannot determine are named (the first link
    # turns about the vertical: its inertia about other axes moves no torque; its Izz only with its rotor's)
    u = fit.info["uncertainty"]
    std = np.array(u["std"])
    assert np.isfinite(std).all() and (std > 0).all()
    assert {"joint1.Ixx", "joint1.Izz", "joint1.armature"} <= set(u["held_by_prior"])
    # a parameter that is a base parameter on its own (no other in its combination, in no other's) is not
    from lnn_torch.robots.regressor import base_parameters, parameter_names, regressor

    base = base_parameters(regressor(chain, *data[:3]).reshape(-1, 84))
    K = np.abs(base["K"]) > 1e-9
    alone = [parameter_names(chain)[j] for k, j in enumerate(base["independent"]) if not K[k].any()]
    assert len(alone) >= 5 and not set(alone) & set(u["held_by_prior"]), alone


def test_the_sigmoid_frictions_constants_come_back_by_variable_projection(arm):
    arm, chain = arm
    truth = {"phi1": torch.full((7,), 0.4, dtype=torch.float64), "phi2": torch.full((7,), 20.0, dtype=torch.float64),
             "phi3": torch.full((7,), 0.05, dtype=torch.float64)}
    fit = classical.least_squares(chain, *samples(arm, 300, 4, "sigmoid", truth), drive="sigmoid")
    for key, value in truth.items():
        np.testing.assert_allclose(fit.friction_coefficients[key], value.numpy(), rtol=1e-3)


def test_an_identified_models_forward_dynamics_is_the_engines(arm):
    arm, chain = arm
    q, qd, qdd, tau = samples(arm, 20, 5, "viscous", {"b": torch.zeros(7, dtype=torch.float64)})
    description = classical.ArmModel(chain, DriveModel.of("viscous"), "description", {"b": np.zeros(7)},
                                     pi=classical.description_parameters(chain).numpy())
    torch.testing.assert_close(description.forward(q, qd, tau), qdd, rtol=1e-9, atol=1e-9)
    fit = classical.least_squares(chain, *samples(arm, 300, 0), drive=DRIVE)
    q, qd, qdd, tau = samples(arm, 20, 6)
    torch.testing.assert_close(fit.forward(q, qd, tau), qdd, rtol=1e-6, atol=1e-6)


def test_open_loop_time_is_the_horizon_for_the_truth_and_short_for_a_wrong_model(arm):
    """A recording of the engine's arm driven by smooth torques; ``open_loop`` of the description
    (the truth) stays within 0.1 rad for the whole horizon from every start; the description with
    every link 20 % heavier leaves early."""
    arm, chain = arm
    dt, steps = 0.004, 100
    t = torch.arange(steps + 1, dtype=torch.float64)[:, None] * dt
    q0 = torch.tensor(arm.sample_q(np.random.default_rng(7), 1))
    q, qd = [q0], [torch.zeros(1, 7, dtype=torch.float64)]
    g = arm.inverse(q0, qd[0], torch.zeros(1, 7, dtype=torch.float64))
    tau = g + 0.5 * torch.sin(3.0 * t + torch.arange(7))[None]  # (1, steps + 1, 7)
    for k in range(steps):  # RK4 of the engine with the torque held, as open_loop integrates
        x, v = rk4_step(held(lambda x, v, p, u: arm.forward(x, v, u), tau[:, k]), q[-1], qd[-1], None, dt)
        q.append(x)
        qd.append(v)

    data = _Recording(dt=dt, num_points=steps + 1, lengths=None, q=torch.stack(q, 1), qd=torch.stack(qd, 1),
                      tau=tau, params=torch.zeros(1, 0, dtype=torch.float64))
    pi = classical.description_parameters(chain).numpy()
    truth = classical.ArmModel(chain, DriveModel.of("viscous"), "description", {"b": np.zeros(7)}, pi=pi)
    out = ai.open_loop(lambda q, qd, u, p: truth.forward(q, qd, u), data, every=0.05, limit=0.2)
    assert out["starts"] == 5 and out["quartiles"] == pytest.approx([0.2] * 3)
    heavy = classical.ArmModel(chain, DriveModel.of("viscous"), "description", {"b": np.zeros(7)}, pi=1.2 * pi)
    wrong = ai.open_loop(lambda q, qd, u, p: heavy.forward(q, qd, u), data, every=0.05, limit=0.2)
    assert wrong["quartiles"][1] < 0.2


class _Recording:
    """The fields of ``Trajectories`` that ``open_loop`` reads."""

    def __init__(self, **fields):
        vars(self).update(fields)

    def __len__(self) -> int:
        return len(self.q)


def test_a_known_payload_per_recording_is_taken_off_before_the_fit_and_put_back_after(arm):
    """Recordings that carry different known payloads (``parameters`` of an import): the payload's torque
    (``regressor.payload_torque``) is the engine's, least squares on the arm's own torques (the payload's
    taken off) recovers every recording's torques with its payload, and the forward dynamics with it are
    the engine's."""
    from lnn_torch.robots.regressor import payload_torque

    arm, chain = arm
    rng = np.random.default_rng(7)
    q, qd, qdd, _ = samples(arm, 300, 4)
    payload = torch.tensor(np.c_[rng.uniform(0, 3, 300), rng.uniform(-0.05, 0.05, (300, 2)), rng.uniform(0, 0.1, 300)])
    tau = arm.inverse(q, qd, qdd, payload) + DriveModel.of(DRIVE).torque(qd, FRICTION)
    added = payload_torque(chain, q, qd, qdd, payload)
    torch.testing.assert_close(added, arm.inverse(q, qd, qdd, payload) - arm.inverse(q, qd, qdd), rtol=0,
                               atol=1e-9 * float(tau.abs().max()))
    fit = classical.least_squares(chain, q[:250], qd[:250], qdd[:250], (tau - added)[:250], drive=DRIVE)
    held_out = slice(250, 300)
    assert (fit.inverse(q[held_out], qd[held_out], qdd[held_out], payload[held_out]) - tau[held_out]).abs().max() \
        <= 1e-7 * tau.abs().max()
    assert (fit.inverse(q[held_out], qd[held_out], qdd[held_out]) - tau[held_out]).abs().max() > 0.1  # it matters
    tau_h = tau[held_out]
    qdd_fit = fit.forward(q[held_out], qd[held_out], tau_h, payload[held_out])
    torch.testing.assert_close(qdd_fit, qdd[held_out], rtol=1e-6, atol=1e-6)


# ---------------------------------------------------------------------------- uncertainty and identifiability
def test_the_95_percent_intervals_of_least_squares_cover_the_truth_95_percent_of_the_time(arm):
    """Torques with white noise of a different size per joint: over five seeds the intervals of every
    base parameter and friction coefficient hold the true value 90-99 % of the time (measured: 0.97 of
    345); intervals of half the width would hold it about 0.68."""
    from lnn_torch.robots.regressor import parameter_vector

    arm, chain = arm
    sigma = torch.linspace(0.05, 0.5, 7, dtype=torch.float64)
    pi = parameter_vector(chain.J, torch.zeros(7, dtype=torch.float64), FRICTION["b"]).numpy()
    inside, narrow = [], []
    for seed in range(5):
        q, qd, qdd, tau = samples(arm, 300, 10 + seed)
        noise = sigma * torch.tensor(np.random.default_rng(seed).normal(size=tau.shape))
        fit = classical.least_squares(chain, q, qd, qdd, tau + noise, drive=DRIVE)
        u = fit.info["uncertainty"]
        truth = np.concatenate([fit.base["map"] @ pi, torch.stack([FRICTION["c"], FRICTION["o"]], 1).reshape(-1)])
        z = np.abs(np.array(u["value"]) - truth) / np.array(u["std"])
        inside.append(z < classical.Z95)
        narrow.append(z < classical.Z95 / 2)
        lo, hi = np.array(u["interval95"]).T
        assert np.allclose(hi - lo, 2 * classical.Z95 * np.array(u["std"]))
    assert 0.90 <= np.concatenate(inside).mean() <= 0.99
    assert np.concatenate(narrow).mean() < 0.8


def test_the_excitation_check_warns_and_the_undetermined_parameters_are_named(arm):
    from lnn_torch import UntrustedParameterWarning

    arm, chain = arm
    fit = classical.least_squares(chain, *samples(arm, 300, 0), drive=DRIVE)
    u = fit.info["uncertainty"]
    assert u["condition_number"] < classical.COND_WARN
    # the first link turns about the vertical: its inertia about other axes moves no torque
    assert "joint1.Ixx" in u["undetermined"] and "joint1.Izz" not in u["undetermined"]
    # no motion of the arm moves those: no recording can determine them (the report says so)
    assert set(u["never_moving"]) == set(u["undetermined"]) and "joint1.Ixx" in u["never_moving"]
    from lnn_torch.identification.arm_comparison import uncertainty_markdown

    assert "no motion of this arm moves any of them" in uncertainty_markdown(u)
    # a recording where the last joint never turns: its link's inertia about its axis moves no torque there, but
    # a motion would move it
    q, qd, qdd, tau = samples(arm, 300, 0)
    still = [torch.cat([x[:, :-1], torch.zeros_like(x[:, -1:])], 1) for x in (qd, qdd)]
    u = classical.least_squares(chain, q, *still, tau, drive=DRIVE).info["uncertainty"]
    lacking = [k for k in u["undetermined"] if k not in set(u["never_moving"])]
    assert lacking and all(k.startswith(chain.joint_names[-1]) for k in lacking), lacking
    assert f"motions these recordings lack would move {', '.join(lacking)}" in uncertainty_markdown(u)
    assert len(u["names"]) == len(u["value"]) == len(u["std"])
    q, qd, qdd, tau = samples(arm, 300, 0)
    slow = 1e-3  # barely moving: the inertial columns hardly differ from noise-level motion
    with pytest.warns(UntrustedParameterWarning, match="condition number"):
        classical.least_squares(chain, q[:1].expand(300, -1) + 1e-4 * q, slow * qd, slow * qdd, tau, drive=DRIVE)


def test_the_consistent_fits_prior_is_chosen_on_validation_data_only(arm):
    from lnn_torch.errors import InputError

    arm, chain = arm
    data = samples(arm, 30, 4)
    with pytest.raises(InputError, match="needs validation data"):
        classical.consistent_fit(chain, *data, drive=DRIVE, prior=(0.1, 1.0))
    with pytest.raises(InputError, match="prior must be >= 0"):
        classical.consistent_fit(chain, *data, drive=DRIVE, prior=-1.0)
    # noise-free data of the drive model: the weakest prior explains the held-out torques best and is chosen.
    # Priors two or more decades apart: near zero error, 1e-6 and 1 leave held-out errors that differ by less
    # than the solver's own tolerance (2.55e-8 against 2.55e-8 N m in one process, 2.9e-8 against 1.6e-7 in another)
    fit = classical.consistent_fit(chain, *samples(arm, 80, 5), drive=DRIVE, prior=(1e-6, 100.0, 1e4),
                                   validation=samples(arm, 40, 6))
    scores = fit.info["prior_selection"]["validation_rms_mean"]
    # the weakest given is best, so weaker ones are tried beyond it while validation improves (within the
    # solver's tolerance here: whichever it keeps is the lowest score, at most 1e-6)
    assert fit.info["prior"] <= 1e-6 and scores["1e-06"] < scores["100"] < scores["10000"], scores
    assert min(scores, key=scores.get) == f"{fit.info['prior']:g}"


def test_a_prior_at_the_end_of_those_given_is_extended_while_validation_improves(arm):
    """The description is the arm itself and the torques are noisy and few: the strongest prior given
    validates best, so stronger ones are tried beyond it (each EXTEND_STEP times the last) until validation
    stops improving or EXTEND more were tried; the one kept is the lowest validation error of all."""
    arm, chain = arm
    rng = np.random.default_rng(7)

    def noisy(n, seed):
        q, qd, qdd, tau = samples(arm, n, seed)
        return q, qd, qdd, tau + torch.as_tensor(rng.normal(scale=2.0, size=tau.shape))

    given = (1e-3, 1e-2, 0.1)
    fit = classical.consistent_fit(chain, *noisy(40, 8), drive=DRIVE, prior=given, validation=noisy(200, 9))
    scores = fit.info["prior_selection"]["validation_rms_mean"]
    beyond = [float(k) for k in scores if float(k) > max(given)]
    assert fit.info["prior"] > max(given) and beyond[0] == pytest.approx(0.316), scores
    assert min(scores, key=scores.get) == f"{fit.info['prior']:g}" and scores["0.316"] < scores["0.1"], scores
    assert len(beyond) <= classical.EXTEND and all(b / a == pytest.approx(classical.EXTEND_STEP, rel=0.01)
                                                   for a, b in zip([0.1, *beyond[:-1]], beyond, strict=True))
    # validation prefers a weak prior on noise-free data: no stronger one is tried
    fit = classical.consistent_fit(chain, *samples(arm, 80, 5), drive=DRIVE, prior=given,
                                   validation=samples(arm, 40, 6))
    assert max(float(k) for k in fit.info["prior_selection"]["validation_rms_mean"]) == max(given)


def test_identify_fits_the_classical_models_with_the_models_own_drive():
    """The classical fits ``lnn-torch identify`` prints beside a model use its drive model: its forms and the
    dataset's Coulomb smoothing (they used the default 0.02 rad/s whatever the dataset said, so a model
    trained with 0.005 was judged against fits of another friction law)."""
    from lnn_torch.commands.identify import classical_drive
    from lnn_torch.training import LNNModule

    config = {"dof": 2, "input_names": ["a", "b"], "coulomb_velocity": 0.005}
    module = LNNModule(scene="measured", scene_config=config, model_options={"friction": "viscous+coulomb+offset"})
    drive = classical_drive(module)
    assert drive == module.model.forces.drive and drive.coulomb_velocity == 0.005
    assert drive.forms == ("viscous", "coulomb", "offset")
    # a term kept on evidence only is in the fits where the model's classical start kept it, and only there
    module = LNNModule(scene="measured", scene_config=config,
                       model_options={"friction": "viscous+coulomb+offset+saturating"})
    assert classical_drive(module).forms == ("viscous", "coulomb", "offset", "saturating")  # no start: as configured
    module.classical_start = {"form": "coulomb+offset"}
    assert classical_drive(module).forms == ("viscous", "coulomb", "offset")
    module.classical_start = {"form": "viscous+coulomb+offset+saturating"}
    assert classical_drive(module).forms == ("viscous", "coulomb", "offset", "saturating")


def test_the_per_recording_table_bolds_every_value_that_prints_as_the_lowest():
    from lnn_torch.identification.arm_comparison import per_recording_markdown

    text = per_recording_markdown({"r07": {"grey box": 0.08596, "least squares": 0.08591, "description": 1.303},
                                   "r08": {"grey box": 0.0993, "least squares": 0.0997, "description": float("nan")}})
    r07, r08 = (line for line in text.splitlines() if line.startswith(("| r07", "| r08")))
    assert r07 == "| r07 | **0.086** | **0.086** | 1.303 |" and r08 == "| r08 | **0.099** | 0.100 | nan |", text


def test_the_regressor_of_the_same_states_is_computed_once_and_never_changed(arm, monkeypatch):
    """A classical start fits a dozen candidates to the same states: their regressor is computed once (by content:
    equal states stacked again hit it), a column zeroed for a drive without viscous friction is zeroed in a copy, and
    other states, or the same states of another arm, get their own."""
    from lnn_torch.robots import regressor as reg

    arm, chain = arm
    q, qd, qdd, _ = samples(arm, 300, 5)
    calls = []
    monkeypatch.setattr(classical, "regressor", lambda *a: calls.append(1) or reg.regressor(*a))
    classical._CACHE.clear()
    first = classical._regressor(chain, q, qd, qdd, DriveModel.of(DRIVE))
    rigid = classical._regressor(chain, q.clone(), qd.clone(), qdd.clone(), DriveModel.of("coulomb"))
    again = classical._regressor(chain, q.clone(), qd.clone(), qdd.clone(), DriveModel.of(DRIVE))
    assert len(calls) == 1 and again is first and not rigid[..., 11 * 7:].any() and first[..., 11 * 7:].any()
    torch.testing.assert_close(first, reg.regressor(chain, q, qd, qdd), rtol=0, atol=0)
    classical._regressor(chain, q + 1e-9, qd, qdd, DriveModel.of(DRIVE))
    moved = read_chain(arm.model)
    moved.axis[0] = -moved.axis[0]
    classical._regressor(moved, q, qd, qdd, DriveModel.of(DRIVE))
    assert len(calls) == 3
    classical._regressor(chain, q[:10], qd[:10], qdd[:10], DriveModel.of(DRIVE))  # few states: not kept
    classical._regressor(chain, q[:10], qd[:10], qdd[:10], DriveModel.of(DRIVE))
    assert len(calls) == 5 and len(classical._CACHE) <= classical.CACHED


@pytest.mark.parametrize("forms", ["viscous+coulomb+offset+saturating", "coulomb+offset", "coulomb+stribeck+saturating",
                                   "viscous", ""])
def test_the_consistent_objectives_closed_form_is_autograds(arm, forms):
    """``ConsistentObjective``'s value, gradient and Hessian (what the physically consistent fit's trust-region
    steps use) equal autograd's of the objective written out directly (the log-Cholesky factor, the classical
    ten, the LogDet divergence), float64, at random parameters of the Panda's links and a random quadratic form."""
    from lnn_torch.identification.consistent_objective import ConsistentObjective
    from lnn_torch.robots.kinematics import log_cholesky, log_cholesky_factor
    from lnn_torch.robots.regressor import classical_of

    _, chain = arm
    n = chain.dof
    drive = DriveModel.of(forms or None, saturation_velocity=0.3) if forms else None
    names = drive.coefficient_names() if drive else []
    linear = [DriveModel.of(f).coefficient_names()[0] for f in (drive.linear_forms if drive else ()) if f != "viscous"]
    floor = drive.saturation_floor() if "d" in names else 0.0
    P = 12 * n + len(linear) * n
    gen = torch.Generator().manual_seed(0)
    root = torch.randn(P, P, generator=gen, dtype=torch.float64)
    A, b, c = root @ root.T / P, torch.randn(P, generator=gen, dtype=torch.float64), 3.0
    J0 = chain.J.double()
    theta = torch.cat([log_cholesky(J0).reshape(-1) + 0.3 * torch.randn(10 * n, generator=gen, dtype=torch.float64),
                       torch.randn((1 + len(names)) * n, generator=gen, dtype=torch.float64)])

    def objective(t, prior):
        J = (lambda U: U @ U.mT)(log_cholesky_factor(t[: 10 * n].reshape(n, 10)))
        coef = {name: t[(11 + i) * n: (12 + i) * n] for i, name in enumerate(names)}
        values = {k: v if k == "o" else v ** 2 for k, v in coef.items()}
        if "d" in values:
            values["d"] = values["d"] - floor * values["c"]
        p = torch.cat([classical_of(J).reshape(-1), t[10 * n: 11 * n] ** 2, values.get("b", torch.zeros(n).double()),
                       *([torch.stack([values[k] for k in linear], -1).reshape(-1)] if linear else [])])
        div = sum(torch.trace(torch.linalg.solve(J0[l], J[l])) - torch.logdet(J[l]) + torch.logdet(J0[l]) - 4
                  for l in range(n))
        return p @ A @ p - 2 * b @ p + c + prior * div

    closed = ConsistentObjective(A.numpy(), b.numpy(), c, J0.numpy(), names, linear, floor)
    for prior in (0.0, 0.37):
        t = theta.clone().requires_grad_(True)
        value = objective(t, prior)
        (grad,) = torch.autograd.grad(value, t)
        hess = torch.func.hessian(lambda x, prior=prior: objective(x, prior))(theta)
        v, g = closed.value_and_gradient(theta.numpy(), prior)
        np.testing.assert_allclose(v, float(value.detach()), rtol=1e-12)
        np.testing.assert_allclose(g, grad.numpy(), rtol=1e-10, atol=1e-10 * float(grad.abs().max()))
        H = closed.hessian(theta.numpy(), prior)
        # round-off: the prior's J0^-1 reaches 1e5 on the light links; autograd's own Hessian is asymmetric by 1e-8
        np.testing.assert_allclose(H, hess.numpy(), rtol=1e-9, atol=1e-7 * float(hess.abs().max()))
    with pytest.raises(ValueError, match="physical values expected"):
        ConsistentObjective(A.numpy()[1:, 1:], b.numpy()[1:], c, J0.numpy(), names, linear, floor)
