"""Lagrangian models and baselines behind one interface: ``acceleration(q, qd, params)``.

Variants (``build_model(variant, scene, ...)``):

* ``film_lnn`` (default): structured ``L = 1/2 qd^T M(q, theta) qd - V(q, theta)``; ``M`` from a
  Cholesky factor predicted by a kinetic MLP that FiLM modulates from the parameters; fast
  structured solve with hand-carried tangents.
* ``delan``: the same structure with the parameters concatenated to the inputs (Deep Lagrangian
  Networks, Lutter et al.), no FiLM.
* ``lnn``: a black-box MLP Lagrangian on the generic torch.func solve (Cranmer et al.).
* ``mlp``: predicts ``qdd`` directly (a second-order neural ODE baseline).
* ``hnn``: a Hamiltonian neural network (Greydanus et al.): an MLP ``H(q, p, theta)`` whose flow
  ``qdot = dH/dp, pdot = -dH/dq`` is fitted to the data, in canonical coordinates (``p = dL/dqd``
  from the scene's momentum map) or, as the LNN paper's counter-example, in ``(q, qd)``.

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
from ..dynamics import SingularHessianError, generic_acceleration, structured_acceleration_from_factor
from ..perf import compile_fn
from ..systems.base import InputError
from .layers import FiLM, TangentMLP, _one
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

    variant = ""
    has_energy = True  # the model has its own Hamiltonian H = T + V for the energy regulariser
    # True for a model whose accelerations call torch.autograd (which needs grad mode on, even in
    # evaluation); torch.func transforms do not, so every built-in model runs evaluation under no_grad
    needs_autograd = False
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
        (measured: float32 features at |q| = 1e5 rad within 3.6e-8 of float64 sin/cos of the same
        stored angle). On other devices the angles are first wrapped to [-pi, pi) in float64
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

        def accel(q, qd, p):
            return self.acceleration(q, qd, p, check=False)

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


class StructuredLagrangian(DynamicsModel):
    """``L = 1/2 qd^T M qd - V`` with ``M = chol chol^T + eps I`` (variants ``film_lnn`` and ``delan``)."""

    def __init__(self, scene, hidden_dims=(128, 128), activation: str = "tanh", conditioning: str = "film",
                 film_mode: str = "neuron", potential_film: bool = True, film_hidden: int = 16,
                 eps: float = 1e-4, diag_shift: float = 1e-3) -> None:
        super().__init__(scene)
        if not self.scene.quadratic_kinetic:
            raise InputError(
                f"scene '{self.scene.name}' has a kinetic energy that is not quadratic in the velocities; "
                "the structured model (T = 1/2 qd^T M qd) cannot represent it: use variant 'lnn'"
            )
        if conditioning not in ("film", "concat"):
            raise ValueError(f"conditioning must be 'film' or 'concat', got '{conditioning}'")
        dof, P, F = self.scene.dof, self.scene.num_params, self.num_features
        hidden_dims = list(hidden_dims)
        self.conditioning, self.eps, self.diag_shift = conditioning, float(eps), float(diag_shift)
        self.variant = "film_lnn" if conditioning == "film" else "delan"
        self.num_chol = dof * (dof + 1) // 2
        kin_in = F if conditioning == "film" else F + P
        self.kinetic_net = TangentMLP(kin_in, hidden_dims, self.num_chol, activation)
        self.potential_net = TangentMLP(F + P, hidden_dims, 1, activation, out_bias=False)
        self.kinetic_film = FiLM(P, hidden_dims, film_mode, film_hidden) if conditioning == "film" else None
        self.potential_film = FiLM(P, hidden_dims, film_mode, film_hidden) if (conditioning == "film" and potential_film) else None
        # scatter of the Cholesky entries (diagonal first) into a row-major lower-triangular matrix;
        # folded into the kinetic network's output layer, which so outputs the dof^2 matrix directly
        rows, cols = torch.tril_indices(dof, dof)
        order = torch.cat([torch.nonzero(rows == cols)[:, 0], torch.nonzero(rows != cols)[:, 0]])
        scatter = torch.zeros(self.num_chol, dof * dof)
        scatter[torch.arange(self.num_chol), rows[order] * dof + cols[order]] = 1.0
        self.register_buffer("chol_scatter", scatter, persistent=False)
        self.register_buffer("chol_diag", torch.eye(dof, dtype=torch.bool).flatten(), persistent=False)
        self.chunk_conditioning = conditioning == "film"

    def cholesky(self, q_norm, params_norm, tangents: bool = False):
        """Cholesky factor ``(B, dof, dof)`` and, if asked, ``d chol / d q_k`` ``(dof, B, dof, dof)``."""
        phi, dphi = self.features(q_norm, tangents)
        return self._cholesky(phi, dphi, params_norm)

    @staticmethod
    def _film(film_net, net, params_norm, chunks):
        """FiLM pairs for ``net``: per row ``(B, H)``, or per chunk ``(C, 1, H)`` when the batch is
        ``chunks`` runs of rows that share their parameters (one FiLM evaluation per chunk)."""
        if film_net is None:
            return None
        if chunks is None:
            return film_net(params_norm, net.sigmoid_form)
        cond = params_norm.view(chunks, -1, params_norm.shape[-1])[:, 0]
        return [(g[:, None], b[:, None]) for g, b in film_net(cond, net.sigmoid_form)]

    def _cholesky(self, phi, dphi, params_norm, chunks=None, film=False):
        dof, B = self.scene.dof, phi.shape[0]
        x = phi if self.conditioning == "film" else torch.cat([phi, params_norm], -1)
        if film is False:  # not given (None is a valid value: no FiLM)
            film = self._film(self.kinetic_film, self.kinetic_net, params_norm, chunks)
        S = self.chol_scatter.to(phi.dtype)  # (n_chol, dof^2)
        raw, draw = self.kinetic_net(x, dphi, film, out_map=S)  # (B, dof^2), (K, B, dof^2); 0 above the diagonal
        # positive diagonal: softplus + shift (computed on every entry, kept on the diagonal)
        chol = torch.where(self.chol_diag, nn.functional.softplus(raw) + self.diag_shift, raw).view(B, dof, dof)
        if dphi is None:
            return chol, None
        dchol = draw * torch.where(self.chol_diag, torch.sigmoid(raw), _one(raw))  # d softplus = sigmoid
        return chol, dchol.reshape(-1, B, dof, dof)

    def mass_matrix_norm(self, q_norm, params_norm):
        chol, _ = self.cholesky(q_norm, params_norm)
        eye = torch.eye(self.scene.dof, dtype=chol.dtype, device=chol.device)
        return torch.baddbmm(eye * self.eps, chol, chol.mT)

    def mass_matrix(self, q, params):
        """The learned mass matrix in normalised units, ``(B, dof, dof)`` (physical M up to a scale per system)."""
        q_norm, _, params_norm = self.normalize(q, q, params)
        return self.mass_matrix_norm(q_norm, params_norm)

    def potential_norm(self, q_norm, params_norm, grad: bool = False):
        """Potential ``(B,)`` and, if asked, ``dV/dq`` ``(B, dof)`` (hand-written reverse pass)."""
        phi, _, sin_cos = self._features(q_norm, False)
        return self._potential(q_norm, phi, sin_cos, params_norm, grad)

    def _potential(self, q_norm, phi, sin_cos, params_norm, grad: bool, chunks=None, film=False):
        x = torch.cat([phi, params_norm], -1)
        if film is False:
            film = self._film(self.potential_film, self.potential_net, params_norm, chunks)
        if not grad:
            return self.potential_net(x, None, film)[0][..., 0], None
        V, dV_dphi = self.potential_net.value_and_input_grad(x, film, num_grad_inputs=self.num_features)
        return V, self.features_vjp(q_norm, dV_dphi, sin_cos)

    def acceleration_norm(self, q_norm, qd_norm, params_norm):
        return self._solve(q_norm, qd_norm, params_norm, energy=False)

    def acceleration_and_energy_norm(self, q_norm, qd_norm, params_norm, chunks: int | None = None):
        """Accelerations and the model's own ``H = T + V``, ``T``, ``V`` from ONE pass of each network
        (``chunks``: FiLM once per chunk, see ``DynamicsModel.acceleration_and_energy_norm``)."""
        B = q_norm.shape[0]
        if chunks is not None and (chunks < 1 or B % chunks):
            raise InputError(f"a batch of {B} rows cannot be split into {chunks} chunks of equal length")
        return self._solve(q_norm, qd_norm, params_norm, energy=True, chunks=chunks)

    def _solve(self, q_norm, qd_norm, params_norm, energy: bool, chunks=None, films=None):
        """``films``: precomputed ``(kinetic, potential)`` FiLM pairs (``_films``), else computed here."""
        kinetic_film, potential_film = (False, False) if films is None else films
        phi, dphi, sin_cos = self._features(q_norm, True)
        chol, dchol = self._cholesky(phi, dphi, params_norm, chunks, kinetic_film)
        V, dV = self._potential(q_norm, phi, sin_cos, params_norm, grad=True, chunks=chunks, film=potential_film)
        if not energy:
            return structured_acceleration_from_factor(chol, dchol, qd_norm, dV, self.eps)
        qdd, T = structured_acceleration_from_factor(chol, dchol, qd_norm, dV, self.eps, return_kinetic=True)
        return qdd, T + V, T, V

    def _films(self, params_norm):
        """The FiLM pairs of both networks for these parameters (None where a network has no FiLM)."""
        return (self._film(self.kinetic_film, self.kinetic_net, params_norm, None),
                self._film(self.potential_film, self.potential_net, params_norm, None))

    def _acceleration_norm_films(self, q_norm, qd_norm, params_norm, films):
        return self._solve(q_norm, qd_norm, params_norm, energy=False, films=films)

    def acceleration_fn(self, params: torch.Tensor):
        """As ``DynamicsModel.acceleration_fn``, with both networks' FiLM computed once, not at
        every call (an RK4 step makes four)."""
        if self.kinetic_film is None and self.potential_film is None:
            return super().acceleration_fn(params)
        params_norm = self.normalizer.params(params.to(self.dtype))
        films = self._films(params_norm)

        def accel(q, qd, p):
            if p is not params:
                raise InputError("acceleration_fn(params) was called with other parameters than its own")
            return self._acceleration_si(self._acceleration_norm_films, q, qd, params_norm, films)

        return accel

    def energy_norm(self, q_norm, qd_norm, params_norm):
        M = self.mass_matrix_norm(q_norm, params_norm)
        T = 0.5 * torch.einsum("bi,bij,bj->b", qd_norm, M, qd_norm)
        V, _ = self.potential_norm(q_norm, params_norm)
        return T + V, T, V

    def lagrangian_norm(self, q_norm, qd_norm, params_norm):
        """Scalar Lagrangian of ONE sample ``(dof,), (dof,), (P,) -> ()`` (for torch.func references)."""
        M = self.mass_matrix_norm(q_norm[None], params_norm[None])[0]
        V, _ = self.potential_norm(q_norm[None], params_norm[None])
        return 0.5 * qd_norm @ M @ qd_norm - V[0]


class BlackBoxLagrangian(DynamicsModel):
    """The LNN paper's model: an MLP ``L(q, qd, theta)`` and the generic Euler-Lagrange solve."""

    variant = "lnn"
    # The generic solve differentiates the network with torch.func transforms, which work whatever
    # the outer grad mode: evaluation and rollouts run under no_grad and build no autograd graph
    # (with grad forced on, a rollout kept every step's graph alive: ~5 MB per step at batch 64).
    needs_autograd = False

    def __init__(self, scene, hidden_dims=(128, 128), activation: str = "softplus", lnn_init: bool = False,
                 damping: float = 0.0) -> None:
        super().__init__(scene)
        self.net = TangentMLP(self.num_features + self.scene.dof + self.scene.num_params, list(hidden_dims), 1,
                              activation, out_bias=False)
        if lnn_init:
            self.net.lnn_init()
        self.damping = float(damping)
        self.raise_on_singular = True

    def lagrangian_norm(self, q_norm, qd_norm, params_norm):
        phi, _ = self.features(q_norm[None])
        return self.net(torch.cat([phi[0], qd_norm, params_norm], -1)[None])[0][0, 0]

    def acceleration_norm(self, q_norm, qd_norm, params_norm, check_singular: bool | None = None):
        """The generic solve.

        Singular-Hessian policy: the velocity Hessian of an arbitrary network can be indefinite, and
        singular somewhere (an untrained one always is, somewhere along a rollout). With
        ``damping == 0`` (default) such states raise ``SingularHessianError`` (in ``acceleration``
        and rollouts alike) while ``raise_on_singular`` is True, and give NaN otherwise (training
        skips those steps; evaluations count those trajectories as non-finite). ``damping > 0``
        solves the Levenberg-damped system ``H + damping (mean|diag H| + 1) I`` instead.
        """
        check = self.raise_on_singular if check_singular is None else check_singular
        return generic_acceleration(self.lagrangian_norm, q_norm, qd_norm, params_norm, damping=self.damping,
                                    check=check)

    def training_terms(self, q, qd, qdd, params, energy: bool = False, chunks: int | None = None):
        q_n, qd_n, p_n = self.normalize(q, qd, params)
        pred = self.acceleration_norm(q_n, qd_n, p_n, check_singular=False)
        out = (pred, self.normalizer.accel_to_norm(qdd), self.normalizer.accel_rms.to(q.dtype))
        return (*out, *self.energy_norm(q_n, qd_n, p_n)) if energy else out

    def energy_norm(self, q_norm, qd_norm, params_norm):
        L_fn = torch.func.vmap(self.lagrangian_norm)
        L = L_fn(q_norm, qd_norm, params_norm)
        p = torch.func.vmap(torch.func.grad(self.lagrangian_norm, argnums=1))(q_norm, qd_norm, params_norm)
        T = 0.5 * (p * qd_norm).sum(-1)
        H = 2 * T - L
        return H, T, T - L


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


class HamiltonianNN(DynamicsModel):
    """Hamiltonian neural network (Greydanus et al.): an MLP ``H(q, m, theta)`` with the flow
    ``qdot = dH/dm``, ``mdot = -dH/dq`` fitted to the data.

    ``coordinates="canonical"``: ``m`` is the canonical momentum ``p = dL/dqd``, computed from the
    scene's momentum map (so the model needs the scene, not only its description).
    ``coordinates="velocity"``: ``m = qd``, i.e. the HNN is fed non-canonical ``(q, qd)``; it can then
    only represent dynamics whose accelerations do not depend on ``qd`` in a way a Hamiltonian flow
    in ``(q, qd)`` can express (it fails on the relativistic particle, the LNN paper's point).

    Normalisation keeps ``(q_norm, m_norm)`` canonical: ``m_norm = p * coord_scale / c`` with one
    momentum scale ``c`` and one time scale, so ``H_norm = (tau / c) H``.
    """

    variant = "hnn"
    has_energy = False  # its Hamiltonian is conserved by construction; no T/V split
    needs_autograd = False

    def __init__(self, scene, hidden_dims=(128, 128), activation: str = "tanh", coordinates: str = "canonical") -> None:
        super().__init__(scene)
        if coordinates not in ("canonical", "velocity"):
            raise ValueError(f"hnn coordinates must be 'canonical' or 'velocity', got '{coordinates}'")
        self.coordinates = coordinates
        self._momentum_fn = None
        if coordinates == "canonical":
            self._momentum_fn = getattr(scene, "momentum", None)
            if self._momentum_fn is None:
                raise InputError("the canonical HNN needs the scene's momentum map p = dL/dqd: build it from a "
                                 "System (lnn_torch.systems), or use coordinates='velocity'")
        dof, P, F = self.scene.dof, self.scene.num_params, self.num_features
        self.net = TangentMLP(F + dof + P, list(hidden_dims), 1, activation, out_bias=False)

    # ------------------------------------------------------------------ coordinates
    def momentum_norm(self, q, qd, params):
        """The model's second coordinate ``m_norm`` of SI states ``(B, dof)``."""
        if self.coordinates == "velocity":
            return self.normalizer.state(q, qd)[1]
        return self.normalizer.momentum_to_norm(self._momentum_fn(q, qd, params))

    def _momentum_and_rate_norm(self, q, qd, qdd, params):
        """``m_norm`` and its time derivative ``d m_norm / d t_norm`` along the data (SI inputs)."""
        if self.coordinates == "velocity":
            return self.normalizer.state(q, qd)[1], self.normalizer.accel_to_norm(qdd)
        p, pdot = torch.func.jvp(lambda a, b: self._momentum_fn(a, b, params), (q, qd), (qd, qdd))
        tau = self.normalizer.time_scale.to(q.dtype)
        return self.normalizer.momentum_to_norm(p), self.normalizer.momentum_to_norm(pdot) * tau

    def fit_normalizer(self, stats: dict) -> None:
        super().fit_normalizer(stats)
        q, qd, qdd = (stats[k].double() for k in ("q", "qd", "qdd"))
        if self.coordinates == "canonical":
            if "params_points" not in stats:
                raise ValueError("the canonical HNN needs per-point parameters ('params_points') to fit its momentum scale")
            pp = stats["params_points"].double()
            p = self._momentum_fn(q, qd, pp) * self.normalizer.coord_scale.double()
            self.normalizer.momentum_scale.copy_(p.pow(2).mean().sqrt().clamp_min(1e-12))
        else:
            pp = None
        with torch.no_grad():
            m, mdot = self._momentum_and_rate_norm(q, qd, qdd, pp)
            qd_n = self.normalizer.state(q, qd)[1]
        rms = torch.cat([qd_n, mdot], -1).pow(2).mean(0).sqrt().clamp_min(1e-6)
        self.normalizer.vector_field_rms.copy_(rms)

    # ------------------------------------------------------------------ the flow
    def hamiltonian_and_grads(self, q_n, m_n, params_n):
        """``H (B,)``, ``dH/dq_norm (B, dof)``, ``dH/dm_norm (B, dof)`` (hand-written reverse pass)."""
        F = self.num_features
        phi, _, sin_cos = self._features(q_n, False)
        x = torch.cat([phi, m_n, params_n], -1)
        H, g = self.net.value_and_input_grad(x, None, num_grad_inputs=F + self.scene.dof)
        return H, self.features_vjp(q_n, g[:, :F], sin_cos), g[:, F:]

    def vector_field_norm(self, q_n, m_n, params_n):
        """``(dq_norm/dt_norm, dm_norm/dt_norm) = (dH/dm, -dH/dq)``."""
        _, dH_dq, dH_dm = self.hamiltonian_and_grads(q_n, m_n, params_n)
        return dH_dm, -dH_dq

    def energy_norm(self, q_n, qd_n, params_n):
        raise NotImplementedError("the HNN's Hamiltonian is a function of (q, m): use hamiltonian_and_grads")

    def training_terms(self, q, qd, qdd, params, energy: bool = False, chunks: int | None = None):
        q_n, qd_n, p_n = self.normalize(q, qd, params)
        m_n, mdot_n = self._momentum_and_rate_norm(q, qd, qdd, params)
        dq, dm = self.vector_field_norm(q_n, m_n, p_n)
        return (torch.cat([dq, dm], -1), torch.cat([qd_n, mdot_n], -1),
                self.normalizer.vector_field_rms.to(q.dtype))

    def acceleration_norm(self, q_n, qd_n, params_n):
        """Accelerations of the model's flow at ``(q, qd)``.

        ``velocity``: ``qdd = -dH/dq`` at ``m = qd``. ``canonical``: ``m`` from the momentum map,
        then ``qdd = d/dt (dH/dm) = H_mq qdot + H_mm mdot`` along the flow (a jvp).
        """
        if self.coordinates == "velocity":
            return self.vector_field_norm(q_n, qd_n, params_n)[1]
        q, qd = self.normalizer.state_to_phys(q_n, qd_n)
        params = self.normalizer.params_to_phys(params_n)
        m_n = self.normalizer.momentum_to_norm(self._momentum_fn(q, qd, params))
        flow = self.vector_field_norm(q_n, m_n, params_n)
        _, qdd_n = torch.func.jvp(lambda a, b: self.hamiltonian_and_grads(a, b, params_n)[2], (q_n, m_n), flow)
        return qdd_n

    def rollout(self, q0, qd0, params, dt: float, num_steps: int, method: str = "rk4"):
        """Integrate the model's own flow in ``(q, m)`` (RK methods); ``qd`` of the result is the
        model's velocity ``dH/dp`` (canonical) or the state ``m = qd`` (velocity coordinates)."""
        self.check_inputs(q0, qd0, params)
        dof = self.scene.dof
        q_n, _, p_n = self.normalize(q0, qd0, params)
        m_n = self.momentum_norm(q0, qd0, params)

        dtype = self.dtype

        def field(y, pn):  # the state keeps the input dtype; the network runs in its own
            y, pn = y.to(dtype), pn.to(dtype)
            return torch.cat(self.vector_field_norm(y[:, :dof], y[:, dof:], pn), -1).to(q0.dtype)

        tau = float(self.normalizer.time_scale)
        y = integrators.rollout_first_order(field, torch.cat([q_n, m_n], -1), p_n, dt / tau, num_steps, method)
        qs_n, ms_n = y[..., :dof], y[..., dof:]  # (B, T, dof)
        if self.coordinates == "canonical":
            B, T = qs_n.shape[:2]
            flat = lambda x: x.reshape(B * T, -1)  # noqa: E731
            qds_n = self.vector_field_norm(flat(qs_n).to(dtype), flat(ms_n).to(dtype),
                                           flat(p_n[:, None].expand(-1, T, -1)).to(dtype))[0]
            qds_n = qds_n.reshape(B, T, dof).to(q0.dtype)
        else:
            qds_n = ms_n
        return self.normalizer.state_to_phys(qs_n, qds_n)


VARIANTS = ("film_lnn", "lnn", "delan", "mlp", "hnn")
# the black-box LNN's accelerations go through the velocity Hessian of a network: softplus (the LNN
# paper's choice) keeps it usable where tanh saturates (relativistic particle, 3000 steps: 4 % error
# with softplus, 476 % with tanh); the others learned best with tanh
DEFAULT_ACTIVATION = {"film_lnn": "tanh", "delan": "tanh", "lnn": "softplus", "mlp": "tanh", "hnn": "tanh"}


def build_model(variant: str, scene, hidden_dims=(128, 128), activation: str | None = None, film_mode: str = "neuron",
                potential_film: bool = True, eps: float = 1e-4, lnn_init: bool = False, damping: float = 0.0,
                hnn_coordinates: str = "canonical") -> DynamicsModel:
    """Build a model variant for a scene (a ``System``, its ``describe()`` dict or a ``SceneInfo``;
    the canonical ``hnn`` needs a ``System`` for its momentum map). ``activation=None`` takes the
    variant's default (``DEFAULT_ACTIVATION``)."""
    if variant in DEFAULT_ACTIVATION and activation is None:
        activation = DEFAULT_ACTIVATION[variant]
    if variant == "film_lnn":
        return StructuredLagrangian(scene, hidden_dims, activation, "film", film_mode, potential_film, eps=eps)
    if variant == "delan":
        return StructuredLagrangian(scene, hidden_dims, activation, "concat", eps=eps)
    if variant == "lnn":
        return BlackBoxLagrangian(scene, hidden_dims, activation, lnn_init=lnn_init, damping=damping)
    if variant == "mlp":
        return DirectMLP(scene, hidden_dims, activation)
    if variant == "hnn":
        return HamiltonianNN(scene, hidden_dims, activation, coordinates=hnn_coordinates)
    raise InputError(f"unknown model variant '{variant}'; known: {', '.join(VARIANTS)}")
