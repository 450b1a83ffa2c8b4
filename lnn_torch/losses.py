"""Training losses (pure functions)."""

from __future__ import annotations

import torch
import torch.nn.functional as F


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
