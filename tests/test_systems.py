"""Scenes against independent references: the generic Euler-Lagrange solve, limits, normal modes; and the
cases and drawings each scene owns (no scene named in the generic modules)."""

import math
import re

import numpy as np
import pytest
import torch

from lnn_torch.mechanics.euler_lagrange import generic_acceleration
from lnn_torch.mechanics.integrators import rollout
from lnn_torch.systems import GRAVITY, InputError, get_system

from .conftest import QUADRATIC, QUADRATIC_IDS, SCENE_IDS, SCENES, random_batch, random_inputs
from .helpers import ROOT


@pytest.mark.parametrize("name, config", SCENES, ids=SCENE_IDS)
def test_closed_form_acceleration_equals_generic_solve(name, config, rng):
    """With generalised forces (inputs, friction) the generic solve gets the same force Q = B tau + Q_diss."""
    system = get_system(name, **config)
    q, qd, params = random_batch(system, rng, 256)
    tau = random_inputs(system, rng, 256)
    closed = system.acceleration(q, qd, params, tau)
    force = system.generalized_force(q, qd, params, tau) if system.has_forces else None
    generic = generic_acceleration(system.lagrangian, q, qd, params, force=force)
    torch.testing.assert_close(closed, generic, rtol=0, atol=1e-10)


@pytest.mark.parametrize("name, config", SCENES, ids=SCENE_IDS)
def test_every_parameter_matters(name, config, rng):
    """A parameter that is silently ignored would leave the accelerations or energy unchanged."""
    system = get_system(name, **config)
    q, qd, params = random_batch(system, rng, 32)
    tau = random_inputs(system, rng, 32)
    base_a = system.acceleration(q, qd, params, tau)
    base_e = system.energy(q, qd, params)
    for i, pname in enumerate(system.param_names):
        p2 = params.clone()
        p2[:, i] = p2[:, i] * 1.3 + 0.01  # (+ 0.01: friction coefficients may be sampled at 0)
        changed = ((system.acceleration(q, qd, p2, tau) - base_a).abs().max()
                   + (system.energy(q, qd, p2) - base_e).abs().max())
        assert changed > 1e-6, f"parameter {pname} has no effect"


@pytest.mark.parametrize("name, config", SCENES, ids=SCENE_IDS)
def test_mass_matrix_is_velocity_hessian_and_energy_is_legendre(name, config, rng):
    system = get_system(name, **config)
    q, qd, params = random_batch(system, rng, 16)
    if system.quadratic_kinetic:
        H = torch.func.vmap(torch.func.hessian(system.lagrangian, argnums=1))(q, qd, params)
        torch.testing.assert_close(system.mass_matrix(q, params), H, rtol=0, atol=1e-10)
    else:
        with pytest.raises(NotImplementedError, match="not quadratic"):
            system.mass_matrix(q, params)
    p = torch.func.vmap(torch.func.grad(system.lagrangian, argnums=1))(q, qd, params)
    torch.testing.assert_close(system.momentum(q, qd, params), p, rtol=0, atol=1e-10)
    legendre = (p * qd).sum(-1) - system.lagrangian(q, qd, params)
    torch.testing.assert_close(system.energy(q, qd, params), legendre, rtol=0, atol=1e-10)


def test_double_pendulum_potential_range():
    system = get_system("double_pendulum")
    params = torch.tensor([[1.3, 0.7, 1.1, 0.9]], dtype=torch.float64)
    grid = torch.linspace(-math.pi, math.pi, 201, dtype=torch.float64)
    q = torch.stack(torch.meshgrid(grid, grid, indexing="ij"), -1).reshape(-1, 2)
    V = system.potential(q, params.expand(len(q), -1))
    torch.testing.assert_close(V.max() - V.min(), system.energy_scale(params)[0], rtol=1e-12, atol=0)


def _dominant_frequency(x, dt):
    """Angular frequency from the mean spacing of sign changes (linear interpolation)."""
    s = np.sign(x)
    idx = np.nonzero(s[1:] != s[:-1])[0]
    crossings = idx + x[idx] / (x[idx] - x[idx + 1])
    half_period = np.diff(crossings).mean() * dt
    return math.pi / half_period


def test_light_second_mass_gives_simple_pendulum():
    """m2 -> 0: the first rod is a simple pendulum of length l1 (omega = sqrt(g/l1))."""
    system = get_system("double_pendulum")
    l1 = 1.7
    params = torch.tensor([[1.0, 1e-9, l1, 1.2]], dtype=torch.float64)
    q0 = torch.tensor([[1e-3, 0.0]], dtype=torch.float64)
    q, _ = rollout(system.acceleration, q0, torch.zeros_like(q0), params, 0.01, 3000, "rk4")
    omega = _dominant_frequency(q[0, :, 0].numpy(), 0.01)
    assert abs(omega - math.sqrt(GRAVITY / l1)) / math.sqrt(GRAVITY / l1) < 1e-4
    # the closed form itself reduces to -(g/l1) sin(theta1) for any angle
    qq = torch.tensor([[1.2, -0.4]], dtype=torch.float64)
    a = system.acceleration(qq, torch.zeros_like(qq), params)
    assert abs(a[0, 0].item() + GRAVITY / l1 * math.sin(1.2)) < 1e-7


@pytest.mark.parametrize("sign", [-1.0, 1.0])
def test_small_angle_normal_modes(sign):
    """Equal masses and lengths: omega^2 = (g/l)(2 -+ sqrt 2), modes (1, +-sqrt 2)."""
    system = get_system("double_pendulum")
    l = 1.3
    params = torch.tensor([[0.8, 0.8, l, l]], dtype=torch.float64)
    omega_expected = math.sqrt(GRAVITY / l * (2 + sign * math.sqrt(2)))
    amp = 1e-4
    q0 = torch.tensor([[amp, -sign * math.sqrt(2) * amp]], dtype=torch.float64)
    dt = 0.002
    q, _ = rollout(system.acceleration, q0, torch.zeros_like(q0), params, dt, 5000, "rk4")
    t = torch.arange(q.shape[1], dtype=torch.float64) * dt
    expected = q0[0] * torch.cos(omega_expected * t)[:, None]
    assert (q[0] - expected).abs().max() < 1e-3 * amp * 10  # nonlinearity ~ amp^2, integration ~ dt^4


def test_unknown_scene_and_bad_ranges():
    with pytest.raises(InputError, match="unknown scene 'triple'"):
        get_system("triple")
    with pytest.raises(InputError, match="inverted"):
        get_system("double_pendulum", l1_range=(2.0, 1.0))
    assert get_system("pendulum", m_range=(1.0, 1.0)).m_range.low == 1.0  # (one value: a parameter held fixed)
    with pytest.raises(InputError, match="not finite"):
        get_system("pendulum", m_range=(1.0, float("inf")))
    with pytest.raises(InputError, match="positive"):
        get_system("mass_spring", k_range=(-1.0, 1.0))


def test_input_checks(rng):
    system = get_system("double_pendulum")
    q, qd, params = random_batch(system, rng, 4)
    system.check_inputs(q, qd, params)
    with pytest.raises(InputError, match="params must have shape"):
        system.check_inputs(q, qd, params[:, :3])
    with pytest.raises(InputError, match="NaN"):
        system.check_inputs(q.clone().fill_(float("nan")), qd, params)
    bad = params.clone()
    bad[0, 1] = -1.0
    with pytest.raises(InputError, match="m2"):
        system.check_inputs(q, qd, bad)
    with pytest.raises(InputError, match="batch shapes differ"):
        system.check_inputs(q, qd, params[:2])


def test_samplers_follow_the_reference_distribution():
    system = get_system("double_pendulum")
    p = system.sample_params(np.random.default_rng(0), 20000)
    m1, m2, l1, l2 = p.T
    assert abs(np.log(m1).std() - 0.3) < 0.01
    assert (m2 / m1).min() >= 0.2 and (m2 / m1).max() <= 1.0
    assert l1.min() >= 0.9 and l1.max() <= 2.0
    assert (l2 / l1).min() >= 0.9 and (l2 / l1).max() <= 1.1
    q0, qd0 = system.sample_state(np.random.default_rng(0), 20000)
    assert np.abs(q0).max() <= math.pi / 2 and np.abs(q0).max() > 1.5
    assert np.abs(qd0).max() <= math.pi / 5


@pytest.mark.parametrize("name, config", QUADRATIC, ids=QUADRATIC_IDS)
def test_energy_scale_is_the_potential_range(name, config, rng):
    """V_max - V_min over q: pendula reach their extremes hanging down and all upright (all absolute
    angles pi; in joint angles, the first joint at pi and the others straight)."""
    system = get_system(name, **config)
    if name == "mass_spring":
        pytest.skip("V is unbounded; the scale is documented as the sampled amplitude bound")
    params = torch.tensor(system.sample_params(rng, 8))
    down = torch.zeros(8, system.dof, dtype=torch.float64)
    first_up = down.clone()
    first_up[:, 0] = math.pi
    V_down = system.potential(down, params)
    span = torch.maximum(system.potential(down + math.pi, params), system.potential(first_up, params)) - V_down
    torch.testing.assert_close(span, system.energy_scale(params), rtol=1e-12, atol=0)
    # and no other configuration goes beyond
    q = torch.rand(8, 200, system.dof, dtype=torch.float64) * 2 * math.pi
    V = system.potential(q, params[:, None].expand(-1, 200, -1))
    assert (V >= V_down[:, None] - 1e-12).all()
    assert (V <= (V_down + span)[:, None] + 1e-12).all()


def test_chain_of_two_is_the_double_pendulum_and_chain_of_one_the_pendulum(rng):
    dp, chain2 = get_system("double_pendulum"), get_system("chain_pendulum", num_links=2)
    q, qd, params = random_batch(dp, rng, 128)
    torch.testing.assert_close(chain2.acceleration(q, qd, params), dp.acceleration(q, qd, params), rtol=0, atol=1e-12)
    torch.testing.assert_close(chain2.energy(q, qd, params), dp.energy(q, qd, params), rtol=0, atol=1e-12)
    torch.testing.assert_close(chain2.positions(q, params), dp.positions(q, params), rtol=0, atol=1e-14)
    pend, chain1 = get_system("pendulum"), get_system("chain_pendulum", num_links=1)
    q, qd, params = random_batch(pend, rng, 64)
    torch.testing.assert_close(chain1.acceleration(q, qd, params), pend.acceleration(q, qd, params), rtol=0, atol=1e-12)


def test_chain_parameters_and_config():
    chain = get_system("chain_pendulum", num_links=4)
    assert chain.dof == 4 and chain.angle_mask == (True,) * 4
    assert chain.param_names == ("m1", "m2", "m3", "m4", "l1", "l2", "l3", "l4")
    assert chain.describe()["config"]["num_links"] == 4
    with pytest.raises(InputError, match="num_links must be >= 1"):
        get_system("chain_pendulum", num_links=0)


def test_relativistic_particle_closed_forms(rng):
    """The paper's Lagrangian: p = qd (1 - qd^2)^(-3/2), qdd = g (1 - qd^2)^(5/2) / (1 + 2 qd^2)."""
    system = get_system("relativistic_particle")
    assert not system.quadratic_kinetic
    v = torch.linspace(-0.99, 0.99, 199, dtype=torch.float64)[:, None]
    x = torch.zeros_like(v)
    g = torch.full_like(v, 0.7)
    torch.testing.assert_close(system.momentum(x, v, g), v * (1 - v**2) ** -1.5, rtol=1e-14, atol=0)
    torch.testing.assert_close(system.acceleration(x, v, g), 0.7 * (1 - v**2) ** 2.5 / (1 + 2 * v**2),
                               rtol=1e-14, atol=0)
    # d/dt p = dL/dx = g exactly along a trajectory: p(t) = p0 + g t, so the speed stays below c
    q0, qd0 = torch.tensor([[0.0]], dtype=torch.float64), torch.tensor([[0.3]], dtype=torch.float64)
    params = torch.tensor([[0.5]], dtype=torch.float64)
    q, qd = rollout(system.acceleration, q0, qd0, params, 0.01, 2000, "rk8")
    p = system.momentum(q, qd, params[:, None].expand(-1, q.shape[1], -1))
    t = torch.arange(q.shape[1], dtype=torch.float64) * 0.01
    torch.testing.assert_close(p[0, :, 0], p[0, 0, 0] + 0.5 * t, rtol=0, atol=1e-9)
    assert qd.abs().max() < 1
    E = system.energy(q, qd, params[:, None].expand(-1, q.shape[1], -1))
    assert (E - E[:, :1]).abs().max() < 1e-9


def test_relativistic_particle_rejects_superluminal_states():
    system = get_system("relativistic_particle")
    q = torch.zeros(3, 1, dtype=torch.float64)
    qd = torch.tensor([[0.5], [1.0], [-1.2]], dtype=torch.float64)
    with pytest.raises(InputError, match=r"\|qd\| >= 1"):
        system.check_inputs(q, qd, torch.full((3, 1), 0.1, dtype=torch.float64))
    with pytest.raises(InputError, match="inside"):
        get_system("relativistic_particle", v_range=(-1.0, 0.5))


# ---------------------------------------------------------------------------- scenes own their cases
def test_generic_modules_name_no_scene():
    """Evaluation, stability and plots take cases, drawings and time steps from the scene and the
    data: no scene names, and no fixed dof or time step in them."""
    evaluation = [f"evaluation/{p.name}" for p in (ROOT / "lnn_torch" / "evaluation").glob("*.py")]
    for module in (*evaluation, "commands/evaluate.py"):
        text = (ROOT / "lnn_torch" / module).read_text()
        for name in ("double_pendulum", "chain_pendulum", "mass_spring", "relativistic", "OOD_CASES",
                     "reshape(-1, 2)", "m2/m1"):
            assert name not in text, (module, name)
        assert not re.search(r"\bdt = 0\.005\b", text), module


def test_scenes_own_their_cases():
    dp, chain = get_system("double_pendulum"), get_system("chain_pendulum", num_links=4)
    assert len(dp.ood_cases()) == 4 and chain.ood_cases() == []
    assert set(dp.hard_parameter_cases()) == {"m2/m1 = 1e-3", "m2/m1 = 1e3", "l2/l1 = 0.1", "l2/l1 = 10"}
    from lnn_torch.evaluation.stability import hard_cases

    names = {c.name for c in hard_cases(chain, num=2)}
    assert "parameters x10" in names and not any("m2/m1" in n for n in names)
    assert get_system("mass_spring").positions(torch.zeros(1, 1), torch.ones(1, 2)) is None


def test_chain_pendulum_is_drawn_with_all_its_links():
    from lnn_torch.evaluation.plots import frames_figure

    chain = get_system("chain_pendulum", num_links=4)
    rng = np.random.default_rng(0)
    params = torch.tensor(chain.sample_params(rng, 1))[0]
    q = torch.tensor(rng.uniform(-1, 1, (10, 4)))
    fig = frames_figure(chain, q, q + 0.1, params, 0.01, num_frames=3)
    lines = fig.axes[0].get_lines()
    assert len(lines) == 2 and all(len(line.get_xdata()) == 5 for line in lines)  # origin + 4 bodies
    xy = chain.positions(q[:1], params[None])[0]
    np.testing.assert_allclose(lines[0].get_xdata()[1:], xy[:, 0].numpy())
    assert frames_figure(get_system("mass_spring"), q[:, :1], q[:, :1], torch.ones(2), 0.01) is None


def test_the_actuated_scene_refuses_a_link_lighter_in_inertia_than_its_point_mass():
    system = get_system("actuated_double_pendulum")
    p = torch.tensor(system.sample_params(np.random.default_rng(0), 3))
    system.check_params(p)
    p[1, 6] = 0.9 * p[1, 1] * p[1, 4] ** 2  # I2 below m2 r2^2
    with pytest.raises(InputError, match=r"I2 = [\d.e-]+ kg m\^2 is below m2 r2\^2"):
        system.check_params(p)


def test_parameter_kinds_positive_nonnegative_and_real():
    """``positive`` refuses zero, ``nonnegative`` refuses negatives, ``real`` takes any sign (a centre
    of mass); a kind the code does not know is refused rather than read as ``real``."""
    from lnn_torch.systems.base import check_param_signs

    kinds, names = ("positive", "nonnegative", "real"), ("m", "b", "x")
    check_param_signs(torch.tensor([[1.0, 0.0, -3.0], [2.0, 1.0, 4.0]]), kinds, names, "s")
    with pytest.raises(InputError, match=r"must be positive; non-positive values in \['m'\]"):
        check_param_signs(torch.tensor([[0.0, 0.0, -3.0]]), kinds, names, "s")
    with pytest.raises(InputError, match=r"negative values in \['b'\]"):
        check_param_signs(torch.tensor([[1.0, -0.1, -3.0]]), kinds, names, "s")
    with pytest.raises(InputError, match=r"unknown parameter kind\(s\) \['nonegative'\]"):
        check_param_signs(torch.ones(1, 3), ("positive", "nonegative", "real"), names, "s")


def test_a_dataset_whose_scene_a_model_cannot_take_is_named():
    """``System.mismatch``: what a file's recorded scene has that a model of another scene cannot take
    (``lnn-torch evaluate`` refuses such a file in one line)."""
    cart = dict(dof=2, angle_mask=[False, True], input_matrix=[[1.0], [0.0]], input_names=["force"])
    system = get_system("measured", **cart)
    assert system.mismatch(system.describe()) is None
    assert "scene 'double_pendulum'" in system.mismatch(get_system("double_pendulum").describe())
    one = get_system("measured", dof=1, input_matrix=[[1.0]], input_names=["tau"]).describe()
    assert "coordinates 1, where the model has 2" in system.mismatch(one)
    angles = get_system("measured", **{**cart, "angle_mask": [True, True]}).describe()
    assert "angle mask" in system.mismatch(angles)
    pole = get_system("measured", **{**cart, "input_matrix": [[0.0], [1.0]]}).describe()
    assert "input matrix [[0.0], [1.0]]" in system.mismatch(pole)
