"""Evaluation metrics (pure functions): acceleration error, rollout divergence, true-energy drift.

Energies are always the scene's closed-form energy of the model's rollout, relative to the scene's
energy scale ``V_max - V_min`` -- never the model's own (normalised) energy.
"""

from __future__ import annotations

import contextlib
from typing import Callable

import torch

from .integrators import rollout


def relative_l2(pred: torch.Tensor, true: torch.Tensor, dim=None) -> torch.Tensor:
    """``||pred - true|| / ||true||`` over all entries (``dim=None``) or along ``dim``."""
    if dim is None:
        return (pred - true).norm() / true.norm().clamp_min(1e-30)
    return (pred - true).norm(dim=dim) / true.norm(dim=dim).clamp_min(1e-30)


def acceleration_errors(pred: torch.Tensor, true: torch.Tensor, coord_names=None) -> dict:
    """Relative L2 errors: ``total`` and per coordinate. pred, true ``(..., dof)``."""
    flat_p, flat_t = pred.reshape(-1, pred.shape[-1]), true.reshape(-1, true.shape[-1])
    out = {"total": float(relative_l2(flat_p, flat_t))}
    names = coord_names or [f"q{i}" for i in range(pred.shape[-1])]
    for i, name in enumerate(names):
        out[name] = float(relative_l2(flat_p[:, i], flat_t[:, i]))
    return out


def divergence_time(q_pred: torch.Tensor, q_true: torch.Tensor, dt: float, threshold: float,
                    angle_mask=None) -> torch.Tensor:
    """Time (s) until the max coordinate error first exceeds ``threshold``; the horizon if never.

    ``q_pred, q_true``: ``(B, T, dof)``. Angle errors are wrapped to (-pi, pi]. A non-finite
    prediction counts as beyond the threshold.
    """
    err = q_pred - q_true
    if angle_mask is not None:
        mask = torch.as_tensor(angle_mask, dtype=torch.bool, device=err.device)
        wrapped = torch.remainder(err + torch.pi, 2 * torch.pi) - torch.pi
        err = torch.where(mask, wrapped, err)
    over = ~(err.abs().amax(-1) <= threshold)  # (B, T); NaN counts as over
    T = over.shape[1]
    first = torch.where(over.any(1), over.float().argmax(1), torch.full_like(over[:, 0], T - 1, dtype=torch.long))
    return first.to(q_pred.dtype) * dt


def energy_drift(system, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
    """``|E(t) - E(0)| / (V_max - V_min)`` of the scene's closed-form energy: ``(B, T)``."""
    p = params[:, None, :].expand(-1, q.shape[1], -1)
    E = system.energy(q, qd, p)
    return (E - E[:, :1]).abs() / system.energy_scale(params)[:, None]


def rollout_metrics(rollout_fn: Callable, system, q_true: torch.Tensor, qd_true: torch.Tensor, params: torch.Tensor,
                    dt: float, method: str = "rk4", thresholds=(0.1, 0.5)) -> dict:
    """Roll a model out from the true initial states and compare with the true trajectories.

    Args:
        rollout_fn: ``(q0, qd0, params, dt, num_steps, method) -> (q, qd)`` each ``(B, T, dof)``,
            e.g. ``model.rollout`` or ``closed_form_rollout(system)``.
        q_true, qd_true: ``(B, T, dof)`` true trajectories sampled every ``dt``; params ``(B, P)``.

    Returns per-trajectory tensors: ``divergence_time@<thr>`` for each threshold, ``energy_drift_mean``
    and ``energy_drift_max`` (closed-form energy; NaN for a non-finite rollout), ``finite`` (bool),
    and the rolled-out ``q``/``qd``.
    """
    q, qd = rollout_fn(q_true[:, 0], qd_true[:, 0], params, dt, q_true.shape[1] - 1, method)
    drift = energy_drift(system, q, qd, params)
    out = {f"divergence_time@{thr:g}": divergence_time(q, q_true, dt, thr, system.angle_mask) for thr in thresholds}
    out["finite"] = torch.isfinite(q).all(-1).all(-1) & torch.isfinite(qd).all(-1).all(-1)
    out["energy_drift_mean"] = drift.mean(1)
    out["energy_drift_max"] = drift.amax(1)
    out["q"], out["qd"] = q, qd
    return out


def closed_form_rollout(system) -> Callable:
    """``rollout_fn`` of a scene's closed-form dynamics (the ceiling rows of reports)."""

    def fn(q0, qd0, params, dt, num_steps, method="rk4"):
        return rollout(system.acceleration, q0, qd0, params, dt, num_steps, method)

    return fn


@contextlib.contextmanager
def counting_failures(model):
    """Within the block, a model whose accelerations can be undefined (the black-box LNN's singular
    Hessians) returns NaN there instead of raising, so that batched evaluations count them."""
    previous = getattr(model, "raise_on_singular", None)
    if previous is not None:
        model.raise_on_singular = False
    try:
        yield model
    finally:
        if previous is not None:
            model.raise_on_singular = previous


def learned_mass_matrix(model, q: torch.Tensor, params: torch.Tensor) -> torch.Tensor | None:
    """The model's mass matrix in its normalised units (float64) at SI states ``q (n, dof)``,
    ``params (n, P)``: ``(n, dof, dof)``; None for models without one (lnn, mlp, hnn)."""
    if not hasattr(model, "mass_matrix_norm"):
        return None
    with torch.no_grad():
        return model.mass_matrix(q.to(model.dtype), params.to(model.dtype)).double()


def condition_numbers(M: torch.Tensor) -> torch.Tensor:
    """Condition numbers of symmetric positive definite matrices ``(..., n, n)`` -> ``(...)``."""
    eig = torch.linalg.eigvalsh(M)
    return eig[..., -1] / eig[..., 0]
