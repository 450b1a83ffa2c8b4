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
  ``Q_f`` (``friction``, for which ``qd . Q_f <= 0`` stays true). In the rigid-body convention
  (``lnn_torch.networks.rigid_body``) it is its own term, ``M qdd + n = B tau + Q_f + Q_r``: in the
  forward and inverse dynamics and in the power of the model's forces (the power-balance term counts
  its work), never in ``n``, ``g`` or ``Q_f``.
* Its share of the torques is reported by ``lnn_torch.networks.shares.torque_shares``.

``local: true`` makes it a network per coordinate instead (``layers.GroupedMLP``): ``Q_r,j`` from that
coordinate's own angle (``sin(k q_j)``, ``cos(k q_j)``, ``k = 1..K``; a non-angle coordinate: ``q_j``),
its own velocity and the parameters (as inputs, for either conditioning): the form of what a drive adds
to a joint (friction of any shape in its rate, cogging and a spring in its angle, a sensor's offset),
and far fewer inputs to overfit short recordings with. It cannot hold a force that couples joints.
"""

from __future__ import annotations

import torch
from torch import nn

from ..errors import InputError
from .layers import FiLM, GroupedMLP, TangentMLP
from .normalization import trusted
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
        local: a network per coordinate of its own angle (or coordinate) and velocity and the
            parameters (module docstring).
        angle_idx, linear_idx: the angle and the other coordinates (``local``; the features' order:
            the ``j``-th feature angle is the ``j``-th angle coordinate, then the non-angle coordinates).
    """

    def __init__(self, num_features: int, dof: int, num_params: int, conditioning: str, hidden=(32, 32),
                 weight: float = 1e-3, activation: str = "tanh", film_hidden: int = 16, harmonics: int = 1,
                 num_angles: int = 0, local: bool = False, angle_idx=(), linear_idx=()) -> None:
        super().__init__()
        if not (isinstance(harmonics, int) and not isinstance(harmonics, bool) and harmonics >= 1):
            raise InputError(f"residual_force: harmonics must be an integer >= 1, got {harmonics!r}")
        self.harmonics, self.num_angles = int(harmonics), int(num_angles)
        hidden = [int(hidden)] if isinstance(hidden, int) else [int(h) for h in hidden]
        if not hidden or any(h < 1 for h in hidden):
            raise InputError(f"residual_force: hidden must be positive widths, got {hidden!r}")
        if not (isinstance(weight, (int, float)) and weight >= 0):
            raise InputError(f"residual_force: weight must be a number >= 0, got {weight!r}")
        if not isinstance(local, bool):
            raise InputError(f"residual_force: local must be true or false, got {local!r}")
        self.dof, self.weight, self.local = dof, float(weight), local
        self.use_film = conditioning == "film" and num_params > 0 and not local
        extra = 2 * self.num_angles * (self.harmonics - 1)
        self.num_inputs = num_features + extra + dof + (0 if self.use_film else num_params)
        self.film = None
        if local:
            self.register_buffer("local_inputs", self._local_columns(num_features, num_params, angle_idx, linear_idx),
                                 persistent=False)
            self.net = GroupedMLP(dof, self.local_inputs.shape[1], hidden, activation)
        else:
            self.net = TangentMLP(self.num_inputs, hidden, dof, activation)
            self.film = FiLM(num_params, hidden, "neuron", film_hidden) if self.use_film else None
        with torch.no_grad():  # exactly zero at the start
            for p in self.output_layer:
                p.zero_()
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
        w, b = self.output_layer
        return self.weight * (w.pow(2).sum() + b.pow(2).sum())

    @property
    def output_layer(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The output layer's ``(weight, bias)`` (what starts at zero and what the penalty reads)."""
        return self.net.out_layer if self.local else (self.net.out.weight, self.net.out.bias)

    def _local_columns(self, num_features: int, num_params: int, angle_idx, linear_idx) -> torch.Tensor:
        """``(dof, width)``: the columns of ``[features with harmonics, velocities, parameters, 0]`` each
        coordinate's network reads (padded with the zero column)."""
        angle_idx, linear_idx = [int(i) for i in angle_idx], [int(i) for i in linear_idx]
        if sorted(angle_idx + linear_idx) != list(range(self.dof)):
            raise InputError(f"residual_force: local needs the angle and the other coordinates of all {self.dof}")
        na, K = self.num_angles, self.harmonics
        n_ext = num_features + 2 * na * (K - 1)
        params = list(range(n_ext + self.dof, n_ext + self.dof + num_params))
        zero = n_ext + self.dof + num_params
        rows = []
        for i in range(self.dof):
            if i in angle_idx:
                j = angle_idx.index(i)
                own = [j, na + j] + [num_features + 2 * na * (k - 2) + c * na + j for k in range(2, K + 1)
                                     for c in (0, 1)]
            else:
                own = [2 * na + linear_idx.index(i)]
            rows.append(own + [n_ext + i] + params)
        width = max(len(r) for r in rows)
        return torch.tensor([r + [zero] * (width - len(r)) for r in rows], dtype=torch.long)

    def forward(self, features: torch.Tensor, qd_norm: torch.Tensor, params_norm: torch.Tensor) -> torch.Tensor:
        """``Q_r (B, dof)`` in SI from the model's features ``(B, F)``, normalised velocities ``(B, dof)``
        and normalised parameters ``(B, P)`` (or ``(1, P)``)."""
        v = qd_norm / self.velocity_rms.to(qd_norm.dtype)
        features = self._harmonics(features)
        params_norm = trusted(params_norm)  # what the networks read
        if self.local:
            x = torch.cat([features, v, params_norm.expand(features.shape[0], -1),
                           features.new_zeros(features.shape[0], 1)], -1)
            return self.net(x[:, self.local_inputs]) * self.unit.to(x.dtype)
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
