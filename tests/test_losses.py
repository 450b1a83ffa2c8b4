"""Training losses as pure functions (``lnn_torch.training.losses``): each term against a hand computation, the
multiple-shooting residual shared by training and identification, and the LightningModule's losses on
fixed batches against the values and the assembly it had before the losses moved out of it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lnn_torch import LNNModule, load_model
from lnn_torch.mechanics import integrators
from lnn_torch.systems import get_system
from lnn_torch.training.losses import (
    acceleration_loss,
    energy_variance,
    power_balance,
    shooting_residual,
    shooting_residuals,
    shooting_velocity_residual,
    torque_loss,
    training_loss,
    trajectory_loss,
)

F64 = torch.float64


def huber(x: torch.Tensor, delta: float) -> torch.Tensor:
    """Huber loss of residuals ``x`` written out: 0.5 x^2 inside ``delta``, delta (|x| - delta / 2) outside."""
    a = x.abs()
    return torch.where(a <= delta, 0.5 * x**2, delta * (a - 0.5 * delta)).mean()


# ---------------------------------------------------------------------------- multiple shooting
def test_shooting_residual_equals_a_hand_computation():
    """Windows of k = 2 steps spanning 0.1 s: the errors after each window's start, / scale, / (span^2 / 2)."""
    q_data = torch.tensor([[[0.0, 0.0], [0.0, 0.02], [0.03, 0.07]]], dtype=F64)  # (1 window, k + 1, dof)
    q_roll = torch.tensor([[[0.0, 0.0], [0.01, 0.02], [0.04, 0.05]]], dtype=F64)
    # differences after the start: [[0.01, 0], [0.01, -0.02]]; span^2 / 2 = 0.005
    expected = torch.tensor([[[2.0, 0.0], [2.0, -4.0]]], dtype=F64)
    torch.testing.assert_close(shooting_residual(q_roll, q_data, 0.1), expected, rtol=1e-12, atol=1e-12)
    scale = torch.tensor([2.0, 4.0], dtype=F64)
    torch.testing.assert_close(shooting_residual(q_roll, q_data, 0.1, scale), expected / scale, rtol=1e-12, atol=1e-12)
    # velocities: differences in units of scale / time_scale, divided by the span
    qd_data = torch.tensor([[[9.0, 9.0], [1.0, 2.0], [3.0, 4.0]]], dtype=F64)
    qd_roll = torch.tensor([[[0.0, 0.0], [1.5, 2.0], [2.0, 6.0]]], dtype=F64)
    expected_v = torch.tensor([[[0.5 * 3 / 2, 0.0], [-1.0 * 3 / 2, 2.0 * 3 / 4]]], dtype=F64) / 0.1
    torch.testing.assert_close(shooting_velocity_residual(qd_roll, qd_data, 0.1, scale, time_scale=3.0), expected_v,
                               rtol=1e-12, atol=1e-12)


class ConstantAcceleration:
    """A stand-in model: from each start state it moves with the constant acceleration ``params``
    (exactly, at any step); records how it was called."""

    def __init__(self):
        self.calls = []

    def rollout(self, q0, qd0, params, dt, num_steps, method="rk4", tau=None):
        self.calls.append((dt, num_steps, method, tau))
        t = dt * torch.arange(num_steps + 1, dtype=q0.dtype)[None, :, None]
        return q0[:, None] + qd0[:, None] * t + 0.5 * params[:, None] * t**2, qd0[:, None] + params[:, None] * t


def test_shooting_residuals_roll_each_window_out_from_its_start():
    """A model with acceleration a against data with acceleration b (both exact): the residual j steps
    into a window of k is (a - b) (j / k)^2, so at each window's end it is the acceleration error;
    velocities: (a - b) j dt / (k dt) = (a - b) j / k. Steps, integrator and inputs reach the rollout."""
    model = ConstantAcceleration()
    B, k, dt = 3, 4, 0.05
    q0 = torch.tensor([[0.1, -0.2], [0.0, 0.3], [1.0, 1.0]], dtype=F64)
    qd0 = torch.tensor([[0.5, 0.0], [-1.0, 0.2], [0.0, 0.0]], dtype=F64)
    a = torch.tensor([[1.0, 2.0], [0.0, -1.0], [3.0, 0.5]], dtype=F64)
    b = torch.tensor([[0.0, 2.5], [0.0, 1.0], [1.0, 0.5]], dtype=F64)
    q_windows, qd_windows = ConstantAcceleration().rollout(q0, qd0, b, dt, k)
    tau = torch.zeros(B, k, 1, dtype=F64)
    err, err_v = shooting_residuals(model, q0, qd0, a, dt, q_windows, "leapfrog", tau=tau, qd_windows=qd_windows)
    j = torch.arange(1, k + 1, dtype=F64)[None, :, None]
    torch.testing.assert_close(err, (a - b)[:, None] * (j / k) ** 2, rtol=1e-10, atol=1e-10)
    torch.testing.assert_close(err_v, (a - b)[:, None] * (j / k), rtol=1e-10, atol=1e-10)
    (called,) = model.calls
    assert called[:3] == (dt, k, "leapfrog") and called[3] is tau
    # no velocity windows: no velocity residuals; a time unit of 2 s doubles nothing but the span
    err2, none = shooting_residuals(model, q0, qd0, a, dt, q_windows, time_scale=2.0)
    assert none is None
    torch.testing.assert_close(err2, 4.0 * err, rtol=1e-12, atol=0)


def test_identification_and_training_use_the_one_shooting_residual(monkeypatch):
    """Both objectives go through losses.shooting_residuals: identification calls it, training's
    trajectory matching calls losses.trajectory_batch_loss, which calls it."""
    import lnn_torch.identification.learned as identification
    import lnn_torch.training.losses as losses
    import lnn_torch.training.module as module

    assert identification.shooting_residuals is shooting_residuals
    assert module.trajectory_batch_loss is losses.trajectory_batch_loss
    assert "shooting_residuals" in losses.trajectory_batch_loss.__code__.co_names


# ---------------------------------------------------------------------------- loss terms
def test_power_balance_subtracts_the_trapezoid_work_of_the_forces():
    H = torch.tensor([[1.0, 1.0, 1.0, 1.0], [0.0, 2.0, 4.0, 6.0]], dtype=F64)
    power = torch.tensor([[2.0, 2.0, 2.0, 2.0], [0.0, 1.0, 2.0, 3.0]], dtype=F64)
    dt = 0.5
    # work since the first point: trapezoids of 0.5 dt (p_i + p_i+1), accumulated
    work = torch.tensor([[0.0, 1.0, 2.0, 3.0], [0.0, 0.25, 1.0, 2.25]], dtype=F64)
    torch.testing.assert_close(power_balance(H, power, dt), H - work, rtol=1e-12, atol=1e-12)


def test_energy_variance_and_the_huber_terms_by_hand():
    H = torch.tensor([[1.0, 2.0, 3.0]], dtype=F64)
    T = torch.tensor([[0.0, 1.0, 2.0]], dtype=F64)
    V = torch.tensor([[2.0, 2.0, 2.0]], dtype=F64)
    var = 2.0 / 3.0  # population variance of (1, 2, 3) and of (0, 1, 2)
    tiny = 1e-6 * 1.0**2 + 1e-12  # mean |T| = 1
    torch.testing.assert_close(energy_variance(H, T, V), torch.tensor(var / (var + tiny), dtype=F64))
    pred = torch.tensor([[0.5, 3.0], [-2.0, 0.2]], dtype=F64)
    target = torch.tensor([[0.0, 0.0], [0.0, 0.0]], dtype=F64)
    rms = torch.tensor([1.0, 2.0], dtype=F64)
    torch.testing.assert_close(acceleration_loss(pred, target, rms, 1.0), huber(pred / rms, 1.0))
    torch.testing.assert_close(acceleration_loss(pred, target, rms, 0.3), huber(pred / rms, 0.3))
    torch.testing.assert_close(torque_loss(pred, target, 0.3), huber(pred, 0.3))


def synthetic_terms(C=2, L=4, dof=2, n_u=1, seed=0):
    g = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.randn(*s, generator=g, dtype=F64)  # noqa: E731
    return {"pred": r(C * L, dof), "target": r(C * L, dof), "rms": r(dof).abs() + 0.5, "H": r(C * L),
            "T": r(C * L).abs(), "V": r(C * L), "power": r(C * L), "tau_pred": r(C * L, n_u),
            "tau_target": r(C * L, n_u)}


def test_training_loss_assembles_its_parts_by_hand():
    """The total is huber + energy_weight x energy_var (power balance where the terms hold a power) +
    torque_weight x torque; a part is there exactly when its terms are."""
    C, L = 2, 4
    t = synthetic_terms(C, L)
    loss, parts = training_loss(t, C, L, huber_delta=0.7, energy_weight=0.3, torque_weight=2.0, dt=0.1)
    H = t["H"].reshape(C, L)
    p = t["power"].reshape(C, L)
    W = torch.stack([torch.zeros(C, dtype=F64)]
                    + [0.05 * (p[:, :i].sum(1) + p[:, 1:i + 1].sum(1)) for i in range(1, L)], 1)
    e = H - W
    T, V = t["T"].reshape(C, L), t["V"].reshape(C, L)
    ev = (e.var(1, unbiased=False) / (T.var(1, unbiased=False) + V.var(1, unbiased=False)
                                       + 1e-6 * T.abs().mean(1) ** 2 + 1e-12)).mean()
    expected = {"huber": huber((t["pred"] - t["target"]) / t["rms"], 0.7), "energy_var": ev,
                "torque": huber(t["tau_pred"] - t["tau_target"], 0.7)}
    assert set(parts) == set(expected)
    for name in expected:
        torch.testing.assert_close(parts[name], expected[name], rtol=1e-12, atol=1e-14)
    torch.testing.assert_close(loss, expected["huber"] + 0.3 * ev + 2.0 * expected["torque"], rtol=1e-12, atol=1e-14)
    # without power: energy_var of H itself; without H or tau_pred: no such parts
    no_power = {k: v for k, v in t.items() if k != "power"}
    _, parts = training_loss(no_power, C, L, energy_weight=0.3)
    torch.testing.assert_close(parts["energy_var"], energy_variance(H, T, V), rtol=1e-12, atol=0)
    only = {k: t[k] for k in ("pred", "target", "rms")}
    loss, parts = training_loss(only, C, L, energy_weight=0.3, torque_weight=2.0)
    assert set(parts) == {"huber"} and loss is parts["huber"]


def test_trajectory_loss_by_hand():
    err = torch.tensor([[[0.5, -3.0], [1.0, 0.1]]], dtype=F64)
    err_v = torch.tensor([[[2.0, 0.0], [-0.4, 0.1]]], dtype=F64)
    loss, parts = trajectory_loss(err, err_v, huber_delta=1.0, velocity_weight=0.25)
    torch.testing.assert_close(parts["trajectory"], huber(err, 1.0))
    torch.testing.assert_close(parts["trajectory_velocity"], huber(err_v, 1.0))
    torch.testing.assert_close(loss, huber(err, 1.0) + 0.25 * huber(err_v, 1.0))
    loss, parts = trajectory_loss(err, None, huber_delta=0.5)
    assert set(parts) == {"trajectory"}
    torch.testing.assert_close(loss, huber(err, 0.5))


# ---------------------------------------------------------------------------- the module, before and after
def old_assembly(module, batch):
    """The LightningModule's acceleration loss as it assembled it itself before ``lnn_torch.training.losses``
    held the assembly (the code of commit 335e6c3, written out)."""
    F = torch.nn.functional
    C, L, _ = batch["q"].shape
    flat = [batch[k].reshape(C * L, -1) for k in ("q", "qd", "qdd", "params")]
    tau = batch["tau"].reshape(C * L, -1) if "tau" in batch else None
    out = module.training_terms(*flat, tau, C)
    rms = out["rms"]
    huber_ = F.huber_loss(out["pred"] / rms, out["target"] / rms, delta=module.hparams.huber_delta)
    loss, parts = huber_, {"huber": huber_}
    if "H" in out:
        H, T, V = (out[k].reshape(C, L) for k in ("H", "T", "V"))
        if "power" in out:
            dt_norm = (module.data_dt or 1.0) / float(module.model.normalizer.time_scale)
            power = out["power"].reshape(C, L)
            step = 0.5 * dt_norm * (power[:, 1:] + power[:, :-1])
            H = H - torch.cat([torch.zeros_like(H[:, :1]), step.cumsum(1)], 1)
        parts["energy_var"] = energy_variance(H, T, V)
        loss = loss + module.hparams.energy_weight * parts["energy_var"]
    if "tau_pred" in out:
        one = torch.ones_like(out["tau_target"][0])
        parts["torque"] = F.huber_loss(out["tau_pred"] / one, out["tau_target"] / one, delta=module.hparams.huber_delta)
        loss = loss + module.hparams.torque_weight * parts["torque"]
    return loss, parts


def old_trajectory_loss(module, batch):
    """The module's trajectory-matching loss before it used ``losses.shooting_residuals`` (commit 335e6c3)."""
    F = torch.nn.functional
    q, qd = batch["q"], batch["qd"]
    C, L, _ = q.shape
    tau = batch["tau"][:, :-1] if "tau" in batch else None
    dt = module.data_dt or 1.0
    qs, qds = module.model.rollout(q[:, 0], qd[:, 0], batch["params"][:, 0], dt, L - 1,
                                   module.hparams.trajectory_integrator, tau=tau)
    norm = module.model.normalizer
    span = (L - 1) * dt / float(norm.time_scale)
    scale = norm.coord_scale.to(q.dtype)
    err = (qs[:, 1:] - q[:, 1:]) / scale / (0.5 * span**2)
    loss = F.huber_loss(err, torch.zeros_like(err), delta=module.hparams.huber_delta)
    parts = {"trajectory": loss}
    if module.hparams.trajectory_velocity_weight > 0:
        err_v = (qds[:, 1:] - qd[:, 1:]) * (float(norm.time_scale) / scale) / span
        parts["trajectory_velocity"] = F.huber_loss(err_v, torch.zeros_like(err_v), delta=module.hparams.huber_delta)
        loss = loss + module.hparams.trajectory_velocity_weight * parts["trajectory_velocity"]
    return loss, parts


def fixed_batch(system, C=3, L=6, dt=0.01, seed=0):
    """``C`` chunks of ``L`` points of the scene's own motion (RK4 at ``dt``, float64) from seeded
    start states and parameters (the scene's sampler), with inputs for an actuated scene."""
    g = torch.Generator().manual_seed(seed)
    params = torch.as_tensor(system.sample_params(np.random.default_rng(seed), C), dtype=F64)
    q0 = 2 * torch.rand(C, system.dof, generator=g, dtype=F64) - 1
    qd0 = 2 * torch.rand(C, system.dof, generator=g, dtype=F64) - 1
    tau = 0.3 * torch.randn(C, L, system.num_inputs, generator=g, dtype=F64) if system.num_inputs else None
    q, qd = integrators.rollout(system.acceleration, q0, qd0, params, dt, L - 1, "rk4",
                                tau=None if tau is None else tau[:, :-1])
    flat = lambda x: x.reshape(C * L, -1)  # noqa: E731
    qdd = system.acceleration(flat(q), flat(qd), flat(params[:, None].expand(C, L, -1)),
                              None if tau is None else flat(tau)).reshape(C, L, -1)
    batch = {"q": q, "qd": qd, "qdd": qdd, "params": params[:, None].expand(C, L, -1).clone()}
    if tau is not None:
        batch["tau"] = tau
    return batch


# the box model's losses on ``fixed_batch`` (float64; pretrained:double_pendulum_box), as the module computed
# them before the losses moved to ``lnn_torch.training.losses`` (commit 335e6c3): energy_weight 0.1,
# trajectory_velocity_weight 0.5
SHIPPED_BEFORE = {"huber": 1.563899052850841e-07, "energy_var": 3.639888997182706e-08, "loss": 1.600297942822668e-07,
                  "trajectory": 5.526111403220439e-08, "trajectory_velocity": 7.921772710517591e-08,
                  "trajectory_loss": 9.486997758479234e-08}


def shipped_model_losses():
    module = load_model("pretrained:double_pendulum_box").double()  # the shipped default when they were recorded
    module.hparams.energy_weight = 0.1
    module.data_dt = 0.01
    batch = fixed_batch(module.system)
    values = {}
    with torch.no_grad():
        loss, parts = module.batch_loss(batch)
        values.update({k: float(v) for k, v in parts.items()}, loss=float(loss))
        module.hparams.loss = "trajectory"
        module.hparams.trajectory_velocity_weight = 0.5
        loss, parts = module.batch_loss(batch)
        values.update({k: float(v) for k, v in parts.items()}, trajectory_loss=float(loss))
    return values


def test_the_shipped_models_losses_on_a_fixed_batch_are_the_values_before_the_refactor():
    values = shipped_model_losses()
    assert set(values) == set(SHIPPED_BEFORE)
    for name, before in SHIPPED_BEFORE.items():
        assert values[name] == pytest.approx(before, rel=1e-9, abs=0), name


@pytest.mark.parametrize("scene, kw", [("double_pendulum", {"energy_weight": 0.1}),
                                       ("actuated_double_pendulum", {"energy_weight": 0.05, "torque_weight": 0.3}),
                                       ("actuated_double_pendulum", {"variant": "delan", "torque_weight": 1.0,
                                                                     "huber_delta": 0.2})])
def test_module_losses_equal_the_assembly_the_module_had_before(scene, kw):
    """On a fixed batch, the module's loss and parts (acceleration and trajectory matching) equal, to
    the bit, the module's own code before the refactor (``old_assembly``, ``old_trajectory_loss``)."""
    torch.manual_seed(0)
    module = LNNModule(scene=scene, hidden_dims=[16, 16], val_rollouts=0, compile=False, **kw).double()
    system = get_system(scene)
    batch = fixed_batch(system)
    flat = lambda x: x.reshape(-1, x.shape[-1])  # noqa: E731
    module.model.fit_normalizer({"q": flat(batch["q"]), "qd": flat(batch["qd"]), "qdd": flat(batch["qdd"]),
                                 "params": batch["params"][:, 0],
                                 **({"tau": flat(batch["tau"])} if "tau" in batch else {})})
    module.data_dt = 0.01
    new, new_parts = module.batch_loss(batch)
    old, old_parts = old_assembly(module, batch)
    assert set(new_parts) == set(old_parts) == {"huber", "energy_var", "torque"} & (
        {"huber"} | ({"energy_var"} if kw.get("energy_weight") else set())
        | ({"torque"} if kw.get("torque_weight") else set()))
    assert torch.equal(new, old) and all(torch.equal(new_parts[k], old_parts[k]) for k in old_parts)
    module.hparams.loss = "trajectory"
    for weight in (0.0, 0.5):
        module.hparams.trajectory_velocity_weight = weight
        new, new_parts = module.batch_loss(batch)
        old, old_parts = old_trajectory_loss(module, batch)
        assert set(new_parts) == set(old_parts)
        assert torch.equal(new, old) and all(torch.equal(new_parts[k], old_parts[k]) for k in old_parts)
