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


def evaluation_plots(result: dict, output_dir, system) -> list:
    """Trajectories, energy drift, error growth vs the predictability limit, and (double pendulum) a
    frame strip of the first out-of-distribution case. Returns the PNG paths."""
    from pathlib import Path

    output_dir = Path(output_dir)
    arr = result["_arrays"]
    dt = result["dt"]
    paths = []
    fig = trajectory_figure(arr["q_true"][0], arr["q_model"][0], dt, system.coord_names)
    paths.append(output_dir / "trajectory.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    t = torch.arange(arr["drift"].shape[1]) * dt
    fig, ax = plt.subplots(figsize=(7, 2.8))
    ax.plot(t, arr["drift"].median(0).values, label="median")
    ax.plot(t, arr["drift"].amax(0), label="max")
    ax.set_yscale("log")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("|E(t)-E(0)| / (Vmax-Vmin)")
    ax.legend()
    fig.tight_layout()
    paths.append(output_dir / "energy_drift.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    def err(q):
        e = torch.remainder(q - arr["q_true"] + torch.pi, 2 * torch.pi) - torch.pi
        return e.abs().amax(-1).median(0).values.clamp_min(1e-16)

    fig, ax = plt.subplots(figsize=(7, 2.8))
    ax.plot(t, err(arr["q_model"]), label="model")
    ax.plot(t, err(arr["q_exact"]), label="exact system, 1e-6 rad off")
    ax.axhline(0.1, color="k", lw=0.8, ls=":")
    ax.set_yscale("log")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("median max |angle error| [rad]")
    ax.legend()
    fig.tight_layout()
    paths.append(output_dir / "error_growth.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    if "_ood_arrays" in result and hasattr(system, "positions"):
        ood = result["_ood_arrays"]
        n = ood["q_true"].shape[1]
        frames = [int(i) for i in torch.linspace(0, n - 1, 6)]
        fig, axes = plt.subplots(1, len(frames), figsize=(2.2 * len(frames), 2.6))
        p = ood["params"][:1]
        reach = float(p[0, 2] + p[0, 3]) * 1.1
        for ax, k in zip(axes, frames):
            for q, style, label in ((ood["q_true"][0, k], "k-o", "true"), (ood["q_model"][0, k], "C1--o", "model")):
                xy = system.positions(q[None], p)[0]
                ax.plot([0, xy[0, 0], xy[1, 0]], [0, xy[0, 1], xy[1, 1]], style, ms=4, label=label)
            ax.set_xlim(-reach, reach)
            ax.set_ylim(-reach, reach)
            ax.set_aspect("equal")
            ax.set_title(f"t = {k * dt:.1f} s", fontsize=9)
            ax.set_xticks([])
            ax.set_yticks([])
        axes[0].legend(fontsize=7, loc="upper left")
        fig.tight_layout()
        paths.append(output_dir / "frames_ood_case1.png")
        fig.savefig(paths[-1], dpi=110)
        plt.close(fig)
    return paths
