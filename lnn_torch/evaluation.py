"""Evaluation metrics (pure functions): acceleration error, rollout divergence, true-energy drift.

Energies are always the scene's closed-form energy of the model's rollout, relative to the scene's
energy scale ``V_max - V_min`` -- never the model's own (normalised) energy.
"""

from __future__ import annotations

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

    ``q_pred, q_true``: ``(B, T, dof)``. Angle errors are wrapped to (-pi, pi].
    """
    err = q_pred - q_true
    if angle_mask is not None:
        mask = torch.as_tensor(angle_mask, dtype=torch.bool, device=err.device)
        wrapped = torch.remainder(err + torch.pi, 2 * torch.pi) - torch.pi
        err = torch.where(mask, wrapped, err)
    over = err.abs().amax(-1) > threshold  # (B, T)
    T = over.shape[1]
    first = torch.where(over.any(1), over.float().argmax(1), torch.full_like(over[:, 0], T - 1, dtype=torch.long))
    return first.to(q_pred.dtype) * dt


def energy_drift(system, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
    """``|E(t) - E(0)| / (V_max - V_min)`` of the scene's closed-form energy: ``(B, T)``."""
    p = params[:, None, :].expand(-1, q.shape[1], -1)
    E = system.energy(q, qd, p)
    return (E - E[:, :1]).abs() / system.energy_scale(params)[:, None]


def rollout_metrics(accel_fn: Callable, system, q_true: torch.Tensor, qd_true: torch.Tensor, params: torch.Tensor,
                    dt: float, method: str = "rk4", thresholds=(0.1, 0.5)) -> dict:
    """Roll ``accel_fn`` out from the true initial states and compare with the true trajectories.

    Returns per-trajectory tensors: ``divergence_time@<thr>`` for each threshold, ``energy_drift_mean``
    and ``energy_drift_max`` (closed-form energy), and the rolled-out ``q``/``qd``.
    """
    q, qd = rollout(accel_fn, q_true[:, 0], qd_true[:, 0], params, dt, q_true.shape[1] - 1, method)
    drift = energy_drift(system, q, qd, params)
    out = {f"divergence_time@{thr:g}": divergence_time(q, q_true, dt, thr, system.angle_mask) for thr in thresholds}
    out["energy_drift_mean"] = drift.mean(1)
    out["energy_drift_max"] = drift.amax(1)
    out["q"], out["qd"] = q, qd
    return out
