"""The ``robot_arm`` scene option ``unmodelled`` (``lnn_torch.robots.unmodelled``): each effect's torque
is its closed form, written out here from the recorded values and against the engine's arm without
the effects; the conservative effects are the gradient of their potential, the friction is passive;
the engine's hook is the closed form; the truth's forward, forced and inverse dynamics agree; a
recorded dataset is reproducible, closes its power balance with the effects' potential and work,
replays open loop, and its torques are the description's inverse dynamics plus the effects' torques
(what the grey box from the description misses); bad options are refused in one line."""

import json
import math

import numpy as np
import pytest
import torch

mujoco = pytest.importorskip("mujoco")

from lnn_torch.data import DatasetSpec, generate_arrays, generate_dataset, read_dataset  # noqa: E402
from lnn_torch.errors import InputError  # noqa: E402
from lnn_torch.mechanics.integrators import rollout  # noqa: E402
from lnn_torch.robots.unmodelled import EFFECTS, UnmodelledEffects  # noqa: E402
from lnn_torch.systems import get_system  # noqa: E402

ALL = {"seed": 5, "friction": {}, "spring": {}, "cogging": {}, "sensor_offset": {}}


@pytest.fixture(scope="module")
def plain():
    return get_system("robot_arm")


def _batch(system, n=6, seed=0):
    rng = np.random.default_rng(seed)
    params = torch.tensor(system.sample_params(rng, n))
    q, qd = (torch.tensor(x) for x in system.sample_state(rng, n))
    qd = qd * 3
    qd[0, :] = 0.01  # near rest: the Coulomb and Stribeck terms in their steep part
    qdd = torch.tensor(rng.uniform(-3, 3, (n, 7)))
    return q, qd, qdd, params


def _values(system, effect):
    """The drawn values of an effect as the file records them: ``{key: (7,) array}``."""
    report = system.unmodelled.report()["effects"][effect]
    return {k: np.array(list(v["per_joint"].values())) for k, v in report.items() if isinstance(v, dict)}


def _closed_form(effect, v, q, qd, load):
    """Each effect's share of the recorded torque, written out from the module docstring."""
    q, qd, load = q.numpy(), qd.numpy(), load.numpy()
    if effect == "friction":
        sign = np.tanh(qd / v["v_c"])
        level = v["c"] + v["l"] * (np.sqrt(load**2 + 0.01) - 0.1)
        return level * sign + v["s"] * sign * np.exp(-(qd / v["v_s"]) ** 2)
    if effect == "spring":
        d = q - v["r"]
        return (v["k"] * d + v["k3"] * d**3) * (np.arange(7) < 2)  # joints 1 and 2 by default
    if effect == "cogging":
        return v["a"] * np.sin(v["n"] * q + v["phi"])
    return np.broadcast_to(v["o"], q.shape)


@pytest.mark.parametrize("effect", EFFECTS)
def test_each_effect_is_its_closed_form_on_the_engine(effect, plain):
    """One effect at a time: the truth's inverse dynamics minus the engine's arm without it (damper on)
    is the effect's closed form (to 1e-10 N m); the truth's accelerations are the engine's under the
    recorded torques less the effect's."""
    system = get_system("robot_arm", unmodelled={"seed": 2, effect: {}})
    q, qd, qdd, params = _batch(system)
    load = plain.arm.gravity(q, params)
    expected = torch.from_numpy(_closed_form(effect, _values(system, effect), q, qd, load).copy())
    assert expected.abs().max() > 0.1  # the effect is there (measured 0.23-1.5 N m at most)
    recorded_minus_rigid = system.effect_torques(q, qd, params)[effect]
    torch.testing.assert_close(recorded_minus_rigid, expected, rtol=0, atol=1e-12)
    if effect != "sensor_offset":  # a force on the arm: the engine with the hook
        torch.testing.assert_close(system.arm.inverse(q, qd, qdd, params) - plain.arm.inverse(q, qd, qdd, params),
                                   expected, rtol=0, atol=1e-10)
    tau = plain.arm.inverse(q, qd, qdd, params) + expected  # the torques a sensor records for qdd
    torch.testing.assert_close(system.acceleration(q, qd, params, tau), qdd, rtol=0, atol=1e-9)


def test_the_effects_values_are_seeded_drawn_around_their_magnitudes_and_recorded():
    a = get_system("robot_arm", unmodelled=ALL).unmodelled
    b = get_system("robot_arm", unmodelled=ALL).unmodelled
    c = get_system("robot_arm", unmodelled={**ALL, "seed": 6}).unmodelled
    for name in EFFECTS:
        for key, value in a.values[name].items():
            np.testing.assert_array_equal(value, b.values[name][key])
    assert not np.array_equal(a.values["friction"]["c"], c.values["friction"]["c"])
    # one effect's values do not depend on which others are on (each its own generator)
    alone = get_system("robot_arm", unmodelled={"seed": 5, "cogging": {}}).unmodelled
    np.testing.assert_array_equal(alone.values["cogging"]["phi"], a.values["cogging"]["phi"])
    # defaults: fractions of the Panda's torque limits (87 N m joints 1-4, 12 N m 5-7), drawn x U(0.5, 1.5)
    limit = np.array([87.0] * 4 + [12.0] * 3)
    c_rel = a.values["friction"]["c"] / (0.004 * limit)
    assert ((c_rel >= 0.5) & (c_rel <= 1.5)).all() and np.ptp(c_rel) > 0.1
    assert (np.abs(a.values["sensor_offset"]["o"]) <= 0.003 * limit).all()
    np.testing.assert_array_equal(a.values["cogging"]["n"], 6.0)
    # values given per joint are used as they are; one number is a magnitude
    given = get_system("robot_arm", unmodelled={"friction": {"coulomb": [0.1] * 7, "stribeck": 0.2}}).unmodelled
    np.testing.assert_array_equal(given.values["friction"]["c"], 0.1)
    assert not np.allclose(given.values["friction"]["s"], 0.2)
    # the report names every value per joint, its unit, the seed and the formulas
    report = a.report()
    assert report["seed"] == 5 and set(report["effects"]) == set(EFFECTS)
    assert report["effects"]["friction"]["c"]["unit"] == "N m"
    assert list(report["effects"]["cogging"]["phi"]["per_joint"]) == [f"joint{i}" for i in range(1, 8)]
    assert report["effects"]["spring"]["joints"] == ["joint1", "joint2"] and set(report["formulas"]) == set(EFFECTS)
    # the configuration rebuilds it
    rebuilt = get_system("robot_arm", **{k: v for k, v in get_system("robot_arm", unmodelled=ALL).config().items()})
    np.testing.assert_array_equal(rebuilt.unmodelled.values["spring"]["r"], a.values["spring"]["r"])


def test_the_conservative_effects_are_the_gradient_of_their_potential_and_the_friction_is_passive():
    effects = get_system("robot_arm", unmodelled=ALL).unmodelled
    q = torch.randn(50, 7, dtype=torch.float64, requires_grad=True)
    (grad,) = torch.autograd.grad(effects.potential(q).sum(), q)
    torch.testing.assert_close(effects.conservative_force(q.detach()), -grad, rtol=0, atol=1e-12)
    qd = torch.linspace(-2, 2, 401, dtype=torch.float64)[:, None].expand(-1, 7)
    load = torch.randn(401, 7, dtype=torch.float64) * 20
    assert (effects.friction(qd, load) * qd >= 0).all()
    # numpy and torch give the same (the engine's hook runs on numpy)
    np.testing.assert_allclose(effects.potential(q.detach().numpy()), effects.potential(q.detach()).numpy(),
                               rtol=0, atol=1e-13)


def test_the_engines_hook_is_the_closed_form_and_the_gravity_load_the_engines(plain):
    """``gravity_from_kinematics`` (bodies' centres of mass after mj_kinematics) equals the engine's
    ``bias(q, 0)``; the hook's numpy path equals the general closed forms."""
    system = get_system("robot_arm", unmodelled=ALL)
    q, qd, _, params = _batch(system)
    arm = system.arm
    for k in arm._each(q, qd, params):
        mujoco.mj_kinematics(arm.model, arm.data)
        load = arm.gravity_from_kinematics(arm.data)
        np.testing.assert_allclose(load, plain.arm.gravity(q[k:k + 1], params[k])[0].numpy(), rtol=0,
                                   atol=1e-12)
        conservative, dissipative = system.unmodelled.engine_forces(arm, arm.data)
        np.testing.assert_allclose(conservative, system.unmodelled.conservative_force(q[k]).numpy(), rtol=0,
                                   atol=1e-13)
        np.testing.assert_allclose(dissipative, -system.unmodelled.friction(qd[k], torch.from_numpy(load)).numpy(),
                                   rtol=0, atol=1e-13)


def test_forward_forced_and_inverse_dynamics_of_the_truth_agree():
    system = get_system("robot_arm", unmodelled=ALL)
    q, qd, qdd, params = _batch(system)
    tau = torch.tensor(np.random.default_rng(1).uniform(-10, 10, (len(q), 7)))
    a = system.acceleration(q, qd, params, tau)
    torch.testing.assert_close(system.forced_acceleration(q, qd, params, system.generalized_force(q, qd, params, tau)),
                               a, rtol=0, atol=1e-10)
    # the recorded torques that give a: the engine's inverse (effects included) plus the sensor's offset
    torch.testing.assert_close(system.arm.inverse(q, qd, a, params) + system.unmodelled.offset(tau), tau, rtol=0,
                               atol=1e-9)
    # the scene's potential holds the conservative effects: -dV/dq by central differences = gravity force + Q_c
    h = 1e-6
    grad = torch.stack([(system.potential(q + h * e, params) - system.potential(q - h * e, params)) / (2 * h)
                        for e in torch.eye(7, dtype=torch.float64)], -1)
    expected = system.arm.gravity(q, params) - system.unmodelled.conservative_force(q)
    torch.testing.assert_close(grad, expected, rtol=0, atol=1e-6)


# ---------------------------------------------------------------------------- a recorded dataset
@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """3 trajectories x 1 s with every effect (about 2 s)."""
    spec = DatasetSpec(scene="robot_arm", scene_config={"unmodelled": ALL}, num_trajectories=3, duration=1.0,
                       dt=0.005, seed=3, split=(0.34, 0.33, 0.33))
    path = generate_dataset(spec, tmp_path_factory.mktemp("arm") / "arm.h5")
    f = read_dataset(path)
    arrays = {k: torch.from_numpy(f.read(k)) for k in ("q", "qd", "qdd", "tau", "params", "energy", "work")}
    return spec, f, arrays


def _flat(a):
    T = a["q"].shape[1]
    flat = {k: a[k].reshape(-1, a[k].shape[-1]) for k in ("q", "qd", "qdd", "tau")}
    flat["params"] = a["params"][:, None].expand(-1, T, -1).reshape(-1, 4)
    return flat


def test_the_file_records_the_effects_and_their_seed(recorded):
    spec, f, _ = recorded
    report = json.loads(f.attrs["unmodelled"])
    assert report["seed"] == 5 and set(report["effects"]) == set(EFFECTS)
    assert json.loads(f.attrs["scene_json"])["config"]["unmodelled"] == {**ALL}
    assert "unmodelled effects (seed 5)" in f.attrs["conventions"]
    recording = json.loads(f.attrs["recording"])
    assert "sensor's offset" in recording["recorded"] and "mj_forward" in recording["integration"]
    tolerances = json.loads(f.attrs["tolerances"])
    assert "sensor offset" in tolerances["check"] and tolerances["max_power_balance_residual_rel"] < 1e-9


def test_the_power_balance_closes_with_the_effects_potential_and_work(recorded):
    """``E`` with the spring's and the cogging's potential, ``W`` the recorded torques' and Q_diss's
    (damper, friction, offset): closes to 1e-9 of the energy scale (measured 2.6e-11); without the
    effects' potential it does not."""
    _, _, a = recorded
    system = get_system("robot_arm", unmodelled=ALL)
    params = a["params"][:, None].expand(-1, a["q"].shape[1], -1)
    torch.testing.assert_close(a["energy"], system.energy(a["q"], a["qd"], params), rtol=0, atol=1e-10)
    scale = system.energy_scale(a["params"]).min()
    residual = (a["energy"] - a["energy"][:, :1] - a["work"].sum(-1)).abs().max() / scale
    assert residual < 1e-9
    V_effects = system.unmodelled.potential(a["q"])
    assert ((V_effects - V_effects[:, :1]).abs().max() / scale) > 1e-4  # measured 1.1e-3: it matters
    # the friction dissipates more than the damper alone
    damper = -(a["qd"] * system.arm.damping * a["qd"]).sum(-1)
    damper_work = (0.5 * 0.005 * (damper[:, 1:] + damper[:, :-1])).sum(-1)
    offset_work = (a["q"][:, -1] - a["q"][:, 0]) @ system.unmodelled.offset(a["q"])
    assert (a["work"][:, -1, 1] + offset_work < damper_work).all()


def test_the_recorded_torques_are_the_description_plus_the_effects(recorded, plain):
    """The truth's inverse dynamics reproduces the recorded torques (1e-9 N m); the description's (the
    engine's arm without the effects) misses exactly the effects' torques, the grey box's torque error
    (the truth's measured 7e-15 N m off)."""
    _, _, a = recorded
    system = get_system("robot_arm", unmodelled=ALL)
    f = _flat(a)
    truth = system.arm.inverse(f["q"], f["qd"], f["qdd"], f["params"]) + system.unmodelled.offset(f["tau"])
    torch.testing.assert_close(truth, f["tau"], rtol=0, atol=1e-9)
    description = plain.arm.inverse(f["q"], f["qd"], f["qdd"], f["params"])
    shares = system.effect_torques(f["q"], f["qd"], f["params"])
    torch.testing.assert_close(f["tau"] - description, sum(shares.values()), rtol=0, atol=1e-9)
    nmse = ((f["tau"] - description).pow(2).mean(0) / f["tau"].var(0))
    assert (nmse > 1e-3).all()  # measured 2.8e-3 (joint 6) to 6.0e-2 (joint 1)
    assert all(s.abs().max() > 1e-3 for s in shares.values())


def test_the_recorded_torques_replayed_open_loop_reproduce_the_motion(recorded):
    spec, _, a = recorded
    system = get_system("robot_arm", unmodelled=ALL)
    steps = a["q"].shape[1] - 1
    q, qd = rollout(system.acceleration, a["q"][:, 0], a["qd"][:, 0], a["params"], spec.dt, steps, "rk4",
                    spec.substeps, tau=a["tau"][:, :-1])
    assert (q - a["q"]).abs().max() < 1e-9  # measured 7e-16 rad: the same RK4 on the same forces
    params = a["params"][:, None].expand(-1, a["q"].shape[1], -1)
    torch.testing.assert_close(a["qdd"], system.acceleration(a["q"], a["qd"], params, a["tau"]), rtol=0, atol=1e-9)


def test_a_dataset_with_effects_is_reproducible():
    spec = DatasetSpec(scene="robot_arm", scene_config={"unmodelled": ALL}, num_trajectories=3, duration=0.2, seed=7)
    full = generate_arrays(spec)
    again = generate_arrays(spec, indices=[2])
    for key in ("q", "qd", "qdd", "tau", "work", "energy"):
        np.testing.assert_array_equal(again[key][0], full[key][2], err_msg=key)
    other = generate_arrays(DatasetSpec(scene="robot_arm", scene_config={"unmodelled": {**ALL, "seed": 6}},
                                        num_trajectories=3, duration=0.2, seed=7), indices=[2])
    np.testing.assert_array_equal(other["params"][0], full["params"][2])  # the same payload and reference
    assert np.abs(other["tau"][0] - full["tau"][2]).max() > 1e-3  # other effects


@pytest.mark.parametrize("config, message", [
    ([1, 2], "unmodelled must be a dict"),
    ({"seed": 1}, "names no effect"),
    ({"backlash": {}}, "no effect 'backlash'"),
    ({"friction": {"coulomb": -1}}, r"friction coulomb must be a number >= 0"),
    ({"friction": {"coulomb": [0.1, 0.2]}}, r"or 7 such numbers"),
    ({"friction": {"viscous": 1}}, "takes no option 'viscous'"),
    ({"friction": {"coulomb_velocity": 0}}, "coulomb_velocity must be a positive number"),
    ({"spring": {"joints": [7]}}, r"joint indices in \[0, 7\)"),
    ({"cogging": {"cycles": 2.5}}, "cycles must be an integer"),
    ({"seed": -1, "cogging": {}}, "seed must be an integer"),
])
def test_bad_options_are_refused_in_one_line(config, message):
    with pytest.raises(InputError, match=message) as err:
        get_system("robot_arm", unmodelled=config)
    assert "\n" not in str(err.value)


def test_defaults_need_torque_limits_or_magnitudes():
    with pytest.raises(InputError, match="give it in N m"):
        UnmodelledEffects.of({"cogging": {}}, np.zeros((7, 2)), None, [f"j{i}" for i in range(7)])
    effects = UnmodelledEffects.of({"cogging": {"amplitude": 0.1}}, np.zeros((7, 2)), None,
                                   [f"j{i}" for i in range(7)])
    assert 0.05 <= effects.values["cogging"]["a"].min() and effects.values["cogging"]["a"].max() <= 0.15
    assert math.isclose(float(effects.potential(np.zeros(7))), float(-(effects.values["cogging"]["a"] / 6 * np.cos(
        effects.values["cogging"]["phi"])).sum()), abs_tol=1e-14)
