"""The plant view and the controllers (``lnn_torch.control``): linearisations against finite
differences and the closed form, the rigid-body terms against independent references, LQR
stabilising the true upright, one code path for every plant, clear refusals."""

import math

import numpy as np
import pytest
import torch

from lnn_torch.control import LQR, ComputedTorque, Plant, calibrate_torque_scale, closed_loop, lqr_gain, plant_of, wrap
from lnn_torch.errors import InputError
from lnn_torch.identification.two_link import RigidArmModel
from lnn_torch.networks import build_model
from lnn_torch.systems import get_system

from .helpers import perturbed, random_batch

DP = get_system("double_pendulum")
ARM = get_system("actuated_double_pendulum")
LAB = RigidArmModel(m1=0.59, m2=0.59, l1=0.3, r1=0.3, r2=0.28, I1=0.054, I2=0.048, Ir=7e-5, gr=6.0, b1=0.001,
                    b2=0.001, cf1=0.09, cf2=0.08)


def structured_model(system, seed=0):
    """An untrained film_lnn of ``system`` (perturbed so every path matters), normaliser fitted."""
    torch.manual_seed(seed)
    model = perturbed(build_model("film_lnn", system, hidden_dims=[16, 16]).double(), 0.05, seed)
    rng = np.random.default_rng(seed)
    q, qd, params = random_batch(system, rng, 256)
    tau = None if not system.num_inputs else torch.tensor(rng.uniform(-1, 1, (256, system.num_inputs)))
    model.fit_normalizer({"q": q, "qd": qd, "qdd": system.acceleration(q, qd, params, tau), "params": params,
                          "params_points": params, **({"tau": tau} if tau is not None else {})})
    return model


PLANTS = {
    "double pendulum, both joints": lambda: plant_of(DP),
    "double pendulum, pendubot": lambda: plant_of(DP, actuation=(True, False)),
    "actuated arm with friction": lambda: plant_of(ARM),
    "learned arm (film_lnn)": lambda: plant_of(structured_model(ARM)),
    "learned double pendulum, acrobot": lambda: plant_of(structured_model(DP), actuation=(False, True)),
    "identified lab arm": lambda: plant_of(LAB),
}


def _states(plant, n=6, seed=0):
    rng = np.random.default_rng(seed)
    system = ARM if plant.num_params == ARM.num_params else DP
    q, qd, params = random_batch(system, rng, n)
    params = params if plant.num_params else torch.zeros(n, 0, dtype=torch.float64)
    u = torch.tensor(rng.uniform(-1, 1, (n, plant.num_inputs)))
    return q, qd, params, u


@pytest.mark.parametrize("name", PLANTS)
def test_linearisation_equals_central_differences(name):
    plant = PLANTS[name]()
    q, qd, params, u = _states(plant)
    A, B = plant.linearize(q, qd, u, params)
    x, n, h = torch.cat([q, qd], -1), plant.dof, 1e-6

    def f(x, u):
        return torch.cat([x[:, n:], plant.forward(x[:, :n], x[:, n:], params, u)], -1)

    for j in range(2 * n):
        dx = torch.zeros_like(x)
        dx[:, j] = h
        fd = (f(x + dx, u) - f(x - dx, u)) / (2 * h)
        torch.testing.assert_close(A[..., j], fd, rtol=1e-6, atol=1e-6)
    for j in range(plant.num_inputs):
        du = torch.zeros_like(u)
        du[:, j] = h
        torch.testing.assert_close(B[..., j], (f(x, u + du) - f(x, u - du)) / (2 * h), rtol=1e-6, atol=1e-6)


def test_linearisation_at_the_upright_is_the_closed_form():
    """About theta1 = theta2 = pi at rest: qdd = M^-1 (diag((m1+m2) g l1, m2 g l2) dtheta + D^T u),
    M = [[(m1+m2) l1^2, m2 l1 l2], [m2 l1 l2, m2 l2^2]] (point masses, absolute angles)."""
    m1, m2, l1, l2, g = 1.0, 0.6, 1.2, 1.1, 9.81
    params = torch.tensor([[m1, m2, l1, l2]], dtype=torch.float64)
    up = torch.full((1, 2), math.pi, dtype=torch.float64)
    A, B = plant_of(DP).linearize(up, torch.zeros_like(up), None, params)
    M = torch.tensor([[(m1 + m2) * l1**2, m2 * l1 * l2], [m2 * l1 * l2, m2 * l2**2]], dtype=torch.float64)
    Minv = torch.linalg.inv(M)
    torch.testing.assert_close(A[0, 2:, :2], Minv @ torch.diag(torch.tensor([(m1 + m2) * g * l1, m2 * g * l2],
                                                                           dtype=torch.float64)))
    torch.testing.assert_close(A[0, :2, 2:], torch.eye(2, dtype=torch.float64))
    torch.testing.assert_close(B[0, 2:], Minv @ torch.tensor([[1.0, -1.0], [0.0, 1.0]], dtype=torch.float64))


@pytest.mark.parametrize("name", PLANTS)
def test_rigid_body_terms_are_consistent(name):
    """``M qdd + n = B u + Q_f`` with the inverse undoing the forward dynamics (fully actuated)."""
    plant = PLANTS[name]()
    q, qd, params, u = _states(plant)
    qdd = plant.forward(q, qd, params, u)
    M, n, Qf = plant.mass_matrix(q, params), plant.bias(q, qd, params), plant.friction(q, qd, params)
    torch.testing.assert_close(torch.einsum("bij,bj->bi", M, qdd) + n, u @ plant.input_matrix.T + Qf)
    if plant.num_inputs == plant.dof:
        torch.testing.assert_close(plant.inverse(q, qd, qdd, params), u)
        assert plant.residual(q, qd, qdd, params).max() < 1e-9


def test_the_learned_plant_is_the_models_rigid_body_face():
    """``plant_of(model)`` takes M, n, g and Q_f from the model's SI face (``lnn_torch.networks.rigid_body``),
    nothing derived again; a model learned without inputs has all of them in its own units, divided by
    the torque scale (model units per N m) in its plant."""
    model = structured_model(ARM)
    plant = plant_of(model)
    q, qd, params, _ = _states(plant)
    with torch.no_grad():
        for got, face in ((plant.mass_matrix(q, params), model.mass_matrix(q, params)),
                          (plant.bias(q, qd, params), model.bias(q, qd, params)),
                          (plant.gravity(q, params), model.gravity(q, params)),
                          (plant.friction(q, qd, params), model.friction(q, qd, params))):
            torch.testing.assert_close(got, face, rtol=0, atol=0)
    # a measured arm learned without inputs (joint friction in the model's units) under a torque scale
    from lnn_torch.systems import MeasuredSystem

    scene = MeasuredSystem(2, angle_combinations=[[1, 1]])
    torch.manual_seed(1)
    learned = perturbed(build_model("film_lnn", scene, hidden_dims=[16, 16]).double(), 0.05, 1)
    gen = torch.Generator().manual_seed(1)
    q, qd, qdd = (torch.randn(64, 2, generator=gen, dtype=torch.float64) for _ in range(3))
    none = torch.zeros(64, 0, dtype=torch.float64)
    learned.fit_normalizer({"q": q, "qd": qd, "qdd": qdd, "params": none[:1], "params_points": none})
    scaled = plant_of(learned, torque_scale=2.5)
    q, qd, u = q[:6], 0.3 * qd[:6], torch.randn(6, 2, generator=gen, dtype=torch.float64)
    M, n, Qf = scaled.mass_matrix(q, none[:6]), scaled.bias(q, qd, none[:6]), scaled.friction(q, qd, none[:6])
    torch.testing.assert_close(Qf, learned.friction(q, qd, none[:6]) / 2.5, rtol=0, atol=0)
    assert Qf.abs().max() > 1e-3
    qdd = scaled.forward(q, qd, none[:6], u)
    torch.testing.assert_close(torch.einsum("bij,bj->bi", M, qdd) + n, u @ scaled.input_matrix.T + Qf)


def test_gravity_is_the_gradient_of_the_potential():
    """An independent reference: the truth's ``n(q, 0)`` equals ``dV/dq`` by autograd of its potential."""
    q, _, params = random_batch(ARM, np.random.default_rng(3), 8)
    q = q.requires_grad_(True)
    dV = torch.autograd.grad(ARM.potential(q, params).sum(), q)[0]
    torch.testing.assert_close(plant_of(ARM).gravity(q.detach(), params), dV)


@pytest.mark.parametrize("actuation, ball", [(None, 0.05), ((True, False), 0.05), ((False, True), 0.01)])
def test_lqr_of_the_true_double_pendulum_stabilises_the_upright(actuation, ball):
    """Fully actuated, pendubot and acrobot: digital LQR at 500 Hz on the nonlinear truth, from a ball of
    starts around the upright, ends within 1e-3 rad of it after 5 s."""
    plant = plant_of(DP, actuation=actuation)
    N = 16
    params = torch.tensor([[1.0, 0.6, 1.2, 1.1]] * N, dtype=torch.float64)
    up = torch.full((N, 2), math.pi, dtype=torch.float64)
    gen = torch.Generator().manual_seed(0)
    q0 = up + ball * (2 * torch.rand(N, 2, generator=gen, dtype=torch.float64) - 1)
    lqr = LQR(plant, up, params, Q=[10, 10, 1, 1], R=0.1, dt=0.002)
    ep = closed_loop(plant, lqr, q0, torch.zeros_like(q0), params, 5.0, 0.002, substeps=2)
    assert wrap(ep["q"][:, -1] - up, (True, True)).abs().max() < 1e-3
    # without the controller it falls (within 2 s): the test can fail
    free = closed_loop(plant, lambda t, q, qd: torch.zeros(N, plant.num_inputs, dtype=torch.float64), q0,
                       torch.zeros_like(q0), params, 2.0, 0.002, substeps=2)
    assert wrap(free["q"][:, -1] - up, (True, True)).abs().max() > 0.5


def test_one_code_path_for_the_learned_and_the_true_plant():
    """LQR and computed torque take any ``Plant``: designed on a learned plant they run on the truth's
    (here an untrained model: only the code path is shared, not the quality)."""
    learned, true = plant_of(structured_model(ARM)), plant_of(ARM)
    assert isinstance(learned, Plant) and isinstance(true, Plant)
    q, qd, params, _ = _states(true, n=4)
    ref = lambda t: (q, torch.zeros_like(q), torch.zeros_like(q))  # noqa: E731
    for design in (learned, true):
        ct = ComputedTorque(design, ref, params, kp=50.0, kd=14.0)
        ep = closed_loop(true, ct, q, torch.zeros_like(q), params, 0.2, 0.002)
        assert torch.isfinite(ep["q"]).all() and ep["u"].shape == (4, 100, 2)


def test_computed_torque_on_the_true_model_tracks_a_reference_exactly():
    plant = plant_of(ARM)
    q, _, params, _ = _states(plant, n=4)

    def ref(t):
        s = torch.tensor(t, dtype=torch.float64)
        return (q + 0.3 * torch.sin(2 * s), 0.6 * torch.cos(2 * s) * torch.ones_like(q),
                -1.2 * torch.sin(2 * s) * torch.ones_like(q))

    ep = closed_loop(plant, ComputedTorque(plant, ref, params, kp=400.0, kd=40.0), q, 0.6 * torch.ones_like(q), params,
                     1.0, 0.001, substeps=1)
    err = (ep["q"][:, -1] - ref(1.0)[0]).abs().max()
    assert err < 1e-3, err


def test_torque_scale_of_a_lagrangian_known_up_to_scale_is_calibrated():
    """A plant whose Lagrangian is 3 times the truth's (what a model learned without inputs may be)
    gets its scale back from a recording with known torques."""
    true = plant_of(DP)
    scaled = Plant("scaled", 2, 4, true.input_matrix, true.angle_mask, true.accel_fn,
                   lambda q, p: 3.0 * DP.mass_matrix(q, p))
    q, qd, params, u = _states(true, n=32)
    qdd = true.forward(q, qd, params, u)
    assert calibrate_torque_scale(scaled, q, qd, qdd, u, params) == pytest.approx(3.0, rel=1e-9)


def test_bad_input_is_refused_in_one_line():
    up = torch.tensor([[math.pi / 2, 0.0]], dtype=torch.float64)
    params = torch.tensor([[1.0, 0.6, 1.2, 1.1]], dtype=torch.float64)
    with pytest.raises(InputError, match="cannot hold q = .* not an equilibrium"):
        LQR(plant_of(DP, actuation=(False, True)), up, params)
    plant = plant_of(DP)
    with pytest.raises(InputError, match="torque_limit needs 2 positive values"):
        closed_loop(plant, lambda t, q, qd: torch.zeros(1, 2), up, torch.zeros_like(up), params, 0.01, 0.002,
                    torque_limit=[1.0, 1.0, 1.0])
    with pytest.raises(InputError, match="has no mass matrix"):
        plant_of(build_model("mlp", DP, hidden_dims=[8]))
    with pytest.raises(InputError, match="u must have shape"):
        plant.forward(up, torch.zeros_like(up), params, torch.zeros(1, 3))
    with pytest.raises(InputError, match="inputs of its own"):
        plant_of(ARM, actuation=(True, False))
    with pytest.raises(InputError, match="Q must be"):
        lqr_gain(*plant.linearize(up, torch.zeros_like(up), None, params), Q=[1.0, 2.0], R=1.0)
    A, B = plant.linearize(up, torch.zeros_like(up), None, params)
    for Q, R, message in ((-np.eye(4), 1.0, r"^LQR: Q must be positive semi-definite \(its smallest eigenvalue is "
                                            r"-1\)"),
                          (1.0, np.zeros((2, 2)), r"^LQR: R must be positive definite"),
                          ([[1, 0], [0]], 1.0, r"^LQR: Q must be a scalar, 4 diagonal entries or a \(4, 4\) matrix "),
                          (np.triu(np.ones((4, 4))), 1.0, r"^LQR: Q must be finite and symmetric$")):
        with pytest.raises(InputError, match=message):
            lqr_gain(A, B, Q=Q, R=R)


def test_the_control_command_reports_a_swing_up_designed_on_the_plant(tmp_path, capsys):
    """``lnn-torch control plant -c SCENARIO``: the shipped real-pendulum scenario with the lab model
    both as plant and as design swings up every episode, and writes what it says."""
    import json

    from lnn_torch.cli import main

    from .helpers import ROOT

    scenario = ROOT / "configs" / "control" / "real_double_pendulum_swingup.yaml"
    out = tmp_path / "ctl"
    assert main(["control", "plant", "-c", str(scenario), "--episodes", "4", "-o", str(out)]) == 0
    report = json.loads((out / "control.json").read_text())
    assert report["success_rate"] == 1.0 and report["torque_max"] <= 10.0
    printed = capsys.readouterr().out
    assert "| success (within tolerance of the goal at the end) | 100.0 % |" in printed
    for name in ("control.json", "report.md", "episode.png", "episode.gif"):
        assert (out / name).stat().st_size > 100 and str(out / name) in printed


def test_a_goal_the_limits_cannot_hold_is_said_with_the_share_of_time_at_the_limit(tmp_path, capsys):
    """Holding the lab pendulum's first link level needs about 4 N m on its shoulder: with 0.3 N m the report says
    that the goal is beyond the limits, and how often the torque sat at its limit."""
    import json

    from lnn_torch.cli import main

    scenario = tmp_path / "s.yaml"
    scenario.write_text(ON_LAB.replace("{kind: lqr}", "{kind: lqr, goal: [1.5707963, 0.0]}")
                        + "limits: {torque: [0.3, 0.3]}\nduration: 1.0\nsuccess: {hold: 0.5}\n")
    assert main(["control", "plant", "-c", str(scenario), "--episodes", "2", "-o", str(tmp_path / "o"),
                 "--no-animation"]) == 0
    report = json.loads((tmp_path / "o" / "control.json").read_text())
    assert report["success_rate"] == 0.0 and report["torque_at_limit_share"] > 0.5
    # one number is every input's limit; YAML's 1e-3 (text) is a number; a full Q with off-diagonal terms is taken
    scenario.write_text(ON_LAB.replace("{kind: lqr}", "{kind: lqr, goal: [1.5707963, 0.0], Q: [[10, -1, 0, 0], "
                                       "[-1, 10, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}")
                        + "limits: {torque: 0.3}\nnoise: {angle: 1e-3}\nduration: 1.0\nsuccess: {hold: 0.5}\n")
    assert main(["control", "plant", "-c", str(scenario), "--episodes", "2", "-o", str(tmp_path / "o"),
                 "--no-animation"]) == 0
    again = json.loads((tmp_path / "o" / "control.json").read_text())
    assert again["goal_beyond_limit"]["limit"] == 0.3 and again["torque_max"] <= 0.3 + 1e-12
    # an episode shorter than the default hold (1 s) without success.hold: held over the whole episode
    scenario.write_text(ON_LAB + "duration: 0.5\n")
    assert main(["control", "plant", "-c", str(scenario), "--episodes", "2", "-o", str(tmp_path / "o"),
                 "--no-animation"]) == 0
    assert json.loads((tmp_path / "o" / "control.json").read_text())["success_rate"] == 1.0
    assert report["goal_beyond_limit"]["input"] == "tau1" and report["goal_beyond_limit"]["holding_torque"] > 3.0
    printed = capsys.readouterr().out
    assert "The goal cannot be held within the limits: at rest there the plant needs " in printed
    assert "| control periods with a torque at its limit | " in printed


ON_LAB = ("plant: {identified: lnn_torch/datasets/real_double_pendulum/identified_parameters.yml}\n"
                "controller: {kind: lqr}\n")


@pytest.mark.parametrize("text, message", [("controller: {kind: swingup}\n", "'plant' is missing"),
                                           ("plant: {scene: double_pendulum}\ncontroller: {kind: lqr}\n",
                                            "plant.params is missing"),
                                           ("plant: {identified: nowhere.yml}\ncontroller: {}\n",
                                            "file nowhere.yml does not exist"),
                                           # a key misspelt ran without it (no torque limit: 100 % success)
                                           (f"{ON_LAB}limits: {{torques: [0.3, 0.3]}}\n", "unknown key limits.torques "
                                            "(the keys of limits: torque)"),
                                           (f"{ON_LAB}episdoes: 3\n", "unknown key episdoes (the keys: episodes, "),
                                           (f"{ON_LAB}noise: 0.001\n", "noise must be a mapping (angle, velocity)"),
                                           (f"{ON_LAB}control_hz: 0\n", "control_hz must be a number > 0, got 0"),
                                           (f"{ON_LAB}delay: 2.7\n", "delay must be a whole number >= 0, got 2.7"),
                                           (f"{ON_LAB}seed: [1]\n", "seed must be a whole number >= 0, got [1]"),
                                           (f"{ON_LAB}success: {{hold: 9}}\n", "success.hold (9 s) is longer than an "
                                            "episode (duration 5.0 s)"),
                                           (f"{ON_LAB}start: {{q: [0, 0, 0]}}\n", "start.q needs 2 values"),

                                           ("plant: {identified: lnn_torch/datasets/real_double_pendulum/"
                                            "identified_parameters.yml}\ncontroller: {kind: lqr, R: -0.1}\n",
                                            "controller.R must be a list of numbers (or one number) > 0, got -0.1")])
def test_the_control_command_names_a_bad_scenario_in_one_line(text, message, tmp_path, capsys):
    from lnn_torch.cli import main

    scenario = tmp_path / "s.yaml"
    scenario.write_text(text)
    assert main(["control", "plant", "-c", str(scenario), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err


def test_mppi_holds_the_lab_arm_upright_where_it_falls_without_control():
    from lnn_torch.control import MPPI

    N = 3
    goal = torch.tensor([[math.pi, 0.0]] * N, dtype=torch.float64)
    gen = torch.Generator().manual_seed(1)
    q0 = goal + 0.05 * (2 * torch.rand(N, 2, generator=gen, dtype=torch.float64) - 1)
    plant = plant_of(LAB)
    mppi = MPPI(plant, goal, None, samples=300, horizon=30, dt=0.01, noise=0.3, temperature=0.05, Q=(20, 20, 1, 1),
                torque_limit=[10.0, 10.0])
    ep = closed_loop(plant, mppi, q0, torch.zeros_like(q0), None, 2.0, 0.01, substeps=5, torque_limit=[10.0, 10.0])
    assert wrap(ep["q"][:, 50:] - goal[:, None], (True, True)).abs().max() < 0.15
    free = closed_loop(plant, lambda t, q, qd: torch.zeros(N, 2, dtype=torch.float64), q0, torch.zeros_like(q0), None,
                       2.0, 0.01, substeps=5)
    assert wrap(free["q"][:, -1] - goal, (True, True)).abs().max() > 0.5


@pytest.mark.parametrize("model, scenario", [("pretrained:real_double_pendulum", "real_double_pendulum_swingup"),
                                             ("pretrained:double_pendulum_control", "double_pendulum_lqr")])
def test_controllers_designed_on_the_shipped_models_succeed_on_the_true_plants(model, scenario, tmp_path):
    """The README's control commands: swing-up and balance of the lab's arm designed on the model
    learned from the real recordings; LQR of the true double pendulum designed on the shipped family
    model (torque scale calibrated from the plant)."""
    import json

    from lnn_torch.cli import main

    from .helpers import ROOT

    out = tmp_path / "ctl"
    assert main(["control", model, "-c", str(ROOT / "configs" / "control" / f"{scenario}.yaml"), "--episodes", "8",
                 "--no-animation", "-o", str(out)]) == 0
    report = json.loads((out / "control.json").read_text())
    assert report["success_rate"] == 1.0, report
    assert ("torque_scale_calibrated" in report) == (model.endswith("control"))


@pytest.mark.slow
def test_the_arm_reaches_its_goal_by_computed_torque_designed_on_the_grey_box():
    """configs/control/robot_arm_reach.yaml on the engine (the 7-joint arm with a 2 kg payload), designed
    on the description's grey box (untrained: its inertia is the description's, its friction not yet
    fitted): every episode ends at the goal."""
    pytest.importorskip("mujoco")
    from lnn_torch import LNNModule
    from lnn_torch.commands.config_files import read_config
    from lnn_torch.commands.control import run_scenario

    from .helpers import ROOT

    scenario = read_config(ROOT / "configs" / "control" / "robot_arm_reach.yaml")
    module = LNNModule(scene="robot_arm", model_options={"kinetic": {"spatial": {}}, "potential": {"spatial": {}}},
                       eps=0.0)
    out = run_scenario({**scenario, "duration": 3.0}, module.model, episodes=3)
    assert out["success_rate"] == 1.0, {k: v for k, v in out.items() if not k.startswith("_")}
    assert out["tracking_error_rms_rad"] < 0.01
