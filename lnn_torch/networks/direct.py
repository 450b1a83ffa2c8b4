"""Baseline: an MLP that predicts accelerations directly from ``(q, qd, theta)`` (a second-order
neural ODE; no Lagrangian structure, no energy)."""

from __future__ import annotations

import torch

from .base import DynamicsModel
from .layers import TangentMLP


class DirectMLP(DynamicsModel):
    """Baseline: an MLP that predicts normalised accelerations from ``(q, qd, theta)``."""

    variant = "mlp"
    has_energy = False

    def __init__(self, scene, hidden_dims=(128, 128), activation: str = "tanh") -> None:
        super().__init__(scene)
        self.net = TangentMLP(self.num_features + self.scene.dof + self.scene.num_params, list(hidden_dims),
                              self.scene.dof, activation)

    def acceleration_norm(self, q_norm, qd_norm, params_norm):
        phi, _ = self.features(q_norm)
        return self.net(torch.cat([phi, qd_norm, params_norm], -1))[0]
