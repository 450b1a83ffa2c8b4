"""Evaluation metrics: pure tensor functions (no models, no files).

Energies are always the scene's closed-form energy of a trajectory, relative to the scene's energy
scale ``V_max - V_min`` -- never a model's own (normalised) energy. ``lnn_torch.evaluation`` composes
these into reports.
"""

from __future__ import annotations

import math

import torch

from ..mechanics.angles import wrap_angles
from ..mechanics.forces import input_force, power


def relative_l2(pred: torch.Tensor, true: torch.Tensor, dim=None) -> torch.Tensor:
    """``||pred - true|| / ||true||`` over all entries (``dim=None``) or along ``dim``."""
    if dim is None:
        return (pred - true).norm() / true.norm().clamp_min(1e-30)
    return (pred - true).norm(dim=dim) / true.norm(dim=dim).clamp_min(1e-30)


def acceleration_errors(pred: torch.Tensor, true: torch.Tensor, coord_names=None) -> dict:
    """Relative L2 errors of accelerations ``(B, T, dof)``: ``total``, per coordinate, and the median
    and 90th percentile over trajectories. A non-finite prediction is an infinite error: the totals and the
    error of each trajectory that holds one are ``inf`` (a model that gives NaN must not score well), and
    ``non_finite_fraction`` counts those points."""
    B, T, dof = pred.shape
    known = torch.isfinite(true).all(-1)  # (B, T): padding of shorter recordings is not a point
    finite = torch.isfinite(pred).all(-1) & known
    broken = known & ~finite  # (B, T)
    names = list(coord_names or [f"q{i}" for i in range(dof)])
    pred_f, true_f = pred[finite], true[finite]  # (n, dof)
    inf = float("inf")
    out = {"total": inf if broken.any() else float(relative_l2(pred_f, true_f))}
    for i, name in enumerate(names):
        out[name] = inf if broken.any() else float(relative_l2(pred_f[:, i], true_f[:, i]))
    per_traj = torch.stack([torch.tensor(inf, dtype=pred.dtype) if broken[b].any() else
                            relative_l2(pred[b][finite[b]], true[b][finite[b]]) for b in range(B)])
    per_traj = per_traj[known.any(1)]
    if per_traj.numel():
        out["per_trajectory_median"] = float(per_traj.median())
        ordered = per_traj.double().sort().values
        at = 0.9 * (len(ordered) - 1)  # (torch's linear interpolation; one with an inf in it is inf, not NaN)
        upper = ordered[math.ceil(at)]
        out["per_trajectory_p90"] = inf if math.isinf(upper) and at > math.floor(at) or math.isinf(
            ordered[math.floor(at)]) else float(torch.quantile(ordered, 0.9))
    out["non_finite_fraction"] = float(broken.double().sum() / known.double().sum().clamp_min(1))
    return out


def coordinate_error(q_pred: torch.Tensor, q_true: torch.Tensor, angle_mask=None) -> torch.Tensor:
    """The largest coordinate error at each time, ``(B, T)``; angle errors wrapped to (-pi, pi]."""
    err = q_pred - q_true
    if angle_mask is not None:
        err = wrap_angles(err, angle_mask)
    return err.abs().amax(-1)


def divergence_time(q_pred: torch.Tensor, q_true: torch.Tensor, dt: float, threshold: float,
                    angle_mask=None) -> torch.Tensor:
    """Time (s) until the max coordinate error first exceeds ``threshold``; the horizon if never.

    ``q_pred, q_true``: ``(B, T, dof)``. Angle errors are wrapped to (-pi, pi]. A non-finite
    prediction counts as beyond the threshold.
    """
    over = ~(coordinate_error(q_pred, q_true, angle_mask) <= threshold)  # (B, T); NaN counts as over
    T = over.shape[1]
    first = torch.where(over.any(1), over.float().argmax(1), torch.full_like(over[:, 0], T - 1, dtype=torch.long))
    return first.to(q_pred.dtype) * dt


def energy_drift(system, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
    """``|E(t) - E(0)| / (V_max - V_min)`` of the scene's closed-form energy along trajectories
    ``(B, T, dof)`` with parameters ``(B, P)``: ``(B, T)``."""
    E = system.energy(q, qd, params[:, None, :].expand(-1, q.shape[1], -1))
    return (E - E[:, :1]).abs() / system.energy_scale(params)[:, None]


def work_along(system, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor, tau: torch.Tensor | None,
               dt: float) -> torch.Tensor:
    """The true work of the scene's generalised forces along trajectories ``(B, T, dof)`` sampled every
    ``dt``, since ``t = 0``: ``(B, T)`` in J. Inputs ``tau (B, T - 1, n_u)`` are held over each
    interval, so their work ``tau_k . B^T (q_{k+1} - q_k)`` is exact; the dissipated work is the
    trapezoidal rule of ``qd . Q_diss``."""
    T = q.shape[1]
    p = params[:, None, :].expand(-1, T, -1)
    diss = power(qd, system.dissipative_force(q, qd, p))  # (B, T)
    step = 0.5 * dt * (diss[:, 1:] + diss[:, :-1])
    if tau is not None:
        step = step + power(q[:, 1:] - q[:, :-1], input_force(tau[:, : T - 1], system._force_maps()[0]))
    return torch.cat([torch.zeros_like(step[:, :1]), step.cumsum(1)], 1)


def power_balance_error(system, q, qd, params, tau, dt: float) -> torch.Tensor:
    """``|E(t) - E(0) - W(t)| / (V_max - V_min)`` along trajectories: ``(B, T)`` (the scene's true
    energy and work; the energy drift for a conservative scene)."""
    p = params[:, None, :].expand(-1, q.shape[1], -1)
    E = system.energy(q, qd, p)
    return (E - E[:, :1] - work_along(system, q, qd, params, tau, dt)).abs() / system.energy_scale(params)[:, None]


def normalized_rmse(pred: torch.Tensor, true: torch.Tensor) -> torch.Tensor:
    """Per component (last axis): ``sqrt(mean((pred - true)^2) / var(true))`` (Deep Lagrangian
    Networks' normalised error of torques); ``(..., n) -> (n,)``."""
    pred, true = pred.reshape(-1, pred.shape[-1]), true.reshape(-1, true.shape[-1])
    return ((pred - true).pow(2).mean(0) / true.var(0).clamp_min(1e-30)).sqrt()


def quartiles(x: torch.Tensor) -> dict:
    """``{"q25", "median", "q75"}`` of a 1-D tensor."""
    q = torch.quantile(x.double(), torch.tensor([0.25, 0.5, 0.75], dtype=torch.float64, device=x.device))
    return {"q25": float(q[0]), "median": float(q[1]), "q75": float(q[2])}


def condition_numbers(M: torch.Tensor) -> torch.Tensor:
    """Condition numbers of symmetric positive definite matrices ``(..., n, n)`` -> ``(...)``."""
    eig = torch.linalg.eigvalsh(M)
    return eig[..., -1] / eig[..., 0]


def scaled_matrix_error(M_true: torch.Tensor, M_model: torch.Tensor) -> torch.Tensor:
    """Relative Frobenius error of ``M_model`` after the best scale per system: ``(B, T, n, n)`` -> ``(B,)``.
    (A Lagrangian is defined up to a factor, so a learned mass matrix is compared up to one.)"""
    c = (M_true * M_model).sum((1, 2, 3)) / (M_model * M_model).sum((1, 2, 3))
    return ((M_true - c[:, None, None, None] * M_model).pow(2).sum((1, 2, 3)) / M_true.pow(2).sum((1, 2, 3))).sqrt()
