"""The base of every dynamics model: normalisation glue, input features, input checks, rollouts and
(opt-in) compilation. Subclasses give ``acceleration_norm`` (and, with an energy, ``energy_norm``).

Every model works in normalised units internally (``Normalizer``); ``acceleration`` takes and
returns SI units. Shapes: ``q, qd (B, dof)``, ``params (B, P)`` -> ``(B, dof)``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import torch
from torch import nn

from .. import integrators
from ..dynamics import SingularHessianError
from ..perf import compile_fn
from ..systems.base import InputError
from .normalization import Normalizer


def wrap_angle(q: torch.Tensor) -> torch.Tensor:
    """``q`` reduced to [-pi, pi), same dtype. The reduction runs in float64 where the device has it:
    in float32, ``remainder(q + pi, 2 pi)`` loses up to 3e-4 rad at |q| = 1e4 (q + pi is rounded to
    the float32 grid there), while float64 keeps the reduced angle exact to ~1e-12."""
    wide = torch.float64 if q.device.type in ("cpu", "cuda") else q.dtype
    return (torch.remainder(q.to(wide) + math.pi, 2 * math.pi) - math.pi).to(q.dtype)


@dataclass(frozen=True)
class SceneInfo:
    """What a model needs to know about a scene."""

    name: str
    dof: int
    angle_mask: tuple[bool, ...]
    num_params: int
    quadratic_kinetic: bool = True

    @classmethod
    def of(cls, scene) -> "SceneInfo":
        """From a ``System``, a ``System.describe()`` dict or a ``SceneInfo``."""
        if isinstance(scene, SceneInfo):
            return scene
        if isinstance(scene, dict):
            return cls(scene["name"], int(scene["dof"]), tuple(bool(a) for a in scene["angle_mask"]),
                       len(scene["param_names"]), bool(scene.get("quadratic_kinetic", True)))
        return cls(scene.name, scene.dof, tuple(scene.angle_mask), scene.num_params, scene.quadratic_kinetic)


class DynamicsModel(nn.Module):
    """Base: normalisation, input features and checks; subclasses give ``acceleration_norm``."""

    variant = ""  # the registry name (``lnn_torch.networks.registry``)
    has_energy = True  # the model has its own Hamiltonian H = T + V for the energy regulariser
    # the model computes its parameter conditioning once per chunk when given ``chunks``
    chunk_conditioning = False

    def __init__(self, scene) -> None:
        super().__init__()
        self.scene = SceneInfo.of(scene)
        dof = self.scene.dof
        self.normalizer = Normalizer(dof, self.scene.num_params, self.scene.angle_mask)
        angles = [i for i, a in enumerate(self.scene.angle_mask) if a]
        linear = [i for i, a in enumerate(self.scene.angle_mask) if not a]
        self.register_buffer("angle_idx", torch.tensor(angles, dtype=torch.long), persistent=False)
        self.register_buffer("linear_idx", torch.tensor(linear, dtype=torch.long), persistent=False)
        # d(feature)/dq_k selectors: (dof, n_angles) and (dof, n_linear)
        self.register_buffer("sel_angle", torch.eye(dof)[:, angles], persistent=False)
        self.register_buffer("sel_linear", torch.eye(dof)[:, linear], persistent=False)
        self.num_features = 2 * len(angles) + len(linear)
        self.all_angles = not linear

    # ------------------------------------------------------------------ features
    def features(self, q_norm: torch.Tensor, tangents: bool = False):
        """Features ``[sin q_a, cos q_a, q_lin]`` ``(B, F)`` and, if asked, ``d phi / d q_k`` ``(dof, B, F)``.

        On the CPU, sin/cos read the raw angles: torch's CPU kernels reduce large arguments exactly
        (``tests/test_stability.py::test_angle_features_are_exact_at_1e4_rad``). On other devices the angles are first wrapped to [-pi, pi) in float64
        (``wrap_angle``), in case a device kernel reduces large arguments inexactly. The dynamics
        and rollouts never see wrapped angles.
        """
        phi, dphi, _ = self._features(q_norm, tangents)
        return phi, dphi

    def _features(self, q_norm: torch.Tensor, tangents: bool):
        """``features`` plus ``(sin, cos)`` of the angles (reused by ``features_vjp``)."""
        qa = q_norm if self.all_angles else q_norm[..., self.angle_idx]
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
        na = int(self.angle_idx.numel())
        if sin_cos is None:
            qa = q_norm if self.all_angles else q_norm[..., self.angle_idx]
            sin_cos = torch.sin(qa), torch.cos(qa)
        s, c = sin_cos
        g_angle = g_phi[..., :na] * c - g_phi[..., na : 2 * na] * s
        if self.all_angles:
            return g_angle
        g_lin = g_phi[..., 2 * na :]
        return g_angle @ self.sel_angle.to(g_phi.dtype).T + g_lin @ self.sel_linear.to(g_phi.dtype).T

    # ------------------------------------------------------------------ interface
    def acceleration_norm(self, q_norm, qd_norm, params_norm) -> torch.Tensor:
        raise NotImplementedError

    def energy_norm(self, q_norm, qd_norm, params_norm):
        """The model's own Hamiltonian ``H``, kinetic-like ``T`` and potential-like ``V`` (normalised)."""
        raise NotImplementedError(f"variant '{self.variant}' has no energy")

    def acceleration_and_energy_norm(self, q_norm, qd_norm, params_norm, chunks: int | None = None):
        """``(qdd, H, T, V)`` in normalised units; subclasses share work between the two.

        ``chunks``: the batch is ``chunks`` runs of consecutive rows, each with ONE parameter vector
        (training chunks of one trajectory each); a model may compute its parameter conditioning
        once per run. The parameters must then be constant within each run (not checked here)."""
        return (self.acceleration_norm(q_norm, qd_norm, params_norm), *self.energy_norm(q_norm, qd_norm, params_norm))

    def check_inputs(self, q, qd, params) -> None:
        dof, P = self.scene.dof, self.scene.num_params
        if q.ndim != 2 or q.shape[-1] != dof:
            raise InputError(f"q must have shape (batch, {dof}), got {tuple(q.shape)}")
        if qd.shape != q.shape:
            raise InputError(f"qd must have the shape of q {tuple(q.shape)}, got {tuple(qd.shape)}")
        if params.ndim != 2 or params.shape != (q.shape[0], P):
            raise InputError(f"params must have shape ({q.shape[0]}, {P}) for scene '{self.scene.name}', "
                             f"got {tuple(params.shape)}")
        for name, x in (("q", q), ("qd", qd), ("params", params)):
            if not torch.isfinite(x).all():
                raise InputError(f"{name} contains NaN or Inf")
        if (params <= 0).any():
            raise InputError("params must be positive (masses, lengths, stiffnesses)")

    def normalize(self, q, qd, params):
        q_norm, qd_norm = self.normalizer.state(q, qd)
        return q_norm, qd_norm, self.normalizer.params(params)

    def fit_normalizer(self, stats: dict) -> None:
        """Set the normalisation from training data (SI): ``q, qd, qdd (n, dof)``, ``params (m, P)``
        per trajectory and ``params_points (n, P)`` aligned with the points."""
        self.normalizer.fit(stats["q"], stats["qd"], stats["qdd"], stats["params"])

    def training_terms(self, q, qd, qdd, params, energy: bool = False, chunks: int | None = None):
        """What the training loss compares, from a batch in SI units (``(B, dof)``, ``(B, P)``).

        Returns ``(pred, target, rms)`` in normalised units (``rms`` weights each component), plus
        the model's own ``(H, T, V)`` when ``energy``. Lagrangian models and the direct MLP predict
        accelerations. ``chunks``: see ``acceleration_and_energy_norm``.
        """
        q_n, qd_n, p_n = self.normalize(q, qd, params)
        target = self.normalizer.accel_to_norm(qdd)
        rms = self.normalizer.accel_rms.to(q.dtype)
        if energy or (chunks is not None and self.chunk_conditioning):
            pred, H, T, V = self.acceleration_and_energy_norm(q_n, qd_n, p_n, chunks)
            return (pred, target, rms, H, T, V) if energy else (pred, target, rms)
        return self.acceleration_norm(q_n, qd_n, p_n), target, rms

    def rollout(self, q0, qd0, params, dt: float, num_steps: int, method: str = "rk4"):
        """Integrate the learned dynamics from ``(q0, qd0)`` (SI units, ``(B, dof)``, params ``(B, P)``).

        Returns ``(q, qd)``, each ``(B, num_steps + 1, dof)``. Second-order models integrate their
        accelerations with ``lnn_torch.integrators.rollout``; Hamiltonian models their own flow.
        What the model derives from the parameters alone (FiLM) is computed once per rollout.
        """
        self.check_inputs(q0, qd0, params)
        return integrators.rollout(self.acceleration_fn(params), q0, qd0, params, dt, num_steps, method)

    def acceleration_fn(self, params: torch.Tensor):
        """``(q, qd, params) -> qdd`` (SI, unchecked) for states of systems with these ``params``
        ``(B, P)``: the model's parameter conditioning is computed once, here, and reused by every
        call, which must pass these same ``params``. Integrators call it at every stage."""

        def accel(q, qd, params):
            return self.acceleration(q, qd, params, check=False)

        return accel

    def acceleration(self, q: torch.Tensor, qd: torch.Tensor, params: torch.Tensor, check: bool = True) -> torch.Tensor:
        """Accelerations in SI units: ``(B, dof), (B, dof), (B, P) -> (B, dof)``.

        The networks run in their own dtype; the result has the dtype and device of ``q``.
        Compiled after ``compile_dynamics()``.
        """
        if check:
            self.check_inputs(q, qd, params)
        return self._acceleration_si(self.acceleration_norm, q, qd, self.normalizer.params(params.to(self.dtype)))

    def _acceleration_si(self, fn, q, qd, params_norm, *extra):
        """SI accelerations from ``fn(q_norm, qd_norm, params_norm, *extra)`` (normalised units), run
        through ``_run`` (compiled after ``compile_dynamics()``); the result has ``q``'s dtype."""
        dtype = self.dtype
        q_norm, qd_norm = self.normalizer.state(q.to(dtype), qd.to(dtype))
        return self.normalizer.accel_to_phys(self._run(fn, q_norm, qd_norm, params_norm, *extra)).to(q.dtype)

    # ------------------------------------------------------------------ opt-in compilation
    _compile = False  # False, True (compile on first use) or "failed"
    _compiled: dict | None = None  # compiled functions by name

    def compile_dynamics(self, enabled: bool = True) -> "DynamicsModel":
        """Opt in (or out) of running ``acceleration``, and so ``rollout``, through ``torch.compile``.

        Compiled on first use for each batch shape, dtype and grad mode (10-30 s each; inductor
        caches compiled code on disk across processes); the C++ wrapper on the CPU
        (``lnn_torch.perf.compile_fn``). If compilation or a compiled call fails, a warning is
        issued once and the model continues eagerly. Returns the model.
        """
        self._compile, self._compiled = bool(enabled), {}
        return self

    def _run(self, fn, *args):
        """``fn(*args)``, compiled after ``compile_dynamics()`` (with the eager fallback)."""
        if self._compile is not True:
            return fn(*args)
        compiled = self._compiled.get(fn.__name__)
        if compiled is None:
            compiled = self._compiled[fn.__name__] = compile_fn(fn, args[0].device)
        try:
            return compiled(*args)
        except (InputError, SingularHessianError):  # the model's own answers, not compilation failures
            raise
        except Exception as err:  # noqa: BLE001 - any failure of the compiler or compiled code
            warnings.warn(f"compiled accelerations failed ({type(err).__name__}: "
                          f"{str(err).splitlines()[0][:200] if str(err) else ''}); continuing eagerly",
                          RuntimeWarning, stacklevel=3)
            self._compile, self._compiled = "failed", {}
            return fn(*args)

    def __getstate__(self):
        state = super().__getstate__()  # a copy of __dict__
        if "_compiled" in state:
            state["_compiled"] = {}  # compiled code is rebuilt on first use (copies, pickles)
        return state

    @property
    def dtype(self) -> torch.dtype:
        return next(self.parameters()).dtype

    forward = acceleration
