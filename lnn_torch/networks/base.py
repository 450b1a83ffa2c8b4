"""The base of every dynamics model: normalisation glue, input features, input checks, rollouts and
(opt-in) compilation. Subclasses give ``acceleration_norm`` (and, with an energy, ``energy_norm``).

Every model works in normalised units internally (``Normalizer``); ``acceleration`` takes and
returns SI units. Shapes: ``q, qd (B, dof)``, ``params (B, P)`` -> ``(B, dof)``.
"""

from __future__ import annotations

import contextlib
import math
import warnings
from dataclasses import dataclass

import torch
from torch import nn

from .. import integrators
from ..errors import InputError, SingularHessianError, UntrustedParameterWarning
from ..perf import CompiledFallback, apply_cpu_defaults, compile_fn, compile_pays, warn_compile_failure
from .capabilities import (  # noqa: F401 - the capability names, also importable from here
    CAPABILITIES,
    ENERGY,
    FRICTION,
    INVERSE_DYNAMICS,
    MASS_MATRIX,
    NAN_ON_SINGULAR,
    STATIC_FRICTION,
)
from .normalization import Normalizer


def wrap_angle(q: torch.Tensor) -> torch.Tensor:
    """``q`` reduced to [-pi, pi), same dtype. The reduction runs in float64 where the device has it:
    in float32, ``remainder(q + pi, 2 pi)`` loses up to 3e-4 rad at |q| = 1e4 (q + pi is rounded to
    the float32 grid there), while float64 keeps the reduced angle exact to ~1e-12."""
    wide = torch.float64 if q.device.type in ("cpu", "cuda") else q.dtype
    return (torch.remainder(q.to(wide) + math.pi, 2 * math.pi) - math.pi).to(q.dtype)


@dataclass(frozen=True)
class SceneInfo:
    """What a model needs to know about a scene: its coordinates, parameters and generalised forces
    (``input_matrix`` (dof, n_u) of the inputs; joint ``friction`` on the rates ``joint_map @ qd``,
    ``lnn_torch.forces``). A conservative scene has neither, and a model of it builds none."""

    name: str
    dof: int
    angle_mask: tuple[bool, ...]
    num_params: int
    quadratic_kinetic: bool = True
    param_kinds: tuple[str, ...] = ()  # "positive" / "nonnegative" per parameter; empty: all positive
    input_matrix: tuple[tuple[float, ...], ...] | None = None
    friction: bool = False
    joint_map: tuple[tuple[float, ...], ...] | None = None
    coulomb_velocity: float = 0.05
    # further angles (rows: coefficients over the coordinates) whose sin/cos are features, e.g. the
    # absolute angle q1 + q2 of a link in a chain measured in joint angles
    angle_combinations: tuple[tuple[float, ...], ...] | None = None
    param_names: tuple[str, ...] = ()  # for messages; empty: params[i]
    param_units: tuple[str, ...] = ()
    robot_description: str | None = None  # a robot arm's description (its scene config's ``description``)

    @property
    def num_inputs(self) -> int:
        return 0 if self.input_matrix is None else len(self.input_matrix[0])

    @property
    def has_forces(self) -> bool:
        return self.num_inputs > 0 or self.friction

    @property
    def kinds(self) -> tuple[str, ...]:
        return self.param_kinds or ("positive",) * self.num_params

    @classmethod
    def of(cls, scene) -> "SceneInfo":
        """From a ``System``, a ``System.describe()`` dict or a ``SceneInfo``."""
        if isinstance(scene, SceneInfo):
            return scene
        d = scene if isinstance(scene, dict) else scene.describe()
        as_tuple = lambda m: None if m is None else tuple(tuple(float(x) for x in row) for row in m)  # noqa: E731
        return cls(d["name"], int(d["dof"]), tuple(bool(a) for a in d["angle_mask"]), len(d["param_names"]),
                   bool(d.get("quadratic_kinetic", True)), tuple(d.get("param_kinds", ())),
                   as_tuple(d.get("input_matrix")), d.get("friction") is not None,
                   as_tuple(d.get("joint_map")), float(d.get("coulomb_velocity", 0.05)),
                   as_tuple(d.get("angle_combinations")), tuple(d.get("param_names", ())),
                   tuple(d.get("param_units", ())), (d.get("config") or {}).get("description"))


class DynamicsModel(nn.Module):
    """Base: normalisation, input features and checks; subclasses give ``acceleration_norm``."""

    variant = ""  # the registry name (``lnn_torch.networks.registry``)
    has_energy = True  # the model has its own Hamiltonian H = T + V for the energy regulariser
    # the model computes its parameter conditioning once per chunk when given ``chunks``
    chunk_conditioning = False

    # the model represents the scene's generalised forces with ``LearnedForces`` (the direct MLP
    # reads the inputs as features instead)
    uses_forces = True
    # static friction needs accelerations affine in the generalised force through a positive definite
    # mass matrix (the joints' response D M^-1 D^T to a torque)
    static_friction = True
    # what the class can give beyond accelerations and rollouts (the constants above); the instance's
    # ``capabilities`` keeps those its scene allows
    provides: frozenset[str] = frozenset()

    def __init__(self, scene, learn_input_matrix: bool = False, dissipation: str = "joint") -> None:
        super().__init__()
        apply_cpu_defaults()  # once per process; LNN_TORCH_CPU_TUNING=0 leaves the process as it is
        self.scene = SceneInfo.of(scene)
        dof = self.scene.dof
        self.normalizer = Normalizer(dof, self.scene.num_params, self.scene.angle_mask, self.scene.kinds,
                                     self.scene.num_inputs, self.scene.has_forces)
        angles = [i for i, a in enumerate(self.scene.angle_mask) if a]
        linear = [i for i, a in enumerate(self.scene.angle_mask) if not a]
        self.register_buffer("angle_idx", torch.tensor(angles, dtype=torch.long), persistent=False)
        self.register_buffer("linear_idx", torch.tensor(linear, dtype=torch.long), persistent=False)
        # the feature angles G q (rows: each angle coordinate, then the scene's angle combinations) and
        # d(feature)/dq_k selectors: sel_angle = G^T (dof, n_feature_angles), sel_linear (dof, n_linear)
        G = torch.eye(dof)[angles]
        combos = self.scene.angle_combinations
        if combos:
            C = torch.tensor(combos, dtype=torch.float32)
            if C.shape[1] != dof or (C[:, linear] != 0).any():
                raise InputError(f"angle_combinations must be rows of {dof} coefficients over angle coordinates only")
            G = torch.cat([G, C])
        self.register_buffer("sel_angle", G.T.contiguous(), persistent=False)
        self.register_buffer("sel_linear", torch.eye(dof)[:, linear], persistent=False)
        self.num_features = 2 * G.shape[0] + len(linear)
        self.all_angles = not linear
        self.combined_angles = bool(combos)
        self.plain_angles = self.all_angles and not combos  # the features read q itself
        self.forces = None
        if self.scene.has_forces and self.uses_forces:
            from .forces import LearnedForces

            self.forces = LearnedForces(self.scene, self.num_features, learn_input_matrix, dissipation)
            if self.forces.stiction and not self.static_friction:
                raise InputError(f"dissipation 'joint+stiction' needs a positive definite mass matrix through which "
                                 f"accelerations are affine in the force (film_lnn, delan), not variant '{self.variant}'")

    # ------------------------------------------------------------------ features
    def features(self, q_norm: torch.Tensor, tangents: bool = False):
        """Features ``[sin q_a, cos q_a, q_lin]`` ``(B, F)`` and, if asked, ``d phi / d q_k`` ``(dof, B, F)``;
        ``q_a`` are the angle coordinates and the scene's angle combinations (``G q``).

        On the CPU, sin/cos read the raw angles: torch's CPU kernels reduce large arguments exactly
        (``tests/test_stability.py::test_angle_features_are_exact_at_1e4_rad``). On other devices the angles are first wrapped to [-pi, pi) in float64
        (``wrap_angle``), in case a device kernel reduces large arguments inexactly. The dynamics
        and rollouts never see wrapped angles.
        """
        phi, dphi, _ = self._features(q_norm, tangents)
        return phi, dphi

    def _feature_angles(self, q_norm: torch.Tensor) -> torch.Tensor:
        if self.plain_angles:
            return q_norm
        if self.combined_angles:
            return q_norm @ self.sel_angle.to(q_norm.dtype)
        return q_norm[..., self.angle_idx]

    def _features(self, q_norm: torch.Tensor, tangents: bool):
        """``features`` plus ``(sin, cos)`` of the angles (reused by ``features_vjp``)."""
        qa = self._feature_angles(q_norm)
        if qa.device.type != "cpu":
            qa = wrap_angle(qa)
        s, c = torch.sin(qa), torch.cos(qa)
        phi = torch.cat([s, c] if self.all_angles else [s, c, q_norm[..., self.linear_idx]], -1)
        if not tangents:
            return phi, None, (s, c)
        sa = self.sel_angle.to(q_norm.dtype)[:, None, :]  # (dof, 1, n_angles)
        parts = [sa * c, sa * -s]
        if not self.all_angles:
            parts.append(self.sel_linear.to(q_norm.dtype)[:, None, :].expand(-1, q_norm.shape[0], -1))
        return phi, torch.cat(parts, -1), (s, c)  # dphi: (dof, B, F)

    def features_vjp(self, q_norm: torch.Tensor, g_phi: torch.Tensor, sin_cos=None) -> torch.Tensor:
        """Pull a feature gradient ``(B, F)`` back to ``(B, dof)`` through ``features``."""
        na = self.sel_angle.shape[1]
        if sin_cos is None:
            qa = self._feature_angles(q_norm)
            sin_cos = torch.sin(qa), torch.cos(qa)
        s, c = sin_cos
        g_angle = g_phi[..., :na] * c - g_phi[..., na : 2 * na] * s
        if self.plain_angles:
            return g_angle
        out = g_angle @ self.sel_angle.to(g_phi.dtype).T
        if not self.all_angles:
            out = out + g_phi[..., 2 * na :] @ self.sel_linear.to(g_phi.dtype).T
        return out

    # ------------------------------------------------------------------ generalised forces
    def force_norm(self, q_norm, qd_norm, params_norm, tau_norm=None):
        """The model's generalised force ``Q`` in normalised units ``(B, dof)`` (inputs and learned
        dissipation, ``LearnedForces``), or None for a model without forces. ``tau_norm``: the
        inputs divided by ``normalizer.input_rms``."""
        if self.forces is None:
            return None
        norm = self.normalizer
        scale, tau_t = norm.coord_scale.to(qd_norm.dtype), norm.time_scale.to(qd_norm.dtype)
        qd = qd_norm * (scale / tau_t)
        tau = None if tau_norm is None else tau_norm * norm.input_rms.to(tau_norm.dtype)
        phi = self.features(q_norm)[0] if self.forces.rayleigh is not None else None
        return norm.force_to_norm(self.forces.force(qd, params_norm, tau, phi, qd_norm))

    def tau_norm(self, tau):
        """Inputs in SI ``(B, n_u)`` -> normalised (None stays None)."""
        return None if tau is None else tau.to(self.dtype) / self.normalizer.input_rms.to(self.dtype)

    def with_static_friction(self, qdd_norm, force_norm, solve, qd_norm, params_norm):
        """The accelerations ``qdd_norm`` (under ``force_norm``) with static friction's holding torques
        added (``dissipation: joint+stiction``; unchanged otherwise). ``solve(force_norm)`` gives the
        model's accelerations under another generalised force at the same state."""
        if self.forces is None or not self.forces.stiction:
            return qdd_norm
        U, lam = self.holding_torques(qdd_norm, force_norm, solve, qd_norm, params_norm)
        return qdd_norm + (U * lam[:, None, :]).sum(-1)

    def holding_torques(self, qdd_norm, force_norm, solve, qd_norm, params_norm):
        """``(U, lam)``: the normalised accelerations per N m at each joint ``U (B, dof, n_j)`` and static
        friction's holding torques ``lam (B, n_j)`` in N m (``with_static_friction``). The accelerations
        are affine in the generalised force, so one more solve per joint gives ``U = M^-1 D^T``."""
        forces, norm = self.forces, self.normalizer
        D = forces.joint_map.to(qdd_norm.dtype)  # (n_j, dof)
        unit = norm.force_to_norm(D)  # 1 N m at each joint, as normalised generalised forces
        U = torch.stack([solve(force_norm + unit[j]) - qdd_norm for j in range(D.shape[0])], -1)  # (B, dof, n_j)
        rho0 = norm.accel_to_phys(qdd_norm) @ D.T
        response = D @ norm.accel_to_phys(U.mT).mT
        qd = qd_norm * (norm.coord_scale / norm.time_scale).to(qd_norm.dtype)
        return U, forces.holding_torque(qd, params_norm, rho0, response)

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
        return (self.solve_norm(q_norm, qd_norm, params_norm, force_norm), *self.energy_norm(q_norm, qd_norm, params_norm))

    def check_inputs(self, q, qd, params, tau=None, inputs: bool = True) -> None:
        """Raise ``InputError`` naming what is wrong with shapes, NaN, parameter signs and (unless
        ``inputs`` is False) the inputs ``tau`` (given iff the scene is actuated)."""
        from ..forces import check_inputs
        from ..systems.base import check_param_signs

        dof, P = self.scene.dof, self.scene.num_params
        if q.ndim != 2 or q.shape[-1] != dof:
            raise InputError(f"q must have shape (batch, {dof}), got {tuple(q.shape)}")
        if qd.shape != q.shape:
            raise InputError(f"qd must have the shape of q {tuple(q.shape)}, got {tuple(qd.shape)}")
        if params.ndim != 2 or params.shape != (q.shape[0], P):
            raise InputError(f"params must have shape ({q.shape[0]}, {P}) for scene '{self.scene.name}', "
                             f"got {tuple(params.shape)}")
        if inputs:
            check_inputs(tau, self.scene.num_inputs, q.shape[:1])
        named = [(n, x) for n, x in (("q", q), ("qd", qd), ("params", params), ("tau", tau)) if x is not None]
        # one sum over everything is finite unless something is NaN or Inf (or the sum overflows): only
        # then is each tensor checked, to name it
        if not math.isfinite(float(torch.cat([x.reshape(x.shape[0], -1) for _, x in named], -1).sum())):
            for name, x in named:
                if not torch.isfinite(x).all():
                    raise InputError(f"{name} contains NaN or Inf")
        check_param_signs(params, self.scene.kinds, [f"params[{i}]" for i in range(P)], "params")
        normalizer = getattr(self, "normalizer", None)
        if normalizer is not None and P:
            note = normalizer.untrusted(params, self.scene.param_names or [f"params[{i}]" for i in range(P)],
                                        self.scene.param_units or [""] * P)
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
        accelerations with ``lnn_torch.integrators.rollout``; Hamiltonian models their own flow.
        What the model derives from the parameters alone (FiLM) is computed once per rollout.
        """
        self.check_inputs(q0, qd0, params, None if tau is None else tau[:, 0])
        step = integrators.METHODS.get(method)  # an unknown name is refused by the eager path
        if step is not None and (self._compile is True
                                 or (self._compile == "auto" and compile_pays(num_steps * step.stages))):
            integrators.check_rollout(q0, qd0, params, dt, num_steps, method, tau=tau)
            out = self._compiled_rollout(q0, qd0, params, dt, num_steps, method, tau)
            if out is not None:
                return out
        return integrators.rollout(self.acceleration_fn(params), q0, qd0, params, dt, num_steps, method, tau=tau)

    def rollout_conditioning(self, params: torch.Tensor) -> tuple[str, torch.Tensor, tuple]:
        """``(name, params_norm, cond)``: the method ``name(q_norm, qd_norm, params_norm, *cond[, tau_norm])``
        that gives normalised accelerations, and what it needs from the parameters alone (computed once
        per rollout, passed to the compiled step as tensors)."""
        return "acceleration_norm", self.normalizer.params(params.to(self.dtype)), ()

    def _rollout_step(self, name: str, method: str, dt: float, q, qd, params_norm, cond: tuple, tau=None):
        """One integrator step in SI units from precomputed conditioning: a pure function of its tensors
        (``rollout`` compiles it whole: the four RK4 stages in one program)."""
        fn = getattr(self, name)
        extra = () if tau is None else (self.tau_norm(tau),)

        def accel(q_, qd_, _params):
            return self._acceleration_si(fn, q_, qd_, params_norm, *cond, *extra)

        return integrators.METHODS[method](accel, q, qd, params_norm, dt)

    def _compiled_rollout(self, q0, qd0, params, dt, num_steps, method, tau):
        """``rollout`` through the compiled ``_rollout_step`` (compiled once per batch shape, dtype, grad
        mode, method and step); None after a compilation failure (warned once; the caller continues
        eagerly)."""
        compiled = self._compiled_fn(self._rollout_step, q0.device, "rollout", eager=False)
        name, params_norm, cond = self.rollout_conditioning(params)
        qs, qds, q, qd = [q0], [qd0], q0, qd0
        for i in range(num_steps):
            out = compiled(name, method, float(dt), q, qd, params_norm, cond, None if tau is None else tau[:, i])
            if out is None:  # failed (warned): the whole rollout is redone eagerly
                return None
            q, qd = out
            qs.append(q)
            qds.append(qd)
        return torch.stack(qs, dim=1), torch.stack(qds, dim=1)

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
        extra = () if tau is None else (self.tau_norm(tau),)
        return self._acceleration_si(self.acceleration_norm, q, qd, self.normalizer.params(params.to(self.dtype)), *extra)

    def _acceleration_si(self, fn, q, qd, params_norm, *extra):
        """SI accelerations from ``fn(q_norm, qd_norm, params_norm, *extra)`` (normalised units), run
        through ``_run`` (compiled after ``compile_dynamics()``); the result has ``q``'s dtype."""
        dtype = self.dtype
        q_norm, qd_norm = self.normalizer.state(q.to(dtype), qd.to(dtype))
        return self.normalizer.accel_to_phys(self._run(fn, q_norm, qd_norm, params_norm, *extra)).to(q.dtype)

    # ------------------------------------------------------------------ compilation
    _compile = "auto"  # "auto" (long rollouts compiled), True (always), False (never) or "failed"
    _compiled: dict | None = None  # compiled functions by name

    def compile_dynamics(self, enabled: bool | str = True) -> "DynamicsModel":
        """Choose when ``acceleration``, and so ``rollout``, runs through ``torch.compile``.

        ``"auto"`` (the default): eagerly, except a rollout long enough to repay the compilation
        (``perf.AUTO_COMPILE_CALLS`` acceleration calls or more; the environment variable
        ``LNN_TORCH_COMPILE=0`` switches it off), whose integrator step is compiled whole (all its
        stages in one program). ``True``: accelerations and every rollout compiled. ``False``: never.

        Compiled on first use for each batch shape, dtype and grad mode (10-30 s each the first
        time; inductor caches compiled code on disk across processes, later compilations take a few
        seconds); the C++ wrapper on the CPU (``lnn_torch.perf.compile_fn``). If compilation or a
        compiled call fails, a warning is issued once and the model continues eagerly. Returns the model.
        """
        if enabled not in (True, False, "auto"):
            raise ValueError(f"compile_dynamics takes True, False or 'auto', got {enabled!r}")
        self._compile, self._compiled = enabled, {}
        return self

    def _run(self, fn, *args):
        """``fn(*args)``, compiled after ``compile_dynamics(True)`` (with the eager fallback); inside a
        compiled rollout step it is part of that step's program."""
        if self._compile is not True or torch.compiler.is_compiling():
            return fn(*args)
        return self._compiled_fn(fn, args[0].device, "accelerations")(*args)

    def _compiled_fn(self, fn, device, what: str, eager: bool = True) -> CompiledFallback:
        """``fn`` compiled with the eager fallback (``perf.CompiledFallback`` over ``perf.compile_fn``),
        built on first use and kept by its name; the model's own errors (``InputError``, a singular
        Hessian) pass through, any other failure is ``_compile_failed``."""
        if self._compiled is None:
            self._compiled = {}
        compiled = self._compiled.get(fn.__name__)
        if compiled is None:
            compiled = self._compiled[fn.__name__] = CompiledFallback(
                fn, device, on_failure=lambda err: self._compile_failed(what, err),
                passthrough=(InputError, SingularHessianError), eager=eager, compiler=compile_fn)
        return compiled

    def _compile_failed(self, what: str, err: Exception) -> None:
        """Warn once that compiled ``what`` failed and continue eagerly from now on."""
        warn_compile_failure(what, err, "continuing eagerly", stacklevel=7)
        self._compile, self._compiled = "failed", {}

    def __getstate__(self):
        state = super().__getstate__()  # a copy of __dict__
        if "_compiled" in state:
            state["_compiled"] = {}  # compiled code is rebuilt on first use (copies, pickles)
        return state

    @property
    def dtype(self) -> torch.dtype:
        return next(self.parameters()).dtype

    def coefficient_parameters(self) -> list[nn.Parameter]:
        """The parameters that are physical coefficients, not network weights (a friction coefficient,
        a learned input matrix, a potential's or a rigid chain's constants): training exempts them
        from weight decay, which would pull a mass or a length towards zero."""
        return [] if self.forces is None else self.forces.coefficient_parameters()

    # ------------------------------------------------------------------ capabilities and SI accessors
    @property
    def capabilities(self) -> frozenset[str]:
        """What this model gives beyond accelerations and rollouts: the class's ``provides`` less what
        its scene rules out (inverse dynamics needs inputs; friction and static friction need the
        scene's friction, learned by the model's ``LearnedForces``)."""
        caps = set(self.provides)
        forces = self.forces
        if forces is None or not forces.num_inputs:
            caps.discard(INVERSE_DYNAMICS)
        if forces is None or not forces.friction:
            caps.discard(FRICTION)
        if forces is None or not forces.stiction:
            caps.discard(STATIC_FRICTION)
        return frozenset(caps)

    def missing(self, *needed: str) -> str | None:
        """Why this model cannot give the capabilities ``needed`` (a sentence), or None if it can."""
        lacking = [c for c in needed if c not in self.capabilities]
        if not lacking:
            return None
        scene = self.scene.name
        ruled_out = {INVERSE_DYNAMICS: f"scene '{scene}' has no inputs (inverse dynamics needs them)",
                     FRICTION: f"scene '{scene}' has no friction",
                     STATIC_FRICTION: "the model has no static friction (dissipation 'joint+stiction')"}
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

    def _si_inputs(self, *tensors):
        """The tensors in the model's dtype (the networks run in it; the SI accessors return the
        dtype they were given)."""
        return tuple(x.to(self.dtype) for x in tensors)

    def _joules(self, value: torch.Tensor) -> torch.Tensor:
        """An energy-like quantity of the normalised Lagrangian in J where the scene's inputs fix the
        Lagrangian's scale (``L_SI = L_norm / force_scale``); without inputs the scale is free (``cL``
        has the same motion) and it stays in the model's own units."""
        return value / float(self.normalizer.force_scale) if self.scene.num_inputs else value

    def energy_si(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """The model's own energy ``H = T + V`` at SI states ``(B, dof), (B, dof), (B, P) -> (B,)`` (``q``'s
        dtype): in J for a scene with inputs, else in the model's units (see ``_joules``). ``ENERGY``."""
        self._require(ENERGY)
        q_n, qd_n, p_n = self.normalize(*self._si_inputs(q, qd, params))
        return self._joules(self.energy_norm(q_n, qd_n, p_n)[0].to(q.dtype))

    def mass_matrix_si(self, q: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """The learned mass matrix ``(B, dof, dof)`` of ``energy_si``'s kinetic energy, SI velocities
        (``D M_norm D``, ``D = diag(time_scale / coord_scale)``; in J s^2 per unit^2 for a scene with
        inputs, else up to the Lagrangian's free scale). ``MASS_MATRIX``."""
        self._require(MASS_MATRIX)
        q_n, _, p_n = self.normalize(*self._si_inputs(q, q, params))
        M_n = self.mass_matrix_norm(q_n, p_n).to(q.dtype)
        norm = self.normalizer
        D = norm.time_scale.to(q.dtype) / norm.coord_scale.to(q.dtype)
        return self._joules(D[:, None] * M_n * D[None, :])

    def friction_torque_si(self, rates: torch.Tensor, params: torch.Tensor) -> torch.Tensor:
        """The learned joint friction torque (N m) at joint rates ``rates (..., n_j)`` (the scene's
        ``joint_map @ qd``) for parameters ``params (..., P)``; ``rates``' dtype. ``FRICTION``."""
        self._require(FRICTION)
        r, p = self._si_inputs(rates, params)
        return self.forces.friction_torque(r, self.normalizer.params(p)).to(rates.dtype)

    def friction_coefficients_si(self, params: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The learned viscous (N m s/rad) and Coulomb (N m) coefficients per joint ``(B, n_j)`` each,
        in ``params``' dtype. ``FRICTION``."""
        self._require(FRICTION)
        b, c = self.forces.coefficients(self.normalizer.params(params.to(self.dtype)))
        return b.to(params.dtype), c.to(params.dtype)

    forward = acceleration
