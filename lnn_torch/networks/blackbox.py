"""The LNN paper's black-box Lagrangian (Cranmer et al.): an MLP ``L(q, qd, theta)`` whose accelerations
come from the generic Euler-Lagrange solve (``lnn_torch.mechanics.euler_lagrange.generic_acceleration``: torch.func
Hessians, which work whatever the outer grad mode, so evaluation and rollouts run under no_grad).

Softplus by default (the LNN paper's choice): tanh saturates the velocity Hessian of the network
(the measured comparison on the relativistic particle is in ``results/README.md``).
"""

from __future__ import annotations

import torch

from ..mechanics.euler_lagrange import generic_acceleration
from .base import DynamicsModel
from .capabilities import ENERGY, FORCES, FRICTION, NAN_ON_SINGULAR
from .layers import TangentMLP


class BlackBoxLagrangian(DynamicsModel):
    """The LNN paper's model: an MLP ``L(q, qd, theta)`` and the generic Euler-Lagrange solve."""

    variant = "lnn"

    def __init__(self, scene, hidden_dims=(128, 128), activation: str = "softplus", lnn_init: bool = False,
                 hessian_reg: float = 0.0, learn_input_matrix: bool = False, dissipation: str = "joint") -> None:
        super().__init__(scene, learn_input_matrix, dissipation)
        self.net = TangentMLP(self.num_features + self.scene.dof + self.scene.num_params, list(hidden_dims), 1,
                              activation, out_bias=False)
        if lnn_init:
            self.net.lnn_init()
        self.hessian_reg = float(hessian_reg)

    def lagrangian_norm(self, q_norm, qd_norm, params_norm):
        phi, _ = self.features(q_norm[None])
        return self.net(torch.cat([phi[0], qd_norm, params_norm], -1)[None])[0][0, 0]

    def solve_norm(self, q_norm, qd_norm, params_norm, force_norm=None):
        """The generic solve (with the generalised force ``force_norm`` on the right-hand side).

        Singular-Hessian policy: the velocity Hessian of an arbitrary network can be indefinite, and
        singular somewhere (an untrained one always is, somewhere along a rollout). With
        ``hessian_reg == 0`` (default) such states raise ``SingularHessianError`` (in ``acceleration``
        and rollouts alike), and give NaN within ``nan_on_singular()`` (training
        skips those steps; evaluations count those trajectories as non-finite). ``hessian_reg > 0``
        solves the Levenberg-regularised system ``H + hessian_reg (mean|diag H| + 1) I`` instead.
        """
        return generic_acceleration(self.lagrangian_norm, q_norm, qd_norm, params_norm, hessian_reg=self.hessian_reg,
                                    check=self.raise_on_singular, force=force_norm)

    def training_terms(self, *args, **kwargs) -> dict:
        """As ``DynamicsModel.training_terms``; singular Hessians give NaN there (the step is skipped)."""
        with self.nan_on_singular():
            return super().training_terms(*args, **kwargs)

    def energy_norm(self, q_norm, qd_norm, params_norm):
        L_fn = torch.func.vmap(self.lagrangian_norm)
        L = L_fn(q_norm, qd_norm, params_norm)
        p = torch.func.vmap(torch.func.grad(self.lagrangian_norm, argnums=1))(q_norm, qd_norm, params_norm)
        T = 0.5 * (p * qd_norm).sum(-1)
        H = 2 * T - L
        return H, T, T - L

    # no mass matrix and no static friction: its velocity Hessian (the mass matrix) may be indefinite
    provides = frozenset({ENERGY, FRICTION, NAN_ON_SINGULAR, FORCES})
