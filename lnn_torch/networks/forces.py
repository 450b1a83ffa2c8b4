"""Learned generalised forces of a model: inputs through the input matrix, and dissipation that can
never inject energy (``lnn_torch.mechanics.forces`` has the physics).

Built only for scenes that declare inputs or friction (``SceneInfo.has_forces``): a model of a
conservative scene has no such module and no extra parameter.

* Inputs: ``B tau`` with ``B`` the scene's input matrix (a buffer), or a learned matrix initialised
  at it (``learn_input_matrix: true``: motor gains or calibration errors), or the scene's with one
  learned positive gain per input (``learn_input_matrix: gains``: drive gains of motor currents known
  only nominally, or not at all: import the currents with gains 1 and the gains are learned in N m/A).
  Gains and a learned rigid body share one scale (both times c explain the same currents): a known
  description (``learn: false``) or a strong ``prior`` fixes it; the real Panda with its torques divided
  by known gains gave the right ratios between joints 1-6 and 0.7 times their scale (2000 steps, prior
  1e-4).
* Joint friction (``dissipation="joint"``, the default): per joint, viscous ``b >= 0`` and smooth
  Coulomb ``c >= 0`` friction on the joint rates ``r = D qd``, ``Q = -D^T (b r + c tanh(r / v))``,
  with ``(b, c)`` = softplus of a small network of the normalised parameters (the conditioning of
  the rest of the model), or free coefficients where the scene has no parameters. ``v`` is the
  scene's Coulomb smoothing velocity.
* ``friction``: the drive model's forms (``lnn_torch.mechanics.friction``): ``viscous+coulomb`` (the default,
  as above) or any of ``viscous``, ``coulomb``, ``offset`` (a constant torque per joint: an asymmetry or a
  torque sensor's offset; *not* dissipative), ``stribeck`` (``s >= 0``, a breakaway above Coulomb fading over
  ``v_s``), ``saturating`` (``d >= -k c``, the Coulomb level moving to ``c + d`` over ``v_d``) and ``sigmoid`` (Gaz
  et al.'s ``phi1 [sigmoid(phi2 (v + phi3)) - sigmoid(phi2 phi3)]``, ``phi1, phi2 >= 0``), e.g.
  ``viscous+coulomb+offset``; the coefficients beyond ``(b, c)`` come from the same network of the parameters
  (or are free constants without parameters).
* ``dissipation="joint+stiction"`` adds static friction to the joint friction: a joint slower than
  the stick velocity ``v_s`` (2.5 times the scene's Coulomb smoothing velocity) is held at rest by
  up to its Coulomb level ``c`` (no parameter of its own), its kinetic friction fading in that
  window (``lnn_torch.mechanics.forces.holding_torque``; the model solves for the holding torques, which need
  its mass matrix). A free static level fitted the real pendulum's training holds and predicted
  two held-out recordings worse (results/real_double_pendulum/cross_validation/), so the level is
  ``c``. For models with a positive definite mass matrix (``film_lnn``, ``delan``).
* ``dissipation="joint+rayleigh"`` adds ``-R(q, qd, theta) qd`` with ``R = chol chol^T`` positive
  semi-definite from a small MLP of ``(features(q), qd, theta)`` (coupled, state-dependent damping).

* A force residual (``attach_residual``: the structured models' option ``residual_force``,
  ``lnn_torch.networks.residual_force``): a learned generalised force ``Q_r(q, qd, theta)`` beside the
  rest, starting at zero, regularised, NOT passive: it is in ``force``/``force_norm`` and
  ``state_force_at`` (what the inverse dynamics subtracts) but never in ``Q_diss``.

In the model's normalised units (``force_norm``, ``dissipative_force_at``, ``holding_torques``,
``with_static_friction``) the forces read the model's ``Normalizer`` (``attach_normalizer``): the model
calls them with its normalised state and gets normalised generalised forces or accelerations back.

Every term of ``Q_diss`` has ``qd . Q_diss <= 0`` by construction, but a friction ``offset`` (a
constant torque, which the data may need and no passive model has); the holding torque of static
friction is not part of it: it opposes the tendency to move, see ``lnn_torch.mechanics.forces``. Coefficients
are in SI units (``unit`` buffers, set from the training data, scale the network outputs).
"""

from __future__ import annotations

import dataclasses
import math

import torch
import torch.nn.functional as F
from torch import nn

from ..mechanics.forces import (
    dissipative_force,
    holding_torque,
    identity_or_none,
    input_force,
    stick_weight,
)
from ..mechanics.friction import SLOPE_LIMIT, DriveModel
from .normalization import trusted

DISSIPATION = ("joint", "joint+rayleigh", "joint+stiction")
_INIT = math.log(math.expm1(0.1))  # softplus^-1(0.1): coefficients start at 0.1 of their unit
# the coefficients beyond (b, c), per joint, in the order of the drive model's forms: (name, raw start);
# the sigmoid's phi2 = L tanh(softplus(raw) / L) / v_c (L = SLOPE_LIMIT: bounded) starts at 0.6 / v_c (30 s/rad at
# v_c = 0.02 rad/s)
_EXTRA = {"offset": (("o", 0.0),), "stribeck": (("s", _INIT),), "saturating": (("d", _INIT),),
          "sigmoid": (("phi1", _INIT), ("phi2", math.log(math.expm1(0.6))), ("phi3", 0.0))}


def _softplus_inverse(x: torch.Tensor) -> torch.Tensor:
    """``r`` with ``softplus(r) = x`` (``x > 0``)."""
    return x + torch.log(-torch.expm1(-x))


class LearnedForces(nn.Module):
    def __init__(self, scene, num_features: int, learn_input_matrix: bool = False, dissipation: str = "joint",
                 hidden: int = 16, friction: str = "viscous+coulomb") -> None:
        super().__init__()
        if dissipation not in DISSIPATION:
            raise ValueError(f"dissipation must be one of {', '.join(DISSIPATION)}, got '{dissipation}'")
        self.stiction = dissipation == "joint+stiction"
        if self.stiction and not scene.friction:
            raise ValueError(f"dissipation 'joint+stiction' needs a scene with joint friction "
                             f"('{scene.name}' has none)")
        self.dof, P = scene.dof, scene.num_params
        self.num_inputs = scene.num_inputs
        if scene.num_inputs:
            B = torch.tensor(scene.input_matrix, dtype=torch.float32)
            if learn_input_matrix not in (False, True, "gains"):
                raise ValueError(f"learn_input_matrix must be true, false or 'gains', got {learn_input_matrix!r}")
            if learn_input_matrix == "gains":  # B diag(k), k = exp(raw) > 0 learned from 1
                self.register_buffer("nominal_input_matrix", B, persistent=False)
                self.input_gains_raw = nn.Parameter(torch.zeros(B.shape[1]))
            elif learn_input_matrix:
                self.input_matrix = nn.Parameter(B)
            else:
                self.register_buffer("input_matrix", B, persistent=False)
            self.identity_inputs = not learn_input_matrix and identity_or_none(B.double()) is None
        self.friction = scene.friction
        if scene.friction:
            D = torch.tensor(scene.joint_map, dtype=torch.float32) if scene.joint_map else torch.eye(self.dof)
            self.num_joints = D.shape[0]
            self.identity_joints = identity_or_none(D.double()) is None
            self.register_buffer("joint_map", D, persistent=False)
            self.drive = DriveModel.of(friction, coulomb_velocity=float(scene.coulomb_velocity))
            # the Coulomb smoothing (rad/s) travels with the weights: a classical start may choose another than
            # the scene's (identification.classical_start), and a model built from the scene then loads it
            self.register_buffer("coulomb_velocity_si", torch.tensor(self.drive.coulomb_velocity, dtype=torch.float64))
            if "saturating" in self.drive.forms:  # so does saturating friction's velocity (chosen there too)
                self.register_buffer("saturation_velocity_si",
                                     torch.tensor(self.drive.saturation_velocity, dtype=torch.float64))
            self._sync_velocities()
            # the forms the drive model keeps of those configured (all, until a classical start leaves one out:
            # ``keep_forms``); they travel with the weights, the coefficients' layout stays the configured one's
            self.configured_forms = self.drive.forms
            self.register_buffer("forms_kept", torch.ones(len(self.configured_forms), dtype=torch.bool))
            # (b, c) first, as always; then the further forms' coefficients per joint
            self.extra = tuple(item for form in self.drive.forms for item in _EXTRA.get(form, ()))
            n_raw = (2 + len(self.extra)) * self.num_joints
            start = torch.tensor([_INIT] * 2 * self.num_joints + [v for _, v in self.extra for _ in
                                                                  range(self.num_joints)])
            if P:
                self.coefficient_net = nn.Sequential(nn.Linear(P, hidden), nn.SiLU(), nn.Linear(hidden, n_raw))
                nn.init.zeros_(self.coefficient_net[-1].weight)
                with torch.no_grad():
                    self.coefficient_net[-1].bias.copy_(start)
            else:
                self.coefficients_raw = nn.Parameter(start)
            # SI units of (b, c): torque / rate and torque, set from the data (fit)
            self.register_buffer("units", torch.ones(2))
        self.rayleigh = None
        if dissipation == "joint+rayleigh":
            n = self.dof * (self.dof + 1) // 2
            self.rayleigh = nn.Sequential(nn.Linear(num_features + self.dof + P, hidden), nn.Tanh(),
                                          nn.Linear(hidden, n))
            nn.init.zeros_(self.rayleigh[-1].weight)
            nn.init.constant_(self.rayleigh[-1].bias, -3.0)
            rows, cols = torch.tril_indices(self.dof, self.dof)
            self.register_buffer("tril_index", rows * self.dof + cols, persistent=False)
        self.residual = None

    def attach_residual(self, residual: nn.Module) -> None:
        """Add the force residual ``Q_r`` (a ``ResidualForce``; the structured models build it after their
        parts, so that a seed gives their other networks as without it)."""
        self.residual = residual

    @property
    def needs_features(self) -> bool:
        """Whether the forces read the model's features of ``q`` (the Rayleigh term, the force residual)."""
        return self.rayleigh is not None or self.residual is not None

    @property
    def dissipative(self) -> bool:
        """Whether the forces have a dissipative part ``Q_diss`` (joint friction, Rayleigh damping)."""
        return self.friction or self.rayleigh is not None

    def coefficient_parameters(self) -> list[nn.Parameter]:
        """The physical coefficients (exempt from weight decay): constant friction coefficients and a
        learned input matrix."""
        return [p for n, p in self.named_parameters(recurse=False)
                if n in ("coefficients_raw", "input_matrix", "input_gains_raw")]

    def current_input_matrix(self) -> torch.Tensor:
        """``B (dof, n_u)``: the scene's, a learned matrix, or the scene's with a learned gain per input
        (``learn_input_matrix="gains"``: ``B diag(input_gains())``)."""
        if hasattr(self, "input_gains_raw"):
            return self.nominal_input_matrix * self.input_gains_raw.exp()
        return self.input_matrix

    def input_gains(self) -> torch.Tensor | None:
        """The learned gain per input (``learn_input_matrix="gains"``; dimensionless: the factor on the
        imported torques, e.g. on the nominal drive gains of motor currents), None otherwise."""
        return self.input_gains_raw.exp() if hasattr(self, "input_gains_raw") else None

    # ------------------------------------------------------------------ set-up
    @torch.no_grad()
    def fit_units(self, torque_scale: float, rate_rms: float) -> None:
        """Coefficient units from the data: ``(torque_scale / rate_rms, torque_scale)`` in SI."""
        if self.friction:
            self.units.copy_(torch.tensor([torque_scale / max(rate_rms, 1e-6), torque_scale]))

    @torch.no_grad()
    def start_at(self, viscous: torch.Tensor, coulomb: float = 1e-4) -> None:
        """Start the friction at known values (after ``fit_units``): viscous ``b (num_joints,)`` in N m
        s/rad, and Coulomb ``coulomb`` times the torque unit (a grey box's description gives its joint
        damping, not the rest)."""
        units = self.units.double()
        b = (viscous.double().clamp_min(1e-6) / units[0])
        c = torch.full_like(b, coulomb)
        raw = torch.cat([_softplus_inverse(b), _softplus_inverse(c)])
        k = 2 * self.num_joints  # the further forms' coefficients keep their start
        if hasattr(self, "coefficient_net"):
            self.coefficient_net[-1].weight[:k].zero_()
            self.coefficient_net[-1].bias[:k].copy_(raw)
        else:
            self.coefficients_raw[:k].copy_(raw)

    def _sync_velocities(self) -> None:
        v = float(f"{float(self.coulomb_velocity_si):.6g}")  # (a float32 copy of the buffer reads 0.00499999988)
        self.coulomb_velocity = v
        self.stick_velocity = 2.5 * v  # the stick window (joint+stiction)
        saturation = getattr(self, "saturation_velocity_si", None)
        saturation = self.drive.saturation_velocity if saturation is None else float(f"{float(saturation):.6g}")
        self.drive = dataclasses.replace(self.drive, coulomb_velocity=v, saturation_velocity=saturation)

    @torch.no_grad()
    def set_saturation_velocity(self, value: float) -> None:
        """Let saturating friction rise over ``value`` rad/s from now on (its coefficients keep their values)."""
        if "saturating" not in self.drive.forms:
            raise ValueError("the drive model has no saturating friction")
        dataclasses.replace(self.drive, saturation_velocity=float(value)).with_forms(self.drive.forms)  # checks it
        self.saturation_velocity_si.fill_(float(value))
        self._sync_velocities()

    @torch.no_grad()
    def set_coulomb_velocity(self, value: float) -> None:
        """Smooth Coulomb (and Stribeck) friction's sign over ``value`` rad/s from now on (the coefficients keep
        their values; the sigmoid's, which depend on it, are refused)."""
        if "sigmoid" in self.drive.forms:
            raise ValueError("the sigmoid drive model's coefficients are in units of the Coulomb smoothing: it stays")
        DriveModel.of(self.drive.forms, coulomb_velocity=float(value))  # checks it
        self.coulomb_velocity_si.fill_(float(value))
        self._sync_velocities()

    @torch.no_grad()
    def keep_forms(self, forms) -> None:
        """Keep only ``forms`` (a subset of the configured drive model's, in any order) from now on: the terms
        left out add no torque and their coefficients no longer move (a classical start's chosen form, so that
        the trained model, its report and its export are that form)."""
        forms = set(DriveModel.of(forms).forms) if isinstance(forms, str) else set(forms)
        unknown = forms - set(self.configured_forms)
        if unknown or not forms:
            raise ValueError(f"forms to keep must be some of {'+'.join(self.configured_forms)}, got {sorted(forms)}")
        self.forms_kept.copy_(torch.tensor([f in forms for f in self.configured_forms]))
        self._sync_forms()

    def _sync_forms(self) -> None:
        kept = [f for f, k in zip(self.configured_forms, self.forms_kept.tolist(), strict=True) if k]
        self.drive = self.drive.with_forms(kept)

    def _load_from_state_dict(self, state_dict, prefix, local_metadata, strict, missing_keys, unexpected_keys,
                              error_msgs) -> None:
        super()._load_from_state_dict(state_dict, prefix, local_metadata, strict, missing_keys, unexpected_keys,
                                      error_msgs)
        key = prefix + "coulomb_velocity_si"
        if self.friction and key in missing_keys:  # saved before it travelled: the scene's smoothing stands
            missing_keys.remove(key)
        elif self.friction and key in state_dict:
            self._sync_velocities()
        key = prefix + "forms_kept"
        if self.friction and key in missing_keys:  # saved before the forms travelled: every configured one
            missing_keys.remove(key)
        elif self.friction and key in state_dict:
            self._sync_forms()

    @torch.no_grad()
    def start_with(self, coefficients: dict) -> None:
        """Start the friction at the drive model's coefficients ``{name: (num_joints,)}`` in SI (after
        ``fit_units``; e.g. a classical fit's): the coefficients named are set (the same for every
        parameter value: the coefficient network's weights on them zeroed), the others keep their start.
        The sigmoid's slope is clipped below its bound; a non-negative coefficient of 0 starts at 1e-12 of
        its unit (where its gradient vanishes: clip it higher to let it move)."""
        units = self.units.double()
        n = self.num_joints
        softplus_inverse = lambda x: _softplus_inverse(x.clamp_min(1e-12))  # noqa: E731

        rows = {}
        for k, name in enumerate(("b", "c")):
            if name in coefficients:
                rows[k] = softplus_inverse(torch.as_tensor(coefficients[name]).double() / units[k])
        for k, (name, _) in enumerate(self.extra):
            if name not in coefficients:
                continue
            value = torch.as_tensor(coefficients[name]).double()
            if name == "phi2":  # phi2 = L tanh(softplus(raw) / L) / v_c
                x = (value * self.coulomb_velocity / SLOPE_LIMIT).clamp(1e-9, 1 - 1e-9)
                raw = softplus_inverse(SLOPE_LIMIT * torch.atanh(x))
            elif name == "phi3":
                raw = value / self.coulomb_velocity
            elif name == "o":
                raw = value / units[1]
            elif name == "d":  # d = softplus(raw) unit - k c: with the Coulomb level set here (else zero)
                c = torch.as_tensor(coefficients.get("c", 0.0)).double() if "coulomb" in self.drive.forms else 0.0
                raw = softplus_inverse((value + self.drive.saturation_floor() * c) / units[1])
            else:
                raw = softplus_inverse(value / units[1])
            rows[2 + k] = raw
        for k, raw in rows.items():
            block = slice(k * n, (k + 1) * n)
            if hasattr(self, "coefficient_net"):
                self.coefficient_net[-1].weight[block].zero_()
                self.coefficient_net[-1].bias[block].copy_(raw)
            else:
                self.coefficients_raw[block].copy_(raw)

    # ------------------------------------------------------------------ the forces (SI)
    def _raw(self, params_norm: torch.Tensor) -> torch.Tensor:
        return self.coefficient_net(trusted(params_norm)) if hasattr(self, "coefficient_net") else self.coefficients_raw

    def coefficients(self, params_norm: torch.Tensor):
        """Friction coefficients ``(b, c)``, each ``(B, num_joints)`` (or ``(num_joints,)`` without
        parameters) in N m s/rad and N m (zero for a form the drive model leaves out)."""
        raw = self._raw(params_norm)[..., : 2 * self.num_joints]
        b, c = F.softplus(raw).split(self.num_joints, -1)
        units = self.units.to(raw.dtype)
        forms = self.drive.forms
        return b * units[0] * ("viscous" in forms), c * units[1] * ("coulomb" in forms)

    def drive_coefficients(self, params_norm: torch.Tensor) -> dict:
        """Every coefficient of the drive model (``lnn_torch.mechanics.friction``) in SI,
        ``{name: (..., num_joints)}``."""
        b, c = self.coefficients(params_norm)
        out = {"b": b, "c": c}
        raw = self._raw(params_norm)[..., 2 * self.num_joints:]
        torque = self.units[1].to(raw.dtype)
        for k, (name, _) in enumerate(self.extra):
            r = raw[..., k * self.num_joints:(k + 1) * self.num_joints]
            if name == "phi2":  # bounded: SLOPE_LIMIT / v_c at most, softplus(raw) / v_c well below it
                out[name] = SLOPE_LIMIT * torch.tanh(F.softplus(r) / SLOPE_LIMIT) / self.coulomb_velocity
            elif name == "phi3":
                out[name] = r * self.coulomb_velocity
            elif name == "o":
                out[name] = r * torque
            elif name == "d":  # passive down to -k c (DriveModel.saturation_floor)
                out[name] = F.softplus(r) * torque - self.drive.saturation_floor() * c
            else:  # s, phi1: non-negative torques
                out[name] = F.softplus(r) * torque
        return out

    def static_level(self, params_norm: torch.Tensor) -> torch.Tensor:
        """The static friction level per joint (``joint+stiction``): the Coulomb level ``c``, N m."""
        return self.coefficients(params_norm)[1]

    def friction_torque(self, rates: torch.Tensor, params_norm: torch.Tensor) -> torch.Tensor:
        """Per-joint (kinetic) friction torque at joint rates ``(B, num_joints)``, N m; with static
        friction it fades as ``1 - w`` in the stick window."""
        torque = self.drive.torque(rates, self.drive_coefficients(params_norm))
        return torque * (1 - stick_weight(rates, self.stick_velocity)) if self.stiction else torque

    def holding_torque(self, qd: torch.Tensor, params_norm: torch.Tensor, rho0: torch.Tensor,
                       response: torch.Tensor) -> torch.Tensor:
        """Static friction's holding torques ``(B, num_joints)`` in N m at SI velocities ``qd``, from the
        joint accelerations without them ``rho0 (B, n_j)`` and the response ``D M^-1 D^T (B, n_j, n_j)``
        (``lnn_torch.mechanics.forces.holding_torque``)."""
        rates = qd if self.identity_joints else qd @ self.joint_map.to(qd.dtype).T
        return holding_torque(rho0, response, stick_weight(rates, self.stick_velocity), self.static_level(params_norm))

    def dissipative_force(self, qd: torch.Tensor, params_norm: torch.Tensor, features=None, qd_norm=None):
        """``Q_diss (B, dof)`` in SI at SI velocities ``qd``; ``features``/``qd_norm`` feed the Rayleigh term."""
        Q = torch.zeros_like(qd)
        if self.friction:
            D = None if self.identity_joints else self.joint_map
            Q = dissipative_force(qd, D, lambda r: self.friction_torque(r, params_norm))
        if self.rayleigh is not None:
            entries = self.rayleigh(torch.cat([features, qd_norm, trusted(params_norm).expand(qd.shape[0], -1)], -1))
            chol = entries.new_zeros(qd.shape[0], self.dof * self.dof).index_copy(-1, self.tril_index, entries)
            chol = chol.view(-1, self.dof, self.dof)
            Q = Q - (chol @ (chol.mT @ qd[..., None]))[..., 0] * self.units[0].to(qd.dtype)
        return Q

    def input_force(self, tau: torch.Tensor) -> torch.Tensor:
        """``B tau (B, dof)`` for inputs ``tau (B, n_u)`` in N m."""
        return input_force(tau, None if self.identity_inputs else self.current_input_matrix())

    def solve_inputs(self, input_force: torch.Tensor) -> torch.Tensor:
        """The inputs ``tau (B, n_u)`` whose force ``B tau`` is closest to ``input_force (B, dof)``
        (exact for a full-rank square ``B``; least squares for an underactuated system)."""
        if self.identity_inputs:
            return input_force
        return input_force @ torch.linalg.pinv(self.current_input_matrix().to(input_force.dtype)).mT

    def force(self, qd, params_norm, tau=None, features=None, qd_norm=None) -> torch.Tensor:
        """``Q = B tau + Q_diss (+ Q_r)`` in SI, ``(B, dof)`` (the residual where ``features`` and ``qd_norm``
        are given)."""
        Q = self.dissipative_force(qd, params_norm, features, qd_norm)
        if self.residual is not None and features is not None and qd_norm is not None:
            Q = Q + self.residual(features, qd_norm, params_norm)
        return Q if tau is None else Q + self.input_force(tau)

    # ------------------------------------------------------------------ in the model's normalised units
    def attach_normalizer(self, normalizer: nn.Module) -> None:
        """The model's ``Normalizer`` (a reference: the model owns it), for the forces in its units."""
        self._normalizer_ref = (normalizer,)

    @property
    def normalizer(self) -> nn.Module:
        return self._normalizer_ref[0]

    def force_norm(self, qd_norm, params_norm, tau_norm=None, features=None) -> torch.Tensor:
        """``Q = B tau + Q_diss`` ``(B, dof)`` in the model's normalised Euler-Lagrange units at normalised
        velocities; ``tau_norm``: the inputs divided by ``normalizer.input_rms`` (None: none);
        ``features``: the model's features of ``q`` (the Rayleigh term reads them)."""
        norm = self.normalizer
        Q = self.state_force_at(qd_norm, params_norm, features)
        if tau_norm is not None:
            Q = Q + self.input_force(tau_norm * norm.input_rms.to(tau_norm.dtype))
        return norm.force_to_norm(Q)

    def dissipative_force_at(self, qd_norm, params_norm, features=None) -> torch.Tensor:
        """``Q_diss (B, dof)`` in SI at the normalised velocities ``qd_norm`` (``features``: as in
        ``force_norm``)."""
        norm = self.normalizer
        qd = qd_norm * (norm.coord_scale.to(qd_norm.dtype) / norm.time_scale.to(qd_norm.dtype))
        return self.dissipative_force(qd, params_norm, features, qd_norm)

    def residual_force_at(self, qd_norm, params_norm, features) -> torch.Tensor | None:
        """``Q_r (B, dof)`` in SI at the normalised velocities (None without a residual)."""
        if self.residual is None:
            return None
        return self.residual(features, qd_norm, params_norm)

    def state_force_at(self, qd_norm, params_norm, features=None) -> torch.Tensor:
        """``Q_diss + Q_r (B, dof)`` in SI: the model's generalised force of the state, all but the inputs
        (what the inverse dynamics subtracts; ``features``: as in ``force_norm``)."""
        Q = self.dissipative_force_at(qd_norm, params_norm, features)
        residual = self.residual_force_at(qd_norm, params_norm, features)
        return Q if residual is None else Q + residual

    def holding_torques(self, qdd_norm, force_norm, solve, qd_norm, params_norm):
        """``(U, lam)``: the normalised accelerations per N m at each joint ``U (B, dof, n_j)`` and static
        friction's holding torques ``lam (B, n_j)`` in N m (``with_static_friction``), from the model's
        normalised accelerations ``qdd_norm`` under ``force_norm`` and its solve under another force
        ``solve(force_norm)``. The accelerations are affine in the generalised force, so one more solve
        per joint gives ``U = M^-1 D^T``."""
        norm = self.normalizer
        D = self.joint_map.to(qdd_norm.dtype)  # (n_j, dof)
        unit = norm.force_to_norm(D)  # 1 N m at each joint, as normalised generalised forces
        U = torch.stack([solve(force_norm + unit[j]) - qdd_norm for j in range(D.shape[0])], -1)  # (B, dof, n_j)
        rho0 = norm.accel_to_phys(qdd_norm) @ D.T
        response = D @ norm.accel_to_phys(U.mT).mT
        qd = qd_norm * (norm.coord_scale / norm.time_scale).to(qd_norm.dtype)
        return U, self.holding_torque(qd, params_norm, rho0, response)

    def with_static_friction(self, qdd_norm, force_norm, solve, qd_norm, params_norm):
        """The normalised accelerations ``qdd_norm`` (under ``force_norm``) with static friction's holding
        torques added (``dissipation: joint+stiction``; unchanged otherwise)."""
        if not self.stiction:
            return qdd_norm
        U, lam = self.holding_torques(qdd_norm, force_norm, solve, qd_norm, params_norm)
        return qdd_norm + (U * lam[:, None, :]).sum(-1)
