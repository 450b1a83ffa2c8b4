"""Static friction (``dissipation: joint+stiction``): the holding torques against their closed forms,
a model at rest that keeps still below its static levels and slips with them opposing beyond, the
plain joint-friction model away from rest, the bounded power of the holding torque, one solve for
every path (training, rollouts), gradients, refusals."""

import math

import pytest
import torch

from lnn_torch.mechanics.forces import holding_torque, soft_clip, stick_weight
from lnn_torch.networks import build_model
from lnn_torch.systems import InputError, get_system
from lnn_torch.systems.measured import MeasuredSystem
from lnn_torch.training.module import LNNModule

from .helpers import perturbed

ARM = MeasuredSystem(2, input_names=("tau1", "tau2"), friction=True, angle_combinations=[[1, 1]],
                     coulomb_velocity=0.02)
CHAIN = dict(kinetic="chain", links=[[1, 0], [1, 1]], potential="chain")
F64 = dict(dtype=torch.float64)


def arm_model(dissipation="joint+stiction", seed=0):
    """A chain model of a measured two-joint arm with set friction coefficients (N m s/rad, N m)."""
    torch.manual_seed(seed)
    model = perturbed(build_model("film_lnn", ARM, dissipation=dissipation, **CHAIN).double(), scale=0.2, seed=seed)
    coef = [0.01, 0.02, 0.1, 0.08]
    gen = torch.Generator().manual_seed(seed)
    q = torch.rand(512, 2, generator=gen, **F64) * 2 - 1
    model.fit_normalizer({"q": q, "qd": torch.randn(512, 2, generator=gen, **F64) * 3,
                          "qdd": torch.randn(512, 2, generator=gen, **F64) * 40, "params": torch.zeros(1, 0, **F64),
                          "params_points": torch.zeros(512, 0, **F64),
                          "tau": torch.randn(512, 2, generator=gen, **F64)})
    with torch.no_grad():
        model.forces.units.fill_(1.0)
        model.forces.coefficients_raw.copy_(torch.tensor(coef, **F64).expm1().log())  # softplus^-1
    return model


def at_rest(n=16, seed=1):
    gen = torch.Generator().manual_seed(seed)
    q = (torch.rand(n, 2, generator=gen, **F64) - 0.5) * 4
    return q, torch.zeros(n, 2, **F64), torch.zeros(n, 0, **F64)


def test_holding_torque_closed_forms():
    """One joint: one sweep gives w s clip(h / s) with h = -rho0 / A (the torque that stops it); two
    uncoupled joints alike; a coupled pair below its levels is held to rest by the sweeps."""
    rho0 = torch.tensor([[3.0], [-0.5], [40.0]], **F64)
    A = torch.tensor([[[10.0]], [[2.0]], [[4.0]]], **F64)
    w = torch.tensor([[1.0], [0.5], [1.0]], **F64)
    s = torch.tensor([0.5], **F64)
    lam = holding_torque(rho0, A, w, s, sweeps=1)
    h = -rho0 / A[..., 0]
    torch.testing.assert_close(lam, w * s * soft_clip(h / s), rtol=0, atol=1e-15)
    assert abs(lam[0, 0] + 0.3) < 1e-3 and abs(lam[2, 0] + 0.5) < 1e-9  # held (0.3 < s); slips at -s
    # strongly coupled joints (condition number 39) held below their levels: at rest from the start
    A2 = torch.tensor([[[2.0, 1.9], [1.9, 2.0]]], **F64)
    rho = torch.tensor([[0.4, -0.3]], **F64)
    lam2 = holding_torque(rho, A2, torch.ones(1, 2, **F64), torch.tensor([50.0, 50.0], **F64), sweeps=0)
    torch.testing.assert_close(rho + (A2 @ lam2[..., None])[..., 0], torch.zeros(1, 2, **F64), rtol=0, atol=1e-9)
    # one joint beyond its level slips at it; the sweeps hold the other still
    lam3 = holding_torque(torch.tensor([[4.0, -0.3]], **F64), A2, torch.ones(1, 2, **F64),
                          torch.tensor([0.5, 50.0], **F64))
    assert abs(lam3[0, 0] + 0.5) < 1e-3
    rho3 = torch.tensor([[4.0, -0.3]], **F64) + (A2 @ lam3[..., None])[..., 0]
    assert abs(rho3[0, 1]) < 1e-6 and rho3[0, 0] > 0.1
    assert stick_weight(torch.tensor([0.0, 0.05, 1.0], **F64), 0.05).tolist() == [1.0, math.exp(-1), math.exp(-400)]


def test_an_arm_at_rest_keeps_still_below_its_static_levels_and_slips_beyond():
    """At rest, torques that leave each joint short of its static level by half keep it still; torques
    far beyond make it slip with exactly the static levels opposing (the model's own solve under
    tau - s sign(excess))."""
    model = arm_model()
    q, qd, p = at_rest()
    s = model.forces.static_level(p[:0]).detach()
    torch.testing.assert_close(s, torch.tensor([0.1, 0.08], **F64))  # the Coulomb levels
    balance = model.inverse(q, qd, torch.zeros_like(q), p).detach()  # gravity's torque, no holding
    signs = torch.tensor([1.0, -1.0], **F64)
    with torch.no_grad():
        held = model.acceleration(q, qd, p, balance + 0.5 * s * signs)
        # held but for the smooth clip's 0.05 % at half the level: less than 0.1 % of the level left unheld
        plain_solve = model.normalizer.accel_to_phys(model.solve_norm(*model.normalize(q, qd, p), model.force_norm(
            *model.normalize(q, qd, p), model.tau_norm(balance + 1e-3 * s * signs))))
        assert (held.abs() < plain_solve.abs()).all()
        excess = 20 * s * signs
        slipping = model.acceleration(q, qd, p, balance + excess)
        q_n, qd_n, p_n = model.normalize(q, qd, p)
        force = model.force_norm(q_n, qd_n, p_n, model.tau_norm(balance + excess - s * signs))
        expected = model.normalizer.accel_to_phys(model.solve_norm(q_n, qd_n, p_n, force))
    torch.testing.assert_close(slipping, expected, rtol=1e-6, atol=1e-6)
    assert expected.abs().min() > 1.0


def test_away_from_rest_static_friction_is_the_joint_friction_model():
    """Joints turning far faster than the stick velocity: the same accelerations as the model with plain
    joint friction and the same coefficients (the stick weight has underflowed)."""
    model, plain = arm_model(), arm_model("joint")
    plain.load_state_dict(model.state_dict())
    q, _, p = at_rest()
    qd = torch.where(torch.rand(q.shape, generator=torch.Generator().manual_seed(3), **F64) < 0.5, -1.0, 1.0) * 2.5
    tau = torch.randn(q.shape, generator=torch.Generator().manual_seed(4), **F64)
    with torch.no_grad():
        torch.testing.assert_close(model.acceleration(q, qd, p, tau), plain.acceleration(q, qd, p, tau),
                                   rtol=1e-12, atol=1e-12)


def test_the_holding_torques_power_is_bounded_and_every_path_adds_it():
    """Within the stick window the holding torque's power is at most 0.43 sum_j s_j v_s in magnitude;
    the training terms (energy path) and the rollout's step predict the accelerations of
    ``acceleration``, static friction included."""
    model = arm_model()
    q, _, p = at_rest(256)
    gen = torch.Generator().manual_seed(5)
    v_s = model.forces.stick_velocity
    qd = (torch.rand(q.shape, generator=gen, **F64) - 0.5) * 6 * v_s
    tau = torch.randn(q.shape, generator=gen, **F64) * 0.5
    with torch.no_grad():
        q_n, qd_n, p_n = model.normalize(q, qd, p)
        force = model.force_norm(q_n, qd_n, p_n, model.tau_norm(tau))
        plain = model.solve_norm(q_n, qd_n, p_n, force)
        full = model.acceleration_norm(q_n, qd_n, p_n, model.tau_norm(tau))
        _, lam = model.holding_torques(plain, force, lambda f: model.solve_norm(q_n, qd_n, p_n, f), qd_n, p_n)
        terms = model.training_terms(q, qd, torch.zeros_like(q), p, tau, energy=True)
    power = (qd * lam).sum(-1)  # joint coordinates: the rates are the velocities
    bound = 0.43 * float(model.forces.static_level(p[:0]).detach().sum()) * v_s
    assert power.abs().max() <= bound and power.abs().max() > 0.2 * bound
    assert (full - plain).abs().max() > 1e-3  # static friction acts here
    torch.testing.assert_close(terms["pred"], full, rtol=1e-10, atol=1e-10)
    step = model.rollout(q[:4], qd[:4], p[:4], 1e-3, 1, method="semi_implicit_euler", tau=tau[:4, None])
    torch.testing.assert_close(step[1][:, 1], qd[:4] + 1e-3 * model.acceleration(q[:4], qd[:4], p[:4], tau[:4]),
                               rtol=1e-10, atol=1e-12)


def test_the_holding_torques_are_what_the_face_leaves_out():
    """The rigid-body face's convention (``networks.rigid_body``): static friction's holding torques are in
    the forward dynamics only, so at the model's accelerations ``M qdd + n - B tau - Q_f = D^T lam`` (the
    holding torques at the joints), and the inverse dynamics of those accelerations is ``tau + lam``."""
    model = arm_model()
    q, _, p = at_rest(64)
    gen = torch.Generator().manual_seed(6)
    qd = (torch.rand(q.shape, generator=gen, **F64) - 0.5) * 4 * model.forces.stick_velocity
    tau = torch.randn(q.shape, generator=gen, **F64) * 0.05
    with torch.no_grad():
        qdd = model.forward(q, qd, p, tau)
        q_n, qd_n, p_n = model.normalize(q, qd, p)
        force = model.force_norm(q_n, qd_n, p_n, model.tau_norm(tau))
        plain = model.solve_norm(q_n, qd_n, p_n, force)
        _, lam = model.holding_torques(plain, force, lambda f: model.solve_norm(q_n, qd_n, p_n, f), qd_n, p_n)
        M, n, Qf = model.mass_matrix(q, p), model.bias(q, qd, p), model.friction(q, qd, p)
        residual = (M @ qdd[..., None])[..., 0] + n - tau - Qf  # the input matrix and the joint map are I
        torch.testing.assert_close(residual, lam, rtol=1e-9, atol=1e-12)
        assert lam.abs().max() > 1e-3  # held here
        torch.testing.assert_close(model.inverse(q, qd, qdd, p), tau + lam, rtol=1e-9, atol=1e-12)


def test_gradients_through_the_holding_torques():
    model = arm_model()
    q, qd, p = (x[:3] for x in at_rest(3))
    qd = qd + torch.tensor([[0.01, -0.02], [0.0, 0.03], [-0.01, 0.0]], **F64)
    q_n, qd_n, p_n = (x.clone().requires_grad_(True) for x in model.normalize(q, qd, p))
    tau_n = (torch.randn(3, 2, **F64) * 0.1).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda a, b, u: model.acceleration_norm(a, b, p_n, u), (q_n, qd_n, tau_n))


def test_static_friction_refusals():
    for variant in ("hnn", "lnn"):
        with pytest.raises(InputError, match="positive definite mass matrix"):
            build_model(variant, ARM, dissipation="joint+stiction")
    with pytest.raises(ValueError, match=r"energy_weight/torque_weight with dissipation 'joint\+stiction'"):
        LNNModule(scene="actuated_double_pendulum", model_options={"dissipation": "joint+stiction"}, energy_weight=0.1)
    with pytest.raises(ValueError, match="needs a scene with joint friction"):
        build_model("film_lnn", MeasuredSystem(2, input_names=("a", "b"), friction=False), dissipation="joint+stiction")
    with pytest.raises(ValueError, match="dissipation must be one of"):
        build_model("film_lnn", get_system("actuated_double_pendulum"), dissipation="stiction")
