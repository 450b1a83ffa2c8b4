"""A learned generalised force beside a model's physics: the force residual ``Q_r(q, qd, theta)``
(model option ``residual_force`` of the structured models: ``model_options: {residual_force: {hidden:
[32, 32], weight: 1e-3}}``).

What a grey box's description cannot write (friction of another form, a spring or cable torque,
motor cogging, a sensor's offset) is a force of the state that no Lagrangian of rigid links and no
passive drive model holds. The residual is an MLP of the model's features of ``q`` (sin/cos of the
angles; with ``harmonics: K``, of ``k`` times the angles for ``k = 1..K`` too, ``sin(k q)`` and ``cos(k
q)`` from the first by the Chebyshev recursion: a position-periodic torque such as a motor's cogging is
then linear in the inputs), the velocities ``qd`` (each divided by its training rms) and, for
``delan``, the parameters;
``film_lnn`` modulates its hidden layers by FiLM of the parameters (the payload) instead. Its outputs
are per coordinate, in SI (N m for an angle), each scaled by that coordinate's rms input force of the
training data.

* It starts at exactly zero (its output layer is zero), so a model with it starts as the model without.
* It is regularised: the training loss adds ``weight`` times the sum of squares of its output layer
  (the residual's amplitude; ``model.regularization()``), on top of any weight decay.
* It is NOT passive: a general force can put energy in, so it is no part of the model's dissipative
  ``Q_f`` (``friction_si``, for which ``qd . Q_f <= 0`` stays true). In the rigid-body convention
  (``lnn_torch.networks.rigid_body``) it is its own term, ``M qdd + n = B tau + Q_f + Q_r``: in the
  forward and inverse dynamics and in the power of the model's forces (the power-balance term counts
  its work), never in ``n``, ``g`` or ``Q_f``.
* Its share of the torques is reported by ``lnn_torch.networks.shares.torque_shares``.
"""

from __future__ import annotations

import torch
from torch import nn

from ..errors import InputError
from .layers import FiLM, TangentMLP
from .parts.base import film_of


class ResidualForce(nn.Module):
    """``Q_r (B, dof)`` in SI from ``[phi(q), qd / rms(qd)(, params)]`` (module docstring).

    Args:
        num_features: the model's features of ``q``.
        dof: coordinates (outputs).
        num_params: the scene's parameters.
        conditioning: ``film`` (FiLM of the parameters on the hidden layers) or ``concat`` (the
            parameters as inputs; also without parameters).
        hidden: hidden widths; activation: ``tanh`` (default), ``softplus``, ``sigmoid``, ``isru``.
        weight: the weight of the L2 penalty on the output layer (>= 0).
        film_hidden: the FiLM network's width.
        harmonics: ``K`` >= 1: the sin/cos of ``k`` times the feature angles for ``k = 1..K`` as inputs.
        num_angles: the feature angles (the first ``2 num_angles`` features are their sin, then cos).
    """

    def __init__(self, num_features: int, dof: int, num_params: int, conditioning: str, hidden=(32, 32),
                 weight: float = 1e-3, activation: str = "tanh", film_hidden: int = 16, harmonics: int = 1,
                 num_angles: int = 0) -> None:
        super().__init__()
        if not (isinstance(harmonics, int) and not isinstance(harmonics, bool) and harmonics >= 1):
            raise InputError(f"residual_force: harmonics must be an integer >= 1, got {harmonics!r}")
        self.harmonics, self.num_angles = int(harmonics), int(num_angles)
        hidden = [int(hidden)] if isinstance(hidden, int) else [int(h) for h in hidden]
        if not hidden or any(h < 1 for h in hidden):
            raise InputError(f"residual_force: hidden must be positive widths, got {hidden!r}")
        if not (isinstance(weight, (int, float)) and weight >= 0):
            raise InputError(f"residual_force: weight must be a number >= 0, got {weight!r}")
        self.dof, self.weight = dof, float(weight)
        self.use_film = conditioning == "film" and num_params > 0
        extra = 2 * self.num_angles * (self.harmonics - 1)
        self.num_inputs = num_features + extra + dof + (0 if self.use_film else num_params)
        self.net = TangentMLP(self.num_inputs, hidden, dof, activation)
        with torch.no_grad():  # exactly zero at the start
            self.net.out.weight.zero_()
            self.net.out.bias.zero_()
        self.film = FiLM(num_params, hidden, "neuron", film_hidden) if self.use_film else None
        # SI units, set from the training data (``fit``): each coordinate's rms input force, and the
        # rms of the normalised velocities (which the network reads divided by it)
        self.register_buffer("unit", torch.ones(dof))
        self.register_buffer("velocity_rms", torch.ones(dof))

    @torch.no_grad()
    def fit(self, force_rms: torch.Tensor | None, velocity_rms: torch.Tensor) -> None:
        """The output unit per coordinate (``force_rms (dof,)``, SI; None: 1) and the normalised velocities'
        rms ``(dof,)``."""
        if force_rms is not None:
            self.unit.copy_(force_rms.clamp_min(1e-6))
        self.velocity_rms.copy_(velocity_rms.clamp_min(1e-6))

    def regularization(self) -> torch.Tensor | None:
        """``weight`` times the sum of squares of the output layer, or None with weight 0."""
        if not self.weight:
            return None
        out = self.net.out
        return self.weight * (out.weight.pow(2).sum() + out.bias.pow(2).sum())

    def forward(self, features: torch.Tensor, qd_norm: torch.Tensor, params_norm: torch.Tensor) -> torch.Tensor:
        """``Q_r (B, dof)`` in SI from the model's features ``(B, F)``, normalised velocities ``(B, dof)``
        and normalised parameters ``(B, P)`` (or ``(1, P)``)."""
        v = qd_norm / self.velocity_rms.to(qd_norm.dtype)
        features = self._harmonics(features)
        if self.use_film:
            x = torch.cat([features, v], -1)
            film = film_of(self.film, self.net, params_norm.expand(x.shape[0], -1), None)
        else:
            x = torch.cat([features, v, params_norm.expand(features.shape[0], -1)], -1)
            film = None
        y, _ = self.net(x, None, film)
        return y * self.unit.to(y.dtype)

    def _harmonics(self, features: torch.Tensor) -> torch.Tensor:
        """``features`` with ``sin(k a), cos(k a)`` of the feature angles ``a`` for ``k = 2..K`` appended
        (``sin(k a) = 2 cos a sin((k-1) a) - sin((k-2) a)``, likewise ``cos``)."""
        if self.harmonics == 1 or not self.num_angles:
            return features
        na = self.num_angles
        s1, c1 = features[..., :na], features[..., na:2 * na]
        sines, cosines = [torch.zeros_like(s1), s1], [torch.ones_like(c1), c1]
        for _ in range(2, self.harmonics + 1):
            sines.append(2 * c1 * sines[-1] - sines[-2])
            cosines.append(2 * c1 * cosines[-1] - cosines[-2])
        return torch.cat([features, *[torch.cat([a, b], -1) for a, b in zip(sines[2:], cosines[2:], strict=True)]],
                         -1)
