"""Baseline: an MLP that predicts accelerations directly from ``(q, qd, theta)`` and, for an actuated
scene, the inputs ``tau`` (a second-order neural ODE; no Lagrangian structure, no energy; it learns
friction and input effects as part of its map)."""

from __future__ import annotations

import torch

from .base import DynamicsModel
from .layers import TangentMLP


class DirectMLP(DynamicsModel):
    """Baseline: an MLP that predicts normalised accelerations from ``(q, qd, theta)``."""

    variant = "mlp"

    def __init__(self, scene, hidden_dims=(128, 128), activation: str = "tanh") -> None:
        super().__init__(scene)
        n_in = self.num_features + self.scene.dof + self.scene.num_params + self.scene.num_inputs
        self.net = TangentMLP(n_in, list(hidden_dims), self.scene.dof, activation)

    def acceleration_norm(self, q_norm, qd_norm, params_norm, tau_norm=None):
        phi, _ = self.features(q_norm)
        x = [phi, qd_norm, params_norm] + ([] if tau_norm is None else [tau_norm])
        return self.net(torch.cat(x, -1))[0]

    provides = frozenset()  # accelerations only: no energy, no forces of its own (the inputs are features)
