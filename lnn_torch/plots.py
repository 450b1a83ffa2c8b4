"""Matplotlib figures (headless): trajectories and true energy over time."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402


def trajectory_figure(q_true: torch.Tensor, q_pred: torch.Tensor, dt: float, names):
    """Predicted vs true coordinates of one trajectory: ``(T, dof)`` each."""
    t = torch.arange(q_true.shape[0]) * dt
    fig, axes = plt.subplots(q_true.shape[1], 1, figsize=(7, 2.2 * q_true.shape[1]), sharex=True, squeeze=False)
    for i, ax in enumerate(axes[:, 0]):
        ax.plot(t, q_true[:, i], "k-", lw=1.5, label="true")
        ax.plot(t, q_pred[: len(t), i], "C1--", lw=1.2, label="model")
        ax.set_ylabel(names[i])
    axes[0, 0].legend(loc="upper right")
    axes[-1, 0].set_xlabel("t [s]")
    fig.tight_layout()
    return fig


def energy_figure(system, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor, dt: float):
    """Closed-form energy drift of rollouts ``(B, T, dof)`` relative to V_max - V_min."""
    from .evaluation import energy_drift

    drift = energy_drift(system, q.double(), qd.double(), params.double())
    t = torch.arange(q.shape[1]) * dt
    fig, ax = plt.subplots(figsize=(7, 2.5))
    for b in range(drift.shape[0]):
        ax.plot(t, drift[b])
    ax.set_xlabel("t [s]")
    ax.set_ylabel("|E(t) - E(0)| / (V_max - V_min)")
    fig.tight_layout()
    return fig
