"""Parameter identification through a parameter-conditioned model: which member of the family is this?

``identify(model, system, t, q, ...)`` finds the physical parameters that make the model's dynamics
best explain an observed trajectory, by gradient-based optimisation through the model:

* ``acceleration``: the model's accelerations at the observed states against the observed (or
  estimated, ``lnn_torch.data.derivatives``) accelerations, each coordinate divided by its rms;
* ``trajectory``: short differentiable rollouts (multiple shooting, ``lnn_torch.training.losses.shooting_residuals``
  as in training: windows of ``window`` s, each from its own start state, which is fitted too,
  beginning at the observed position and estimated velocity; driven by the observed inputs) against
  the observed positions, divided by the window's ``(k dt)^2 / 2`` (acceleration units): no
  derivative estimates in the objective, so position noise enters once instead of amplified by
  ``1/dt^2``;
* ``both``: multi-start on the acceleration fit, then the trajectory fit from the best start.

The acceleration fit (default) is the fast one: about 200 observed points suffice for a handful of
parameters. The trajectory fit costs a sequential rollout per evaluation (tens of seconds on a CPU).

The search runs in a box: each parameter's logarithm (positive parameters) or value (nonnegative
ones) between bounds, by default the model's training distribution (mean +- 3 std of its normaliser
statistics), through ``x = centre + half_width tanh(u)``; ``starts`` random starts (seeded) and a
final L-BFGS.

Identifiability and uncertainty: at the optimum, the Gauss-Newton matrix ``A = J^T J`` of the
residuals ``r(x)`` (``J = dr/dx``, ``x`` the log-parameters) gives the curvature of the objective. A
direction of ``A`` whose standard deviation (``s^2 A^-1``, ``s^2`` the residual variance) exceeds half
the search box along it, or ``FLAT_RATIO`` times that of the best-determined direction, is reported
as not identifiable (e.g. a common scale of the double pendulum's masses, which leaves its
accelerations unchanged), and every parameter or named quantity (``System.identifiable_quantities``)
that moves along it gets no number but that status. The covariance of the identifiable part is the
cluster-robust sandwich ``A^+ (sum_b J_b^T r_b r_b^T J_b) A^+`` over time blocks of ``window`` s:
residuals are correlated along a trajectory (smooth model error, filtered noise), so treating them
as independent would understate the uncertainty.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import torch

from ..data.derivatives import estimate_derivatives
from ..errors import InputError, PoorFitWarning
from ..training.losses import shooting_residuals


@dataclass
class Identification:
    """What ``identify`` found (SI units; uncertainties are one standard deviation)."""

    params: dict  # name -> estimate
    quantities: dict  # name -> {"value", "rel_std" (or None), "identifiable", "coefficients"}
    unidentifiable: list  # [{"direction": {name: coefficient}, "std": float}] in log-parameter space
    loss: float
    residual_rms: dict  # objective name -> rms of its normalised residuals
    method: str
    starts: int
    seconds: float
    at_bound: list  # parameters estimated on the edge of the search box (the truth may lie outside it)
    x: torch.Tensor = field(repr=False)  # the optimum in the transformed parameter space (log / linear)
    covariance: torch.Tensor | None = field(repr=False, default=None)

    def to_json(self) -> dict:
        return {"params": self.params, "quantities": self.quantities, "unidentifiable": self.unidentifiable,
                "loss": self.loss, "residual_rms": self.residual_rms, "method": self.method, "starts": self.starts,
                "seconds": self.seconds, "at_bound": self.at_bound}


class _Space:
    """The search box: ``x = centre + half_width * tanh(u)``, with ``x`` the log of positive parameters
    and the value of nonnegative ones."""

    def __init__(self, kinds, low, high) -> None:
        self.log = torch.tensor([k == "positive" for k in kinds])
        # a nonnegative parameter (a friction coefficient) never below 0: the box of a model's training spread
        # reached -0.02, and a negative friction was returned (the report then refused it and wrote nothing)
        floor = torch.tensor([0.0 if k == "nonnegative" else -float("inf") for k in kinds], dtype=torch.float64)
        low, high = low.double().maximum(floor), high.double()
        self.low, self.high = low, torch.maximum(high, low + 1e-12)
        self.centre, self.half = 0.5 * (self.low + self.high), 0.5 * (self.high - self.low)

    def x(self, u):
        return self.centre + self.half * torch.tanh(u)

    def u(self, x):
        return torch.atanh(((x - self.centre) / self.half).clamp(-1 + 1e-9, 1 - 1e-9))

    def params(self, x):
        return torch.where(self.log, x.exp(), x)


def default_bounds(model, system, width: float = 3.0):
    """The box of the model's training distribution: its normaliser's mean +- ``width`` std (in the
    log of positive parameters); for a model without one (the closed form), the scene's sampler
    (20,000 draws, widened by 10 %)."""
    kinds = system.kinds
    norm = getattr(model, "normalizer", None)
    if norm is not None:
        mean, std = norm.param_log_mean.double(), norm.param_log_std.double()
        return mean - width * std, mean + width * std
    sample = torch.as_tensor(system.sample_params(np.random.default_rng(0), 20_000), dtype=torch.float64)
    x = torch.where(torch.tensor([k == "positive" for k in kinds]), sample.clamp_min(1e-300).log(), sample)
    lo, hi = x.min(0).values, x.max(0).values
    pad = 0.1 * (hi - lo).clamp_min(1e-3)
    return lo - pad, hi + pad


def identify(model, system, t, q, qd=None, tau=None, qdd=None, **options) -> Identification:
    """Identify the parameters of ``system`` (the scene of ``model``) from ONE observed trajectory.

    Args:
        model: a parameter-conditioned model (``DynamicsModel``, e.g. ``load_model(...).model``) or
            ``ClosedForm(system)`` (the scene itself: the ceiling of what the data allow).
        t: ``(T,)`` uniform sample times, s; q: ``(T, dof)`` observed coordinates; qd: ``(T, dof)``
            observed velocities (None: estimated); tau: ``(T, n_u)`` inputs of an actuated scene;
            qdd: ``(T, dof)`` accelerations, where known (None: estimated from q, qd).
        options: those of ``identify_batch``.
    """
    for name, x, width in (("q", q, system.dof), ("qd", qd, system.dof), ("qdd", qdd, system.dof)):
        if x is not None and (np.ndim(x) != 2 or np.shape(x)[1] != width):
            raise InputError(f"{name} must be (T, {width}) for scene '{system.name}' (one trajectory: its samples, "
                             f"its coordinates), got {tuple(np.shape(x))}")
    lift = lambda x: None if x is None else np.asarray(x)[None]  # noqa: E731
    return identify_batch(model, system, t, lift(q), lift(qd), lift(tau), lift(qdd), **options)[0]


def identify_batch(model, system, t, q, qd=None, tau=None, qdd=None, *, method: str = "acceleration", bounds=None,
                   starts: int = 4, steps: int = 150, window: float = 0.2, derivative: dict | None = None,
                   seed: int = 0, accel_stride: int | None = None, integrator: str = "rk4") -> list[Identification]:
    """Identify each of ``N`` observed trajectories of equal length (one optimisation for all: each
    trajectory has its own parameters).

    Args:
        t: ``(T,)`` uniform sample times, s; q, qd, qdd: ``(N, T, dof)``; tau ``(N, T, n_u)`` (see
            ``identify``).
        method: ``acceleration``, ``trajectory`` or ``both``.
        bounds: ``(low, high)`` in the log of positive / value of nonnegative parameters
            (default ``default_bounds``).
        starts: random starts per trajectory (seeded by ``seed``) of the first fit; steps: Adam
            steps per fit (then L-BFGS).
        window: the multiple-shooting windows of the trajectory fit, s.
        derivative: settings of ``lnn_torch.data.derivatives`` for estimating qd/qdd (default: a
            short Savitzky-Golay fit for noise-free positions, a smoothing spline (generalised
            cross-validation) for noisy ones; ``lnn_torch.data.derivatives.position_noise``).
        accel_stride: the acceleration fit uses every ``accel_stride``-th point (default: at most
            about 200 points per trajectory).
    """
    start_time = time.perf_counter()
    if method not in ("acceleration", "trajectory", "both"):
        raise InputError(f"method must be acceleration, trajectory or both, got '{method}'")
    dof, P = system.dof, system.num_params
    if P == 0:
        raise InputError(f"scene '{system.name}' has no parameters to identify (a measured system has those its "
                         "import declares per recording, e.g. a robot arm's payload; this one declares none)"
                         if system.name == "measured" else f"scene '{system.name}' has no parameters to identify")
    t, q, qd, tau, qdd = (_f64(x) for x in (t, q, qd, tau, qdd))
    if q.ndim != 3 or q.shape[2] != dof:
        raise InputError(f"q must be (N, T, {dof}) for scene '{system.name}' (dof {dof}), got {tuple(q.shape)}")
    if t.ndim != 1 or t.shape[0] != q.shape[1]:
        raise InputError(f"t must be ({q.shape[1]},) like q's time axis, got {tuple(t.shape)}")
    for name, x in (("t", t), ("q", q), ("qd", qd), ("tau", tau), ("qdd", qdd)):
        if x is not None and not torch.isfinite(x).all():
            raise InputError(f"the observation's {name} contains NaN or Inf")
    dt = mean_step(t) if len(t) > 1 else 0.0
    if len(t) < 21 or not dt > 0 or (torch.diff(t) - dt).abs().max() > UNIFORM * dt:
        raise InputError(f"the observation is too short or not uniformly sampled ({len(t)} points; "
                         "need >= 21 points at a constant step)")
    if system.num_inputs and tau is None:
        raise InputError(f"scene '{system.name}' is actuated: the observation's inputs tau are needed")
    qd, qdd = estimate_derivatives(q, dt, qd, qdd, derivative)
    accel_stride = accel_stride or max(1, q.shape[1] // 200)
    low, high = bounds if bounds is not None else default_bounds(model, system)
    space = _Space(system.kinds, torch.as_tensor(low), torch.as_tensor(high))
    objectives = _Objectives(model, t, q, qd, qdd, tau, dt, window, accel_stride, integrator)
    N = q.shape[0]

    gen = torch.Generator().manual_seed(seed)
    u0 = torch.atanh(torch.rand(N, starts, P, generator=gen, dtype=torch.float64) * 1.6 - 0.8)
    M = objectives.num_states
    split = lambda z: (space.params(space.x(z[..., :P])), z[..., P:])  # noqa: E731
    traj_loss = lambda z, reduce=True: objectives.loss("trajectory", *split(z), reduce=reduce)  # noqa: E731
    if method == "trajectory":  # multi-start on the trajectory fit itself, start states from the data
        z = _adam(traj_loss, torch.cat([u0, u0.new_zeros(N, starts, M)], -1), steps)
        losses = traj_loss(z, reduce=False)
    else:
        z = _adam(lambda uu: objectives.loss("acceleration", space.params(space.x(uu))), u0, steps)
        losses = objectives.loss("acceleration", space.params(space.x(z)), reduce=False)  # (N, S)
    best = z[torch.arange(N), torch.argmin(losses, 1)][:, None]  # (N, 1, P [+ M])
    final = "acceleration" if method == "acceleration" else "trajectory"
    if final == "trajectory":
        if method == "both":
            best = _adam(traj_loss, torch.cat([best, best.new_zeros(N, 1, M)], -1), steps // 2)
        best = _lbfgs(traj_loss, best)
    else:
        best = _lbfgs(lambda uu: objectives.loss("acceleration", space.params(space.x(uu))), best)
        if getattr(model, "dtype", None) == torch.float64:  # a float32 model's round-off is far above L-BFGS's
            best = _gauss_newton(lambda uu: objectives.residuals("acceleration", space.params(space.x(uu))), best,
                                 1e-6)
    best = best[:, 0].detach()
    x, states = space.x(best[:, :P]), (best[:, P:] if final == "trajectory" else None)  # (N, P), (N, M)
    with torch.no_grad():
        final_losses = objectives.loss(final, space.params(x[:, None]), None if states is None else states[:, None],
                                       reduce=False)[:, 0]
    seconds = (time.perf_counter() - start_time) / N
    found = _uncertainty(objectives, final, space, x, states, system)
    with torch.no_grad():  # the acceleration fit's residual whatever the method, per observation: one measure of fit
        error = objectives.residuals("acceleration", space.params(x[:, None]))[:, 0].reshape(N, -1, dof)
        own = (objectives.qdd / objectives.qdd_rms).pow(2).mean(1).sum(-1)  # (N,): each observation's own, normalised
        # (a ratio of sums over the coordinates: a coordinate that barely moves does not decide it)
        explained = (error.pow(2).mean(1).sum(-1) / own.clamp_min(1e-18)).sqrt()
    for i in range(N):
        _warn_if_poor(float(explained[i]), system, i if N > 1 else None)
    return [Identification(**found[i], loss=float(final_losses[i]), method=method, starts=starts, seconds=seconds)
            for i in range(N)]


# a fit whose normalised residual (the accelerations' error over their rms) exceeds this explains under 3/4 of the
# observed accelerations' variance: said with ``PoorFitWarning``. The shipped double pendulum on its own scene's
# trajectories: 1e-4 noise-free, 0.1-0.25 with 1e-3 to 1e-2 rad of noise; the same angles in degrees 3.9-4.6, a
# pendulum at rest with 1e-5 rad of noise 7-82
POOR_FIT = 0.5


def _warn_if_poor(residual: float, system, index: int | None) -> None:
    if residual > POOR_FIT or not math.isfinite(residual):
        which = "" if index is None else f" (observation {index})"
        warnings.warn(f"the identified model explains little of the observation{which}: the accelerations' "
                      f"residual is {residual:.3g} times their rms (under {POOR_FIT:g} in a fit of the model's own "
                      f"scene); the observation may not be scene '{system.name}', be in other units (angles in rad, "
                      "lengths in m, time in s) or barely move: its estimates and uncertainties describe nothing",
                      PoorFitWarning, stacklevel=3)


EDGE = 10  # samples left out at each end by the acceleration fit
# fewer blocks than this (a recording of one or two 0.2 s windows) cannot estimate the cluster-robust covariance
MIN_BLOCKS = 4

# the units of the trajectory fit's start-state offsets: rad (or m) and rad/s (or m/s)
STATE_SCALE = (1e-2, 1e-1)


class _Objectives:
    """The normalised residuals of the acceleration and trajectory fits of ``N`` observations, for
    parameters ``(N, S, P)``."""

    def __init__(self, model, t, q, qd, qdd, tau, dt, window, stride, integrator) -> None:
        self.model, self.dt, self.integrator = model, dt, integrator
        # the acceleration fit leaves out the ends, where derivative estimates are least accurate
        edge = min(EDGE, q.shape[1] // 10)
        sub = slice(edge, q.shape[1] - edge, stride)
        self.q, self.qd, self.qdd = q[:, sub], qd[:, sub], qdd[:, sub]  # (N, n, dof)
        self.tau = None if tau is None else tau[:, sub]
        self.qdd_rms = self.qdd.pow(2).mean((0, 1)).sqrt().clamp_min(1e-9)
        T = q.shape[1]
        k = min(max(1, int(round(window / dt))), T - 1)
        starts = torch.arange(0, T - k, k)
        self.k = k
        window_idx = starts[:, None] + torch.arange(k + 1)  # (W, k + 1)
        self.q_windows = q[:, window_idx]  # (N, W, k + 1, dof)
        self.q0, self.qd0 = q[:, starts], qd[:, starts]  # (N, W, dof)
        self.tau_windows = None if tau is None else tau[:, window_idx[:, :-1]]
        self.W, self.dof = len(starts), q.shape[2]
        self.num_states = self.W * 2 * self.dof  # the trajectory fit's free window start states
        n = self.q.shape[1]
        dof = q.shape[2]
        # the time block of each residual (for the cluster-robust covariance): windows of k samples
        self.blocks = {"acceleration": ((edge + torch.arange(n) * stride) // k).repeat_interleave(dof),
                       "trajectory": torch.arange(len(starts)).repeat_interleave(k * dof)}

    @staticmethod
    def _rep(x, S):
        """``(N, ...)`` -> ``(N * S * ..., last)`` repeated over ``S`` starts."""
        if x is None:
            return None
        return x[:, None].expand(x.shape[0], S, *x.shape[1:]).reshape(-1, *x.shape[-1:])

    def residuals(self, kind: str, params: torch.Tensor, states: torch.Tensor | None = None) -> torch.Tensor:
        """``(N, S, n)`` normalised residuals for parameters ``(N, S, P)`` and (trajectory fit) the
        offsets of the windows' start states ``(N, S, W * 2 dof)`` from the observed positions and
        estimated velocities, in units of ``STATE_SCALE`` (None: zero)."""
        N, S, _ = params.shape
        if kind == "acceleration":
            n = self.q.shape[1]
            pp = params[:, :, None].expand(-1, -1, n, -1).reshape(N * S * n, -1)
            pred = self.model.acceleration(self._rep(self.q, S), self._rep(self.qd, S), pp, self._rep(self.tau, S),
                                           check=False)
            return ((pred.reshape(N, S, n, -1) - self.qdd[:, None]) / self.qdd_rms).reshape(N, S, -1)
        W = self.q0.shape[1]
        pp = params[:, :, None].expand(-1, -1, W, -1).reshape(N * S * W, -1)
        tau = None if self.tau_windows is None else (
            self.tau_windows[:, None].expand(N, S, *self.tau_windows.shape[1:]).reshape(N * S * W, self.k, -1))
        q0, qd0 = self._rep(self.q0, S), self._rep(self.qd0, S)
        if states is not None:
            offset = states.reshape(N * S * W, 2, self.dof)
            q0, qd0 = q0 + STATE_SCALE[0] * offset[:, 0], qd0 + STATE_SCALE[1] * offset[:, 1]
        windows = self.q_windows[:, None].expand(N, S, *self.q_windows.shape[1:]).reshape(N * S * W, self.k + 1, -1)
        err, _ = shooting_residuals(self.model, q0, qd0, pp, self.dt, windows, self.integrator, tau=tau)
        return err.reshape(N, S, -1)

    def loss(self, kind: str, params: torch.Tensor, states: torch.Tensor | None = None, reduce: bool = True):
        per = 0.5 * self.residuals(kind, params, states).pow(2).mean(-1)  # (N, S)
        return per.sum() if reduce else per.detach()


def _adam(fn, u, steps: int, lr: float = 0.05):
    u = u.clone().requires_grad_(True)
    opt = torch.optim.Adam([u], lr=lr)
    for _ in range(steps):
        opt.zero_grad()
        loss = fn(u)
        if not torch.isfinite(loss):
            break
        loss.backward()
        opt.step()
    return u.detach()


def _lbfgs(fn, u, iterations: int = 60):
    u = u.clone().requires_grad_(True)
    opt = torch.optim.LBFGS([u], lr=1.0, max_iter=iterations, tolerance_grad=1e-14, tolerance_change=1e-16,
                            line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad()
        loss = fn(u)
        loss.backward()
        return loss

    start = u.detach().clone()
    try:
        opt.step(closure)
    except RuntimeError:  # a failed line search leaves the Adam result
        return start
    return u.detach() if torch.isfinite(u).all() else start


def _gauss_newton(residuals, u, h: float, iterations: int = 6):
    """Polish ``u (N, 1, P)`` by Gauss-Newton steps on ``residuals(u) -> (N, 1, n)`` of a float64 model
    (Jacobian by central differences of step ``h``), each observation's step kept only where it lowers its
    loss: where the residuals vanish at the optimum (noise-free data, the exact model) this reaches it to
    round-off, which L-BFGS on the squared loss (its changes below 1e-16) does not."""
    with torch.no_grad():
        r = residuals(u)
        loss = r.pow(2).sum(-1)
        P = u.shape[-1]
        for _ in range(iterations):
            cols = []
            for j in range(P):
                e = torch.zeros_like(u)
                e[..., j] = h
                cols.append((residuals(u + e) - residuals(u - e)) / (2 * h))
            J = torch.stack(cols, -1)[:, 0]  # (N, n, P)
            if not torch.isfinite(J).all():
                break
            step = torch.linalg.lstsq(J, -r[:, 0, :, None]).solution[..., 0]  # (N, P)
            trial = u + step[:, None]
            r_new = residuals(trial)
            loss_new = r_new.pow(2).sum(-1)
            better = (loss_new < loss) & torch.isfinite(loss_new)
            if not better.any():
                break
            u = torch.where(better[..., None], trial, u)
            r = torch.where(better[..., None], r_new, r)
            loss = torch.where(better, loss_new, loss)
    return u


# the relative spread of an observation's time steps still taken as one step (their mean, ``mean_step``): the
# round-off of stamps (a clock written to microseconds, epoch stamps in float64)
UNIFORM = 1e-3


def mean_step(t) -> float:
    """The time step of a uniformly sampled ``t``: its mean (stamps carry round-off)."""
    return float(t[-1] - t[0]) / (len(t) - 1)


# a direction is not identifiable when its standard deviation exceeds half the search box along it,
# or FLAT_RATIO times the standard deviation of the best-determined direction
FLAT_RATIO = 100.0


def _uncertainty(objectives: _Objectives, kind: str, space: _Space, x: torch.Tensor, states, system) -> list[dict]:
    """Estimates, covariance of the identifiable part and the unidentifiable directions of each
    trajectory. The Jacobian ``dr/dx`` is taken by forward mode (one pass per parameter, for all
    trajectories; the trajectory fit's start states in ``2 dof`` passes, each window's residuals
    depending on its own start state only); the start states are nuisance parameters: the
    parameters' information is the Schur complement over them."""
    names = list(system.param_names)
    P, N = len(names), x.shape[0]
    eye = torch.eye(P, dtype=x.dtype)

    def residual(xx, ss):
        return objectives.residuals(kind, space.params(xx)[:, None], None if ss is None else ss[:, None])[:, 0]

    with torch.no_grad():
        r_all = residual(x, states)
    J_all = torch.stack([torch.func.jvp(lambda xx: residual(xx, states), (x.clone(),),
                                        (eye[p].expand_as(x).clone(),))[1] for p in range(P)], -1).detach()
    if states is not None:  # (N, n, M): window w's rows depend on its own 2 dof start-state entries
        two_dof, W = 2 * objectives.dof, objectives.W
        window = objectives.blocks["trajectory"]  # the window of each residual
        J_s = torch.zeros(N, r_all.shape[1], W * two_dof, dtype=x.dtype)
        for j in range(two_dof):
            tangent = torch.zeros(N, W, two_dof, dtype=x.dtype)
            tangent[:, :, j] = 1.0
            d = torch.func.jvp(lambda ss: residual(x, ss), (states.clone(),), (tangent.reshape(N, -1),))[1].detach()
            J_s[:, torch.arange(len(window)), window * two_dof + j] = d
    # the scale the motion cannot see (System.scale_invariance): its tangent at each estimate, in x (the log of a
    # positive parameter, the value of another), is left out of the information, so that direction is reported flat
    # whatever a learned model's imperfect invariance suggests
    scale = system.scale_invariance()
    exponents = torch.tensor([float(scale.get(p, 0.0)) for p in names], dtype=x.dtype)
    tangents = torch.where(space.log, exponents, exponents * space.params(x)) if scale else None
    named = dict(system.identifiable_quantities())
    for name in names:
        named.setdefault(name, {name: 1.0})
    out = []
    for i in range(N):
        r, J_p, xi = r_all[i], J_all[i], x[i]
        J_n = None if states is None else J_s[i]
        n = r.shape[0]
        # the parameters' information with the nuisance states profiled out (Schur complement)
        A = J_p.T @ J_p
        if J_n is not None:
            A_ns = J_n.T @ J_p
            A = A - A_ns.T @ torch.linalg.pinv(J_n.T @ J_n) @ A_ns
        scale_dir = None if tangents is None or tangents[i].norm() == 0 else tangents[i] / tangents[i].norm()
        if scale_dir is not None:
            keep = eye - torch.outer(scale_dir, scale_dir)
            A = keep @ A @ keep
        s2 = float(r.pow(2).sum()) / max(n - P - (0 if J_n is None else J_n.shape[1]), 1)
        eigval, eigvec = torch.linalg.eigh(0.5 * (A + A.T))
        std = (s2 / eigval.clamp_min(1e-300)).sqrt()  # along each eigenvector
        half_box_along = 1.0 / (eigvec.abs() / space.half.abs().clamp_min(1e-12)[:, None]).max(0).values
        flat = (std > 0.5 * half_box_along) | (std > FLAT_RATIO * std.min())
        # cluster-robust covariance of the identifiable directions (and the nuisance states)
        E = eigvec[:, ~flat]
        J_red = J_p @ E if J_n is None else torch.cat([J_p @ E, J_n], 1)
        k = E.shape[1]
        A_inv = torch.linalg.pinv(J_red.T @ J_red)
        blocks = objectives.blocks[kind]
        scores = torch.zeros(int(blocks.max()) + 1, J_red.shape[1], dtype=x.dtype).index_add_(0, blocks,
                                                                                              J_red * r[:, None])
        cov_red = A_inv @ (scores.T @ scores) @ A_inv * (len(scores) / max(len(scores) - 1, 1))
        if len(scores) < MIN_BLOCKS:  # too few blocks to estimate their spread (one block: exactly zero): the
            cov_red = cov_red + s2 * A_inv  # independent residuals' covariance added, so it never collapses
        cov = E @ cov_red[:k, :k] @ E.T
        params = space.params(xi)
        quantities = {}
        for qname, coeffs in named.items():
            c = torch.tensor([float(coeffs.get(p, 0.0)) for p in names], dtype=torch.float64)
            identifiable = bool(((eigvec[:, flat].T @ c).abs() <= 1e-3 * c.norm()).all()) if flat.any() else True
            logarithmic = bool(space.log[c != 0].all())
            value = float(torch.exp(c @ xi)) if logarithmic else float(c @ params)
            std_q = math.sqrt(abs(float(c @ cov @ c))) if identifiable else None
            quantities[qname] = {"value": value, "rel_std" if logarithmic else "std": std_q,
                                 "identifiable": identifiable,
                                 "coefficients": {p: float(v) for p, v in zip(names, c, strict=True) if v != 0}}
        unidentifiable = [{"direction": {p: round(float(v), 3) for p, v in zip(names, eigvec[:, j], strict=True)
                                         if abs(v) > 0.05},
                           "std": float(std[j]),
                           # why: beyond half the search box along it, or 100 times the best-determined direction's
                           "why": "box" if bool(std[j] > 0.5 * half_box_along[j]) else "ratio",
                           # the scale no free motion shows (System.scale_invariance), not a lack of excitation
                           "scale": scale_dir is not None and abs(float(eigvec[:, j] @ scale_dir)) > 0.99}
                          for j in torch.nonzero(flat)[:, 0].tolist()]
        edge = ((xi - space.centre).abs() > 0.999 * space.half.abs()) & ~_flat_members(eigvec[:, flat])
        out.append({"params": {p: float(v) for p, v in zip(names, params, strict=True)}, "quantities": quantities,
                    "at_bound": [p for p, e in zip(names, edge, strict=True) if e],
                    "unidentifiable": unidentifiable, "residual_rms": {kind: float(r.pow(2).mean().sqrt())},
                    "x": xi, "covariance": cov})
    return out


def _f64(x):
    """An observation array as a float64 tensor (None stays None)."""
    return None if x is None else torch.as_tensor(np.asarray(x), dtype=torch.float64)


def _flat_members(directions: torch.Tensor) -> torch.Tensor:
    """The parameters that move along an unidentifiable direction (their value there is arbitrary)."""
    if directions.shape[1] == 0:
        return torch.zeros(directions.shape[0], dtype=torch.bool)
    return (directions.abs() > 0.05).any(1)


def least_squares_reference(system, t, q, qd=None, tau=None, qdd=None, *, window: float = 0.2,
                            derivative: dict | None = None) -> dict | None:
    """Classical identification on the scene's true structure (``System.linear_regressor``): linear
    least squares of its equations of motion in their base parameters, from the same observation
    (and the same derivative estimates) as ``identify``: the ceiling of what the observation allows.

    Returns ``{quantity: {"value", "rel_std"}}`` for the scene's ``identifiable_quantities`` (the
    cluster-robust covariance over time blocks of ``window`` s, propagated to the quantities by their
    Jacobian), or None where the scene has no linear form.
    """
    t, q, qd, tau, qdd = (_f64(x) for x in (t, q, qd, tau, qdd))
    dt = mean_step(t)
    qd, qdd = estimate_derivatives(q[None], dt, None if qd is None else qd[None],
                                   None if qdd is None else qdd[None], derivative)
    e = min(EDGE, q.shape[0] // 10)  # as the acceleration fit: the ends left out
    cut = slice(e, q.shape[0] - e)
    form = system.linear_regressor(q[cut], qd[0, cut], qdd[0, cut], None if tau is None else tau[cut])
    if form is None:
        return None
    Y, b, quantities = form
    phi = torch.linalg.lstsq(Y, b[:, None]).solution[:, 0]
    r = b - Y @ phi
    T = q[cut].shape[0]
    k = max(1, int(round(window / dt)))
    blocks = (torch.arange(Y.shape[0]) % T) // k
    A_inv = torch.linalg.pinv(Y.T @ Y)
    scores = torch.zeros(int(blocks.max()) + 1, Y.shape[1], dtype=Y.dtype).index_add_(0, blocks, Y * r[:, None])
    cov = A_inv @ (scores.T @ scores) @ A_inv * (len(scores) / max(len(scores) - 1, 1))
    values = quantities(phi)
    jac = torch.func.jacrev(quantities)(phi)
    std = (jac @ cov @ jac.T).diagonal().clamp_min(0).sqrt()
    return {name: {"value": float(v), "rel_std": float(s / v.abs())}
            for name, v, s in zip(system.identifiable_quantities(), values, std, strict=True)}
