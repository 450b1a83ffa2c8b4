"""The base of every dynamics model: normalisation glue, input checks, training terms, rollouts and
the model's declared capabilities. Subclasses give ``solve_norm`` (or ``acceleration_norm``) and, with
an energy, ``energy_norm``.

Every model works in normalised units internally (``Normalizer``); ``acceleration`` takes and
returns SI units. Shapes: ``q, qd (B, dof)``, ``params (B, P)`` -> ``(B, dof)``. What the base is
made of, each in its own module: the input features (``features.AngleFeatures``), the scene's
generalised forces (``forces.LearnedForces``), opt-in compilation (``compiled.CompiledDynamics``) and
the SI rigid-body face (``rigid_body.RigidBodyFace``: mass matrix, bias, gravity, friction, inverse
and forward dynamics, with its one convention).
"""

from __future__ import annotations

import contextlib
import math
import operator
import warnings

import torch
from torch import nn

from ..errors import InputError, UntrustedParameterWarning, check_tensors, values_readable
from ..mechanics import integrators
from ..mechanics.forces import check_inputs as check_tau
from ..perf import compile_pays
from ..systems.base import check_param_signs, param_extremes
from .capabilities import (
    ENERGY,
    FORCES,
    FRICTION,
    INVERSE_DYNAMICS,
    STATIC_FRICTION,
)
from .compiled import CompiledDynamics
from .features import AngleFeatures
from .forces import LearnedForces
from .normalization import Normalizer
from .rigid_body import RigidBodyFace
from .scene import SceneInfo


class _Provided:
    """A read-only flag of a model class and its instances: whether the class ``provides`` a capability
    (``has_energy``, ``uses_forces``, ``static_friction``: the flags that ``provides`` replaced, kept
    for code that reads them)."""

    def __init__(self, capability: str) -> None:
        self.capability = capability

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __get__(self, obj, owner=None) -> bool:
        return self.capability in (owner if owner is not None else type(obj)).provides

    def __set__(self, obj, value) -> None:
        raise AttributeError(f"{self.name} is read-only: it is whether the class provides '{self.capability}'")


class DynamicsModel(CompiledDynamics, RigidBodyFace, nn.Module):
    """Base: normalisation, input features and checks; subclasses give ``solve_norm`` or
    ``acceleration_norm``."""

    variant = ""  # the registry name (``lnn_torch.networks.registry``)
    # the model computes its parameter conditioning once per chunk when given ``chunks``
    chunk_conditioning = False
    # what the class can give beyond accelerations and rollouts (``capabilities``); the instance's
    # ``capabilities`` keeps those its scene allows. ``FORCES``: the scene's generalised forces through
    # ``LearnedForces`` (the direct MLP reads the inputs as features instead); ``STATIC_FRICTION`` needs
    # accelerations affine in the generalised force through a positive definite mass matrix (the joints'
    # response D M^-1 D^T to a torque)
    provides: frozenset[str] = frozenset()
    has_energy = _Provided(ENERGY)  # its own H = T + V (the energy regulariser)
    uses_forces = _Provided(FORCES)
    static_friction = _Provided(STATIC_FRICTION)

    def __init__(self, scene, learn_input_matrix: bool = False, dissipation: str = "joint",
                 friction: str = "viscous+coulomb") -> None:
        super().__init__()
        self.scene = SceneInfo.of(scene)
        dof = self.scene.dof
        self.normalizer = Normalizer(dof, self.scene.num_params, self.scene.angle_mask, self.scene.kinds,
                                     self.scene.num_inputs, self.scene.has_forces)
        self.angle_features = AngleFeatures(dof, self.scene.angle_mask, self.scene.angle_combinations)
        self.num_features = self.angle_features.num_features
        self.all_angles = self.angle_features.all_angles
        self.forces = None
        if self.scene.has_forces and FORCES in self.provides:
            self.forces = LearnedForces(self.scene, self.num_features, learn_input_matrix, dissipation,
                                        friction=friction)
            self.forces.attach_normalizer(self.normalizer)
            if self.forces.stiction and STATIC_FRICTION not in self.provides:
                raise InputError(f"dissipation 'joint+stiction' needs a positive definite mass matrix through which "
                                 f"accelerations are affine in the force (film_lnn, delan), "
                                 f"not variant '{self.variant}'")

    # ------------------------------------------------------------------ features
    def features(self, q_norm: torch.Tensor, tangents: bool = False):
        """Features ``[sin q_a, cos q_a, q_lin]`` ``(B, F)`` and, if asked, ``d phi / d q_k`` ``(dof, B, F)``;
        ``q_a`` are the angle coordinates and the scene's angle combinations (``G q``;
        ``features.AngleFeatures``)."""
        phi, dphi, _ = self.angle_features.compute(q_norm, tangents)
        return phi, dphi

    def _features(self, q_norm: torch.Tensor, tangents: bool):
        """``features`` plus ``(sin, cos)`` of the angles (reused by ``features_vjp``)."""
        return self.angle_features.compute(q_norm, tangents)

    def features_vjp(self, q_norm: torch.Tensor, g_phi: torch.Tensor, sin_cos=None) -> torch.Tensor:
        """Pull a feature gradient ``(B, F)`` back to ``(B, dof)`` through ``features``."""
        return self.angle_features.vjp(q_norm, g_phi, sin_cos)

    # ------------------------------------------------------------------ generalised forces
    def force_norm(self, q_norm, qd_norm, params_norm, tau_norm=None):
        """The model's generalised force ``Q`` in normalised units ``(B, dof)`` (inputs and learned
        dissipation, ``LearnedForces.force_norm``), or None for a model without forces. ``tau_norm``:
        the inputs divided by ``normalizer.input_rms``."""
        if self.forces is None:
            return None
        phi = self.features(q_norm)[0] if self.forces.rayleigh is not None else None
        return self.forces.force_norm(qd_norm, params_norm, tau_norm, phi)

    def tau_norm(self, tau):
        """Inputs in SI ``(B, n_u)`` -> normalised (None stays None)."""
        return None if tau is None else tau.to(self.dtype) / self.normalizer.input_rms.to(self.dtype)

    def with_static_friction(self, qdd_norm, force_norm, solve, qd_norm, params_norm):
        """The accelerations ``qdd_norm`` (under ``force_norm``) with static friction's holding torques
        added (``dissipation: joint+stiction``; unchanged otherwise; ``LearnedForces.with_static_friction``).
        ``solve(force_norm)`` gives the model's accelerations under another generalised force at the
        same state."""
        if self.forces is None or not self.forces.stiction:
            return qdd_norm
        return self.forces.with_static_friction(qdd_norm, force_norm, solve, qd_norm, params_norm)

    def holding_torques(self, qdd_norm, force_norm, solve, qd_norm, params_norm):
        """``(U, lam)``: static friction's response and holding torques (``LearnedForces.holding_torques``)."""
        return self.forces.holding_torques(qdd_norm, force_norm, solve, qd_norm, params_norm)

    def forced_acceleration_norm(self, solve, q_norm, qd_norm, params_norm, tau_norm=None) -> torch.Tensor:
        """Normalised accelerations under the model's generalised force at this state (inputs
        ``tau_norm``, friction), static friction included: ``solve(force_norm)`` is the model's solve
        at the state."""
        force = self.force_norm(q_norm, qd_norm, params_norm, tau_norm)
        return self.with_static_friction(solve(force), force, solve, qd_norm, params_norm)

    # ------------------------------------------------------------------ interface
    def acceleration_norm(self, q_norm, qd_norm, params_norm, tau_norm=None) -> torch.Tensor:
        """Normalised accelerations under the inputs ``tau_norm`` (None for an unactuated scene)."""
        return self.forced_acceleration_norm(lambda f: self.solve_norm(q_norm, qd_norm, params_norm, f),
                                             q_norm, qd_norm, params_norm, tau_norm)

    def solve_norm(self, q_norm, qd_norm, params_norm, force_norm=None) -> torch.Tensor:
        """The model's accelerations under a normalised generalised force (None: none)."""
        raise NotImplementedError

    def energy_norm(self, q_norm, qd_norm, params_norm):
        """The model's own Hamiltonian ``H``, kinetic-like ``T`` and potential-like ``V`` (normalised)."""
        raise NotImplementedError(f"variant '{self.variant}' has no energy")

    def acceleration_and_energy_norm(self, q_norm, qd_norm, params_norm, chunks: int | None = None, force_norm=None):
        """``(qdd, H, T, V)`` in normalised units; subclasses share work between the two.

        ``chunks``: the batch is ``chunks`` runs of consecutive rows, each with ONE parameter vector
        (training chunks of one trajectory each); a model may compute its parameter conditioning
        once per run. The parameters must then be constant within each run (not checked here)."""
        return (self.solve_norm(q_norm, qd_norm, params_norm, force_norm),
                *self.energy_norm(q_norm, qd_norm, params_norm))

    def check_inputs(self, q, qd, params, tau=None, inputs: bool = True) -> None:
        """Raise ``InputError`` naming what is wrong with shapes, NaN, parameter signs and (unless
        ``inputs`` is False) the inputs ``tau`` (given iff the scene is actuated)."""
        check_tensors(("q", "qd", "tau"), q=q, qd=qd, params=params, tau=tau)
        dof, P = self.scene.dof, self.scene.num_params
        if q.ndim != 2 or q.shape[-1] != dof:
            raise InputError(f"q must have shape (batch, {dof}), got {tuple(q.shape)}")
        if qd.shape != q.shape:
            raise InputError(f"qd must have the shape of q {tuple(q.shape)}, got {tuple(qd.shape)}")
        if q.shape[0] == 0:
            raise InputError("q has no rows: an empty batch (0, dof) has nothing to compute")
        if params.ndim != 2 or params.shape != (q.shape[0], P):
            raise InputError(f"params must have shape ({q.shape[0]}, {P}) for scene '{self.scene.name}', "
                             f"got {tuple(params.shape)}")
        if inputs:
            check_tau(tau, self.scene.num_inputs, q.shape[:1])
        if not values_readable():  # (vmap, jacrev: no single value to check; the shapes are)
            return
        named = [(n, x) for n, x in (("q", q), ("qd", qd), ("params", params), ("tau", tau)) if x is not None]
        # one sum over everything is finite unless something is NaN or Inf (or the sum overflows): only
        # then is each tensor checked, to name it
        if not math.isfinite(float(torch.cat([x.detach().reshape(x.shape[0], -1) for _, x in named], -1).sum())):
            for name, x in named:
                if not torch.isfinite(x).all():
                    raise InputError(f"{name} contains NaN or Inf")
        extremes = param_extremes(params) if P else None  # one reduction for the signs and the trusted range
        names = self.scene.param_names or [f"params[{i}]" for i in range(P)]
        check_param_signs(params, self.scene.kinds, names, "params", None if extremes is None else extremes[0])
        normalizer = getattr(self, "normalizer", None)
        if normalizer is not None and P:
            note = normalizer.untrusted(params, names, self.scene.param_units or [""] * P, extremes)
            if note:
                warnings.warn(note, UntrustedParameterWarning, stacklevel=3)

    def normalize(self, q, qd, params):
        q_norm, qd_norm = self.normalizer.state(q, qd)
        return q_norm, qd_norm, self.normalizer.params(params)

    def fit_normalizer(self, stats: dict) -> None:
        """Set the normalisation from training data (SI): ``q, qd, qdd (n, dof)``, ``params (m, P)``
        per trajectory, ``params_points (n, P)`` aligned with the points and, for an actuated scene,
        the inputs ``tau (n, n_u)``."""
        tau = stats.get("tau")
        B = None if self.scene.input_matrix is None else torch.tensor(self.scene.input_matrix, dtype=torch.float64)
        input_force = None if tau is None or B is None else tau.double() @ B.T
        self.normalizer.fit(stats["q"], stats["qd"], stats["qdd"], stats["params"], input_force, tau)
        if self.forces is not None and self.forces.friction:
            D = self.forces.joint_map.double()
            rates = stats["qd"].double().reshape(-1, self.scene.dof) @ D.T
            torque = float(1 / self.normalizer.force_scale) if input_force is not None else 1.0
            self.forces.fit_units(torque, float(rates.pow(2).mean().sqrt()))

    def training_terms(self, q, qd, qdd, params, tau=None, energy: bool = False, chunks: int | None = None,
                       torque: bool = False) -> dict:
        """What the training loss compares, from a batch in SI units (``(B, dof)``, ``(B, P)``,
        inputs ``tau (B, n_u)``).

        Returns a dict in normalised units: ``pred``, ``target``, ``rms`` (weights each component);
        with ``energy``, the model's own ``H``, ``T``, ``V`` and, for a model with forces, the
        ``power`` of its generalised force (``qd . Q``, for the power-balance term); with ``torque``
        (structured models of actuated scenes), the inputs of its inverse dynamics ``tau_pred`` and
        the data's ``tau_target``, both divided by their rms. Lagrangian models and the direct MLP
        predict accelerations. ``chunks``: see ``acceleration_and_energy_norm``.
        """
        q_n, qd_n, p_n = self.normalize(q, qd, params)
        out = {"target": self.normalizer.accel_to_norm(qdd), "rms": self.normalizer.accel_rms.to(q.dtype)}
        tau_n = None if tau is None else tau / self.normalizer.input_rms.to(tau.dtype)
        if torque:
            if INVERSE_DYNAMICS not in self.capabilities or tau is None:
                raise InputError(f"a torque loss needs a structured model of an actuated scene with inputs in the "
                                 f"data (variant '{self.variant}', {self.scene.num_inputs} inputs)")
            Btau = self.inverse_dynamics_norm(q_n, qd_n, out["target"], p_n, chunks)
            out["tau_pred"], out["tau_target"] = self.forces.solve_inputs(Btau) / self.normalizer.input_rms, tau_n
        if energy or (chunks is not None and self.chunk_conditioning):
            force = self.force_norm(q_n, qd_n, p_n, tau_n)
            out["pred"], H, T, V = self.acceleration_and_energy_norm(q_n, qd_n, p_n, chunks, force)
            out["pred"] = self.with_static_friction(out["pred"], force, lambda f: self.solve_norm(q_n, qd_n, p_n, f),
                                                    qd_n, p_n)
            if energy:
                out.update(H=H, T=T, V=V)
                if force is not None:
                    out["power"] = (qd_n * force).sum(-1)
            return out
        out["pred"] = self.acceleration_norm(q_n, qd_n, p_n, tau_n)
        return out

    def rollout(self, q0, qd0, params, dt: float, num_steps: int, method: str = "rk4", tau=None):
        """Integrate the learned dynamics from ``(q0, qd0)`` (SI units, ``(B, dof)``, params ``(B, P)``;
        inputs ``tau (B, num_steps, n_u)`` held over each step for an actuated scene).

        Returns ``(q, qd)``, each ``(B, num_steps + 1, dof)``. Second-order models integrate their
        accelerations with ``lnn_torch.mechanics.integrators.rollout``; Hamiltonian models their own flow.
        What the model derives from the parameters alone (FiLM) is computed once per rollout.
        """
        num_steps = self.check_rollout_inputs(q0, num_steps, tau)
        self.check_inputs(q0, qd0, params, None if tau is None else tau[:, 0])
        step = integrators.METHODS.get(method)  # an unknown name is refused by the eager path
        if step is not None and (self._compile is True
                                 or (self._compile == "auto" and compile_pays(num_steps * step.stages))):
            integrators.check_rollout(q0, qd0, params, dt, num_steps, method, tau=tau)
            out = self._compiled_rollout(q0, qd0, params, dt, num_steps, method, tau)
            if out is not None:
                return out
        return integrators.rollout(self.acceleration_fn(params), q0, qd0, params, dt, num_steps, method, tau=tau)

    def check_rollout_inputs(self, q0, num_steps, tau) -> int:
        """``num_steps`` as an int, and the inputs ``tau`` of an actuated scene checked as a rollout takes them,
        ``(batch, num_steps, inputs)``: ``InputError`` in one line naming what is wrong (before the per-step
        checks, whose message would name one step's shape)."""
        try:
            num_steps = operator.index(num_steps)
        except TypeError:
            raise InputError(f"num_steps must be an integer, got {num_steps!r}") from None
        n_u = self.scene.num_inputs
        if n_u and (tau is None or tau.ndim != 3 or tuple(tau.shape) != (q0.shape[0], num_steps, n_u)):
            shape = (q0.shape[0], num_steps, n_u) if q0.ndim == 2 else ("batch", num_steps, n_u)
            got = "none" if tau is None else tuple(tau.shape)
            raise InputError(f"tau must have shape {shape} (batch, num_steps, inputs: each held over its step) for "
                             f"scene '{self.scene.name}', got {got}")
        return num_steps

    def rollout_conditioning(self, params: torch.Tensor) -> tuple[str, torch.Tensor, tuple]:
        """``(name, params_norm, cond)``: the method ``name(q_norm, qd_norm, params_norm, *cond[, tau_norm])``
        that gives normalised accelerations, and what it needs from the parameters alone (computed once
        per rollout, passed to the compiled step as tensors)."""
        return "acceleration_norm", self.normalizer.params(params.to(self.dtype)), ()

    def acceleration_fn(self, params: torch.Tensor):
        """``(q, qd, params[, tau]) -> qdd`` (SI, unchecked) for states of systems with these ``params``
        ``(B, P)``: the model's parameter conditioning is computed once, here, and reused by every
        call, which must pass these same ``params``. Integrators call it at every stage."""

        def accel(q, qd, params, tau=None):
            return self.acceleration(q, qd, params, tau, check=False)

        return accel

    def acceleration(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor, tau: torch.Tensor | None = None,
                     check: bool = True) -> torch.Tensor:
        """Accelerations in SI units: ``(B, dof), (B, dof), (B, P)[, tau (B, n_u)] -> (B, dof)``.

        ``tau``: the inputs of an actuated scene (required there, refused otherwise). The networks
        run in their own dtype; the result has the dtype and device of ``q``. Compiled after
        ``compile_dynamics()``.
        """
        if check:
            self.check_inputs(q, qd, params, tau)
        # compiled, the whole call is one program: the normalisation too (about a dozen small operators, a
        # quarter of a batch-1 call when run eagerly around the compiled solve)
        return self._run(*self._inference_call(q, qd, params, tau))

    def _inference_call(self, q, qd, params, tau=None) -> tuple:
        """``(fn, *args)`` that ``acceleration`` runs (compiled after ``compile_dynamics()``):
        ``_acceleration_whole``; a model with a faster path for calls without a gradient gives it here."""
        return self._acceleration_whole, q, qd, params, tau

    def _acceleration_whole(self, q, qd, params, tau=None):
        """``acceleration`` without its checks: SI in, SI out (what the compiled path compiles whole)."""
        extra = () if tau is None else (self.tau_norm(tau),)
        params_norm = self.normalizer.params(params.to(self.dtype))
        return self._acceleration_si(self.acceleration_norm, q, qd, params_norm, *extra)

    def _acceleration_si(self, fn, q, qd, params_norm, *extra):
        """SI accelerations from ``fn(q_norm, qd_norm, params_norm, *extra)`` (normalised units), run
        through ``_run`` (compiled after ``compile_dynamics()``); the result has ``q``'s dtype."""
        dtype = self.dtype
        q_norm, qd_norm = self.normalizer.state(q.to(dtype), qd.to(dtype))
        return self.normalizer.accel_to_phys(self._run(fn, q_norm, qd_norm, params_norm, *extra)).to(q.dtype)

    @property
    def dtype(self) -> torch.dtype:
        """The dtype the model computes in: its normaliser's, which ``.double()``, ``.float()`` and ``.to(dtype)``
        cast with its parameters (read every call: walking the parameters cost 15 us of a 460 us call at
        batch 1)."""
        return self.normalizer.time_scale.dtype

    def regularization(self) -> torch.Tensor | None:
        """A term the training loss adds (priors of the model's parts on physical parameters), or None."""
        return None

    def coefficient_parameters(self) -> list[nn.Parameter]:
        """The parameters that are physical coefficients, not network weights (a friction coefficient,
        a learned input matrix, a potential's or a rigid chain's constants): training exempts them
        from weight decay, which would pull a mass or a length towards zero."""
        return [] if self.forces is None else self.forces.coefficient_parameters()

    # ------------------------------------------------------------------ capabilities
    @property
    def capabilities(self) -> frozenset[str]:
        """What this model gives beyond accelerations and rollouts: the class's ``provides`` less what
        its scene rules out (inverse dynamics needs inputs; friction and static friction need the
        scene's friction, learned by the model's ``LearnedForces``; forces need inputs or friction)."""
        caps = set(self.provides)
        forces = self.forces
        if forces is None or not forces.num_inputs:
            caps.discard(INVERSE_DYNAMICS)
        if forces is None or not forces.friction:
            caps.discard(FRICTION)
        if forces is None or not forces.stiction:
            caps.discard(STATIC_FRICTION)
        if forces is None:
            caps.discard(FORCES)
        return frozenset(caps)

    def missing(self, *needed: str) -> str | None:
        """Why this model cannot give the capabilities ``needed`` (a sentence), or None if it can."""
        lacking = [c for c in needed if c not in self.capabilities]
        if not lacking:
            return None
        scene = self.scene.name
        ruled_out = {INVERSE_DYNAMICS: f"scene '{scene}' has no inputs (inverse dynamics needs them)",
                     FRICTION: f"scene '{scene}' has no friction",
                     STATIC_FRICTION: "the model has no static friction (dissipation 'joint+stiction')",
                     FORCES: f"scene '{scene}' has no generalised forces (inputs or friction)"}
        absent = [c for c in lacking if c not in self.provides]
        if absent:
            return f"variant '{self.variant}' does not provide {', '.join(absent)}"
        return "; ".join(ruled_out.get(c, c) for c in lacking)

    def _require(self, capability: str) -> None:
        reason = self.missing(capability)
        if reason is not None:
            raise InputError(reason)

    _nan_depth = 0  # how many ``nan_on_singular()`` blocks the model is in

    @property
    def raise_on_singular(self) -> bool:
        """Whether undefined accelerations (singular Hessians) raise; False only within ``nan_on_singular()``."""
        return self._nan_depth == 0

    @contextlib.contextmanager
    def nan_on_singular(self):
        """Within the block, undefined accelerations (``NAN_ON_SINGULAR`` models: the black-box LNN's
        singular Hessians) are NaN instead of raising ``SingularHessianError`` (nested blocks allowed)."""
        self._nan_depth += 1
        try:
            yield self
        finally:
            self._nan_depth -= 1

    forward = acceleration
