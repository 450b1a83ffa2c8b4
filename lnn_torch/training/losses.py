"""Training losses (pure functions): the LightningModule (``lnn_torch.training.module``) and identification
(``lnn_torch.identification.learned``) assemble their objectives from these.

* ``training_loss``: the acceleration objective from a model's ``training_terms`` (Huber on
  accelerations, the energy-conservation / power-balance term, the inverse-dynamics torque term);
* ``trajectory_loss``: trajectory matching from multiple-shooting residuals;
* ``shooting_residuals``: multiple shooting (each window rolled out from its own start state and
  compared with the data), the one used by training and by identification;
* ``acceleration_batch_loss`` and ``trajectory_batch_loss``: the loss of one training batch of
  contiguous chunks (``(C, L, ...)`` tensors, as ``TrajectoryDataModule`` gives them), assembled from
  the above; ``LNNModule.training_step`` is one call of one of them.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ..networks.calls import counting_failures


def acceleration_loss(qdd_pred_norm: torch.Tensor, qdd_true_norm: torch.Tensor, accel_rms: torch.Tensor,
                      delta: float = 1.0) -> torch.Tensor:
    """Huber loss on normalised accelerations, each coordinate divided by its rms (loss weighting only)."""
    return F.huber_loss(qdd_pred_norm / accel_rms, qdd_true_norm / accel_rms, delta=delta)


def energy_variance(H: torch.Tensor, T: torch.Tensor, V: torch.Tensor) -> torch.Tensor:
    """Scale-invariant energy-conservation term over contiguous chunks.

    ``H, T, V``: ``(C, L)`` the model's Hamiltonian, kinetic and potential terms at ``L`` consecutive
    points of ``C`` chunks. Returns the mean over chunks of ``var(H) / (var(T) + var(V) + tiny)``.

    A raw ``var(H)`` can be lowered by shrinking the whole Lagrangian (``L -> cL`` leaves the
    accelerations unchanged and divides ``var(H)`` by ``c^2``); the ratio is invariant under that
    rescaling and under adding a constant to V. For exact dynamics ``H`` is constant along a chunk
    while ``T`` and ``V`` exchange energy, so the ratio is 0; ``tiny`` keeps chunks at rest finite.
    """
    var_h = H.var(dim=-1, unbiased=False)
    spread = T.var(dim=-1, unbiased=False) + V.var(dim=-1, unbiased=False)
    tiny = 1e-6 * T.abs().mean(-1).pow(2) + 1e-12
    return (var_h / (spread + tiny)).mean()


def power_balance(H: torch.Tensor, power: torch.Tensor, dt: float) -> torch.Tensor:
    """``H - W``: the Hamiltonian ``H (C, L)`` along each chunk minus the work ``W`` done on it by the
    model's own forces since the chunk's first point, from their power ``(C, L)`` (trapezoid rule at
    step ``dt``). Constant along a chunk for exact dynamics with generalised forces."""
    step = 0.5 * dt * (power[:, 1:] + power[:, :-1])
    return H - torch.cat([torch.zeros_like(H[:, :1]), step.cumsum(1)], 1)


def torque_loss(tau_pred: torch.Tensor, tau_target: torch.Tensor, delta: float = 1.0) -> torch.Tensor:
    """Huber loss on the inputs (motor torques) the model's inverse dynamics predict, both already
    divided by the inputs' rms."""
    return acceleration_loss(tau_pred, tau_target, torch.ones_like(tau_target[0]), delta)


def training_loss(terms: dict, chunks: int, length: int, *, huber_delta: float = 1.0, energy_weight: float = 0.0,
                  torque_weight: float = 0.0, dt: float = 1.0, acceleration_weight: float = 1.0
                  ) -> tuple[torch.Tensor, dict]:
    """``(loss, parts)``: the acceleration objective and its named parts from a model's training terms
    (``DynamicsModel.training_terms``) on ``chunks`` contiguous chunks of ``length`` points each (rows
    in chunk order).

    * ``huber``: ``acceleration_loss`` of ``terms["pred"]`` against ``terms["target"]`` (rms ``terms["rms"]``),
      weighted by ``acceleration_weight`` (0: the inverse-dynamics torque term alone, as a robot's
      identification fits measured torques);
    * ``energy_var`` (where the terms hold ``H, T, V``): ``energy_variance`` per chunk, of ``H`` or,
      with the forces' ``power``, of the power balance ``H - W`` (``power_balance`` at the data's step
      ``dt`` in normalised time), weighted by ``energy_weight``;
    * ``torque`` (where the terms hold ``tau_pred``): ``torque_loss``, weighted by ``torque_weight``.
    """
    huber = acceleration_loss(terms["pred"], terms["target"], terms["rms"], huber_delta)
    loss, parts = (huber if acceleration_weight == 1 else acceleration_weight * huber), {"huber": huber}
    if "H" in terms:
        H, T, V = (terms[k].reshape(chunks, length) for k in ("H", "T", "V"))
        if "power" in terms:
            H = power_balance(H, terms["power"].reshape(chunks, length), dt)
        parts["energy_var"] = energy_variance(H, T, V)
        loss = loss + energy_weight * parts["energy_var"]
    if "tau_pred" in terms:
        parts["torque"] = torque_loss(terms["tau_pred"], terms["tau_target"], huber_delta)
        loss = loss + torque_weight * parts["torque"]
    return loss, parts


def shooting_residual(q_rollout: torch.Tensor, q_data: torch.Tensor, span: float,
                      scale: torch.Tensor | None = None) -> torch.Tensor:
    """Position residuals of multiple shooting: ``(..., k + 1, dof)`` rolled-out and observed positions
    of windows of ``k`` steps (each window's first point its start) give ``(..., k, dof)``, the error at
    every point after the start, divided by ``scale`` (coordinates; None: as given) and by
    ``span^2 / 2`` with ``span`` the window's duration (``k dt``): acceleration units, so the window's
    length does not weight it."""
    err = q_rollout[..., 1:, :] - q_data[..., 1:, :]
    if scale is not None:
        err = err / scale
    return err / (0.5 * span**2)


def shooting_velocity_residual(qd_rollout: torch.Tensor, qd_data: torch.Tensor, span: float,
                               scale: torch.Tensor | None = None, time_scale: float = 1.0) -> torch.Tensor:
    """Velocity residuals of multiple shooting (shapes as ``shooting_residual``): the error after each
    window's start in units of ``scale / time_scale`` (``scale`` None: 1), divided by ``span``."""
    factor = time_scale if scale is None else time_scale / scale
    return (qd_rollout[..., 1:, :] - qd_data[..., 1:, :]) * factor / span


def shooting_residuals(model, q0: torch.Tensor, qd0: torch.Tensor, params: torch.Tensor, dt: float,
                       q_windows: torch.Tensor, integrator: str = "rk4", tau: torch.Tensor | None = None,
                       qd_windows: torch.Tensor | None = None, scale: torch.Tensor | None = None,
                       time_scale: float = 1.0) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Multiple shooting: each of ``B`` windows of ``k + 1`` points, ``q_windows (B, k + 1, dof)``, rolled
    out ``k`` steps of ``dt`` (s) from its start state ``q0, qd0 (B, dof)`` with ``model.rollout``
    (parameters ``params (B, P)``, inputs ``tau (B, k, n_u)`` held over each step) and compared with
    it. Returns the position residuals ``(B, k, dof)`` (``shooting_residual``, divided by ``scale`` and
    by the window's duration in units of ``time_scale`` s) and, where ``qd_windows`` is given, the
    velocity residuals (``shooting_velocity_residual``; else None)."""
    k = q_windows.shape[-2] - 1
    qs, qds = model.rollout(q0, qd0, params, dt, k, integrator, tau=tau)
    span = k * dt / time_scale  # the window in the residuals' time unit
    err = shooting_residual(qs, q_windows, span, scale)
    err_v = None if qd_windows is None else shooting_velocity_residual(qds, qd_windows, span, scale, time_scale)
    return err, err_v


def trajectory_loss(err: torch.Tensor, err_v: torch.Tensor | None = None, *, huber_delta: float = 1.0,
                    velocity_weight: float = 0.0) -> tuple[torch.Tensor, dict]:
    """``(loss, parts)`` of trajectory matching: Huber on the position residuals of multiple shooting
    (``trajectory``) plus ``velocity_weight`` x Huber on the velocity residuals
    (``trajectory_velocity``, where ``velocity_weight > 0``)."""
    loss = F.huber_loss(err, torch.zeros_like(err), delta=huber_delta)
    parts = {"trajectory": loss}
    if velocity_weight > 0:
        parts["trajectory_velocity"] = F.huber_loss(err_v, torch.zeros_like(err_v), delta=huber_delta)
        loss = loss + velocity_weight * parts["trajectory_velocity"]
    return loss, parts


def acceleration_batch_loss(model, batch: dict, pass_fn, *, huber_delta: float = 1.0, energy_weight: float = 0.0,
                            torque_weight: float = 0.0, dt: float | None = None, acceleration_weight: float = 1.0
                            ) -> tuple[torch.Tensor, dict]:
    """``(loss, parts)`` of ``training_loss`` on one batch of ``C`` chunks of ``L`` contiguous points:
    ``batch`` holds ``q, qd, qdd (C, L, dof)``, ``params (C, L, P)`` and, for a scene with inputs,
    ``tau (C, L, n_u)`` (SI). ``pass_fn(q, qd, qdd, params, tau, chunks)`` gives the model's training
    terms on the flattened rows (``DynamicsModel.training_terms``; compiled or eager); ``chunks`` is
    ``C`` where each chunk has one parameter vector (the model then conditions once per chunk), else
    None. ``dt``: the data's sampling interval in s (the power-balance term integrates the forces'
    power over it, in the model's normalised time; None: 1)."""
    C, L, _ = batch["q"].shape
    flat = [batch[k].reshape(C * L, -1) for k in ("q", "qd", "qdd", "params")]
    tau = batch["tau"].reshape(C * L, -1) if "tau" in batch else None
    params = batch["params"]
    shared = params.shape[1] == 1 or bool((params == params[:, :1]).all())
    out = pass_fn(*flat, tau, C if shared else None)
    dt_norm = (dt or 1.0) / float(model.normalizer.time_scale) if "power" in out else 1.0
    loss, parts = training_loss(out, C, L, huber_delta=huber_delta, energy_weight=energy_weight,
                                torque_weight=torque_weight, dt=dt_norm, acceleration_weight=acceleration_weight)
    return with_prior(model, loss, parts)


def with_prior(model, loss: torch.Tensor, parts: dict) -> tuple[torch.Tensor, dict]:
    """``loss`` plus the model's priors on its physical parameters (``model.regularization()``, e.g.
    a grey box's pull towards its robot description), logged as the part ``prior``; unchanged where it
    has none."""
    prior = model.regularization() if hasattr(model, "regularization") else None
    if prior is None:
        return loss, parts
    return loss + prior, {**parts, "prior": prior}


def trajectory_batch_loss(model, batch: dict, *, dt: float | None = None, integrator: str = "rk4",
                          huber_delta: float = 1.0, velocity_weight: float = 0.0) -> tuple[torch.Tensor, dict]:
    """``(loss, parts)`` of ``trajectory_loss`` on one batch (shapes as ``acceleration_batch_loss``; no
    ``qdd`` needed): multiple shooting, each chunk rolled out ``L - 1`` steps of ``dt`` (s) from its
    first state with ``integrator``, driven by its inputs, against its positions (and, with
    ``velocity_weight``, velocities); residuals in the model's normalised coordinates and time."""
    q, qd = batch["q"], batch["qd"]
    if q.shape[1] < 2:
        raise ValueError("trajectory matching needs chunks of at least 2 points (data.chunk_len >= 2)")
    tau = batch["tau"][:, :-1] if "tau" in batch else None
    norm = model.normalizer
    with counting_failures(model):
        err, err_v = shooting_residuals(model, q[:, 0], qd[:, 0], batch["params"][:, 0], dt or 1.0, q, integrator,
                                        tau=tau, qd_windows=qd if velocity_weight > 0 else None,
                                        scale=norm.coord_scale.to(q.dtype), time_scale=float(norm.time_scale))
    return with_prior(model, *trajectory_loss(err, err_v, huber_delta=huber_delta, velocity_weight=velocity_weight))
