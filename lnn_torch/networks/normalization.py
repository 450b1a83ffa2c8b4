"""Internal normalisation with ONE time scale, stored as buffers so it travels with checkpoints.

Coordinates: angles stay raw (they enter networks as sin/cos); a linear coordinate ``x`` becomes
``(x - shift) / scale``. Time becomes ``t / tau`` for every coordinate. Hence

    q_norm = (q - shift) / scale,  qd_norm = qd * tau / scale,  qdd_norm = qdd * tau^2 / scale.

This is a point transformation plus a time rescaling, so a Lagrangian in normalised variables is an
exact Lagrangian of the physical dynamics (z-scoring each velocity and acceleration separately, as
the reference design does, is not). Positive parameters enter as z-scored logarithms (they span
ratios); parameters that may be zero (friction coefficients) are z-scored as they are. The
conditioning networks see them clamped to ``TRUST`` standard deviations (uniformly sampled training
parameters span about 1.7): far beyond what it was trained on a model is conditioned on the nearest
trusted values instead of extrapolating its FiLM networks without bound. Beyond ``EXTRAPOLATION``
standard deviations its answers are extrapolation: ``untrusted`` names such parameters, and the models
warn with ``UntrustedParameterWarning``. Parameters that a physics part takes exactly (a
grey box's payload, a rigid body added to its last link) are ``exact``: never clamped.
``accel_rms`` (per coordinate, normalised units) only weights the loss.

Generalised forces (scenes with inputs or friction): a force ``Q`` (N m per coordinate) enters the
normalised Euler-Lagrange equations as ``Q_norm = force_scale * coord_scale * Q``: a point
transformation scales a force by the coordinate scale, and ``force_scale`` fixes the otherwise free
scale of the learned Lagrangian (``L -> cL`` leaves accelerations unchanged without forces; with
inputs it must match the torques). ``force_scale = 1 / rms(coord_scale * B tau)`` over the training
data (1 without inputs), so normalised input forces are O(1); ``input_rms`` normalises the inputs
where a network reads them directly (the direct MLP).
"""

from __future__ import annotations

import math

import torch
from torch import nn


class Normalizer(nn.Module):
    TRUST = 8.0  # |z| of a parameter beyond which the conditioning networks see the bound
    # |z| beyond which a model's answers are extrapolation, said with ``UntrustedParameterWarning``: 3 standard
    # deviations is 1.7 times the half-width of uniformly sampled training parameters (the shipped double
    # pendulum's error is 1.2 % at 1.8 times its longest training length, 7.5 % at 2.7 and 39 % at 4.5 times), or
    # 1.1 times the farthest training parameter (``param_z_max``: lognormal masses reach 3.8 in 6,000 draws); a
    # checkpoint written before the farthest was recorded: ``EXTRAPOLATION_UNKNOWN``
    EXTRAPOLATION = 3.0
    EXTRAPOLATION_UNKNOWN = 4.0

    def __init__(self, dof: int, num_params: int, angle_mask, param_kinds=None, num_inputs: int = 0,
                 forces: bool = False) -> None:
        super().__init__()
        self.dof, self.num_params, self.num_inputs = dof, num_params, num_inputs
        kinds = list(param_kinds or ["positive"] * num_params)
        self.all_log = all(k == "positive" for k in kinds)
        self.register_buffer("param_log", torch.tensor([k == "positive" for k in kinds], dtype=torch.bool),
                             persistent=False)
        # True where a physics part takes every parameter exactly (a grey box's payload): never clamped. A
        # Python flag set by the model (``mark_exact``), so torch.export sees no data-dependent branch
        self.exact = False
        self.register_buffer("angle_mask", torch.tensor(list(angle_mask), dtype=torch.bool))
        self.register_buffer("coord_shift", torch.zeros(dof))
        self.register_buffer("coord_scale", torch.ones(dof))
        self.register_buffer("time_scale", torch.ones(()))
        self.register_buffer("param_log_mean", torch.zeros(num_params))
        self.register_buffer("param_log_std", torch.ones(num_params))
        # the largest |z| of the training parameters (0: not recorded, a checkpoint written before it was)
        self.register_buffer("param_z_max", torch.zeros(num_params))
        self.register_load_state_dict_pre_hook(_record_missing_z_max)
        self.register_buffer("accel_rms", torch.ones(dof))
        # Hamiltonian models: one momentum scale, and the rms of each vector-field component
        self.register_buffer("momentum_scale", torch.ones(()))
        self.register_buffer("vector_field_rms", torch.ones(2 * dof))
        if forces:  # only scenes with forces have these (conservative checkpoints stay as they were)
            self.register_buffer("force_scale", torch.ones(()))
        if num_inputs:
            self.register_buffer("input_rms", torch.ones(num_inputs))

    def _transform(self, params):
        """``log`` of the positive parameters, the others as they are."""
        if self.all_log:
            return params.log()
        mask = self.param_log.to(params.device)
        return torch.where(mask, torch.where(mask, params, torch.ones_like(params)).log(), params)

    @torch.no_grad()
    def fit(self, q: torch.Tensor, qd: torch.Tensor, qdd: torch.Tensor, params: torch.Tensor,
            input_force: torch.Tensor | None = None, tau: torch.Tensor | None = None) -> Normalizer:
        """Set the statistics from training data: q, qd, qdd ``(n, dof)``; params ``(m, P)``; the
        input forces ``B tau (n, dof)`` and the inputs ``tau (n, n_u)`` where the scene has inputs."""
        q, qd, qdd, params = (x.double().flatten(0, -2) for x in (q, qd, qdd, params))
        lin = ~self.angle_mask.cpu()
        shift = torch.where(lin, q.mean(0), torch.zeros(self.dof, dtype=torch.float64))
        scale = torch.where(lin, q.std(0).clamp_min(1e-8), torch.ones(self.dof, dtype=torch.float64))
        acc = qdd / scale
        # one time scale: tau = 1/sqrt(rms |qdd / scale|), so normalised accelerations are O(1)
        t_scale = acc.pow(2).mean().sqrt().clamp_min(1e-12).rsqrt()
        logp = self._transform(params)
        self.coord_shift.copy_(shift)
        self.coord_scale.copy_(scale)
        self.time_scale.copy_(t_scale)
        self.param_log_mean.copy_(logp.mean(0))
        # (no parameters: nothing to reduce, and torch warns about the degrees of freedom of an empty std)
        self.param_log_std.copy_(logp.std(0).clamp_min(1e-3) if self.num_params and len(logp) > 1
                                 else torch.ones(self.num_params))
        if self.num_params and len(logp):
            # (never exactly 0 once recorded, which means unknown: a parameter held fixed in training is 0 here)
            self.param_z_max.copy_(((logp - self.param_log_mean) / self.param_log_std).abs().amax(0).clamp_min(1e-6))
        self.accel_rms.copy_((acc * t_scale**2).pow(2).mean(0).sqrt().clamp_min(1e-6))
        if hasattr(self, "force_scale") and input_force is not None:
            rms = (input_force.double().reshape(-1, self.dof) * scale).pow(2).mean().sqrt()
            self.force_scale.fill_(float(1 / rms) if rms > 0 else 1.0)
        if hasattr(self, "input_rms") and tau is not None:
            self.input_rms.copy_(tau.double().reshape(-1, self.num_inputs).pow(2).mean(0).sqrt().clamp_min(1e-6))
        return self

    def state(self, q, qd):
        q_norm = (q - self.coord_shift.to(q.dtype)) / self.coord_scale.to(q.dtype)
        qd_norm = qd * (self.time_scale.to(q.dtype) / self.coord_scale.to(q.dtype))
        return q_norm, qd_norm

    def params(self, params):
        """Normalised parameters, clamped to ``TRUST`` standard deviations (except the ``exact`` ones)."""
        z = (self._transform(params) - self.param_log_mean.to(params.dtype)) / self.param_log_std.to(params.dtype)
        return z if self.exact else z.clamp(-self.TRUST, self.TRUST)

    def mark_exact(self) -> None:
        """Every parameter is taken exactly by a physics part (a grey box's payload): never clamped."""
        self.exact = True

    def trusted_range(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(low, high)`` ``(P,)``: the SI parameters the conditioning networks see unclamped (the ``exact``
        ones: -inf, inf)."""
        bound = torch.full_like(self.param_log_mean, self.TRUST)
        if self.exact:
            return torch.full_like(bound, -float("inf")), torch.full_like(bound, float("inf"))
        return self.params_to_phys(-bound), self.params_to_phys(bound)

    @torch.no_grad()
    def untrusted(self, params: torch.Tensor, names, units, extremes=None) -> str | None:
        """A sentence naming the parameters of ``params (B, P)`` beyond ``EXTRAPOLATION`` standard deviations of
        the training parameters (the first offending value of each, and that range), and those beyond ``TRUST``,
        where the model is conditioned on the nearest trusted values; None when all are inside.
        ``extremes``: each parameter's smallest and largest value where the caller has them
        (``systems.base.param_extremes``): then a batch clearly inside is settled without a tensor operation."""
        if not self.num_params or self.exact:
            return None
        if extremes is not None and self._inside(*extremes):
            return None
        z = (self._transform(params.double()) - self.param_log_mean.double()) / self.param_log_std.double()
        limits = self.extrapolation_limits().to(z.device)
        out = (z.abs() > limits).any(0)
        if not out.any():
            return None
        near, far = self._bounds(limits), self._bounds(self.TRUST)
        beyond, parts = False, []
        for i in out.nonzero().flatten().tolist():
            value = float(params[(z[:, i].abs() > limits[i]).nonzero()[0, 0], i])
            distant = bool((z[:, i].abs() > self.TRUST).any())
            beyond |= distant
            low, high = (far if distant else near)
            parts.append(f"{names[i]} = {value:.4g} {units[i]} ({'trusted' if distant else 'range'} "
                         f"{float(low[i]):.3g} to {float(high[i]):.3g})")
        return (f"parameters beyond the range the model was trained on (its answers there are extrapolation): "
                f"{', '.join(parts)}"
                + (f"; beyond {self.TRUST:g} standard deviations (trusted) the model is conditioned on the nearest "
                   "trusted values" if beyond else ""))

    def extrapolation_limits(self) -> torch.Tensor:
        """``(P,)``: the |z| of each parameter beyond which the model extrapolates (``EXTRAPOLATION``)."""
        return torch.tensor([self._limit(z) for z in self.param_z_max.tolist()], dtype=torch.float64)

    @classmethod
    def _limit(cls, z_max: float) -> float:
        """The extrapolation limit of a parameter whose farthest training value was ``z_max`` (0: not recorded)."""
        return max(cls.EXTRAPOLATION, 1.1 * z_max) if z_max > 0 else cls.EXTRAPOLATION_UNKNOWN

    def _bounds(self, sigmas) -> tuple[torch.Tensor, torch.Tensor]:
        """``(low, high)`` ``(P,)``: the SI parameters ``sigmas`` (a number, or one per parameter) standard
        deviations from the training mean (a linear parameter's low end at 0 at least: those are >= 0)."""
        bound = torch.as_tensor(sigmas, dtype=self.param_log_mean.dtype).expand_as(self.param_log_mean).clone()
        low, high = self.params_to_phys(-bound), self.params_to_phys(bound)
        return torch.where(self.param_log.to(low.device), low, low.clamp_min(0)), high

    def _inside(self, low: list[float], high: list[float]) -> bool:
        """Whether every parameter between ``low`` and ``high`` (per parameter, SI) is inside the
        ``EXTRAPOLATION`` range by a margin (a value within 1e-9 standard deviations of a bound, a NaN or a
        non-positive value of a positive parameter is left to the exact check). The transform is monotone,
        so the extremes decide."""
        # read every call (no cache that a write through ``.data`` or an inference tensor would defeat)
        logs, means, stds, far = (b.tolist() for b in (self.param_log, self.param_log_mean, self.param_log_std,
                                                      self.param_z_max))
        limits = [self._limit(z) - 1e-9 for z in far]
        for lo, hi, log, mean, std, limit in zip(low, high, logs, means, stds, limits, strict=True):
            if log:
                if not lo > 0:
                    return False
                lo, hi = math.log(lo), math.log(hi)
            if not (abs(lo - mean) <= limit * std and abs(hi - mean) <= limit * std):
                return False
        return True

    def accel_to_norm(self, qdd):
        return qdd * (self.time_scale.to(qdd.dtype) ** 2 / self.coord_scale.to(qdd.dtype))

    def accel_to_phys(self, qdd_norm):
        return qdd_norm * (self.coord_scale.to(qdd_norm.dtype) / self.time_scale.to(qdd_norm.dtype) ** 2)

    def state_to_phys(self, q_norm, qd_norm):
        scale = self.coord_scale.to(q_norm.dtype)
        return q_norm * scale + self.coord_shift.to(q_norm.dtype), qd_norm * (scale / self.time_scale.to(q_norm.dtype))

    def params_to_phys(self, params_norm):
        x = params_norm * self.param_log_std.to(params_norm.dtype) + self.param_log_mean.to(params_norm.dtype)
        return x.exp() if self.all_log else torch.where(self.param_log.to(x.device), x.exp(), x)

    def force_to_norm(self, force):
        """A generalised force in SI ``(B, dof)`` -> normalised Euler-Lagrange units."""
        return force * (self.force_scale.to(force.dtype) * self.coord_scale.to(force.dtype))

    def force_to_phys(self, force_norm):
        return force_norm / (self.force_scale.to(force_norm.dtype) * self.coord_scale.to(force_norm.dtype))

    def momentum_to_norm(self, p):
        """Canonical momenta: ``p_norm = p * coord_scale / momentum_scale`` (keeps (q_norm, p_norm) canonical)."""
        return p * (self.coord_scale.to(p.dtype) / self.momentum_scale.to(p.dtype))


def trusted(params_norm: torch.Tensor) -> torch.Tensor:
    """What a network conditioned on the parameters reads: the normalised parameters within ``TRUST``
    standard deviations (unchanged where ``Normalizer.params`` already clamped them; the ``exact`` ones,
    which a physics part takes at any value, clamped here for the networks beside it)."""
    return params_norm.clamp(-Normalizer.TRUST, Normalizer.TRUST)


def _record_missing_z_max(module, state_dict, prefix, *args) -> None:
    """A checkpoint written before ``param_z_max`` was recorded loads with it unknown (zeros)."""
    key = prefix + "param_z_max"
    if key not in state_dict and prefix + "param_log_mean" in state_dict:
        state_dict[key] = torch.zeros_like(state_dict[prefix + "param_log_mean"])

