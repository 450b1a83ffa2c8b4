"""One evaluation pipeline: ``evaluate_model(model, system, data, ...) -> dict``.

The LightningModule's validation and test, ``lnn-torch evaluate`` and ``scripts/benchmark.py`` all
call it. A report is made of *sections*, each one function of an ``EvalContext`` registered in
``SECTIONS`` (a new metric: one function plus its ``@section`` line):

* ``accelerations``: relative L2 acceleration error (total, per coordinate, per-trajectory median
  and 90th percentile) at every ``accel_stride``-th point of every trajectory;
* ``rollouts``: rollouts from the true initial states with a chosen integrator and step, and the
  time until the coordinate error first exceeds each threshold (quartiles over trajectories);
* ``energy``: the scene's true energy along those rollouts, drift relative to ``V_max - V_min``; for
  a scene with inputs or friction the power-balance error ``|E(t) - E(0) - W(t)|`` instead (``W``
  the true work of the inputs and of friction along the rollout);
* ``torques``: inverse dynamics, the inputs the model needs for the data's accelerations against
  the recorded ones (normalised RMSE per input; structured models of actuated scenes);
* ``friction``: learned against true joint friction (coefficients and curves; scenes with friction);
* ``free_decay``: from rest with the inputs off, the model's own energy against the true energy
  (it must decay like the truth; scenes with friction);
* ``predictability``: the same divergence times for the exact system started ``perturbation`` off
  (the limit any model can reach on chaotic trajectories);
* ``mass_matrix``: the learned mass matrix against the scene's (structured models);
* ``ood``: the scene's own out-of-distribution cases (``System.ood_cases``);
* ``stability``: the scene's hard cases (``lnn_torch.stability``) and a long horizon;
* ``horizons``: open-loop rollouts started at many points of every trajectory (every
  ``start_every`` s), driven by the recorded inputs: the coordinate error after fixed horizons
  (``horizons``, s) and the time until it first exceeds each threshold, censored at the longest
  horizon. The sections that need a closed form (energy, predictability, mass matrix, friction, free
  decay, stability) are skipped for a measured system, whose recordings are the reference.

Models are anything with ``acceleration(q, qd, params, tau=None, check=False)`` and ``rollout(q0,
qd0, params, dt, num_steps, method, tau=None)`` in SI units (every ``DynamicsModel``;
``ClosedForm(system)`` for the scene's own dynamics). Rollouts of an actuated scene are driven by the
recorded inputs, held over each step (zero-order hold). The exact reference is
``lnn_torch.ground_truth.reference_rollout``.
"""

from __future__ import annotations

import contextlib
import functools
import time
from dataclasses import dataclass, field
from typing import Callable

import torch

from .data.trajectories import Trajectories
from .ground_truth import reference_rollout
from .integrators import rollout
from .metrics import (acceleration_errors, condition_numbers, divergence_time, energy_drift,  # noqa: F401
                      normalized_rmse, power_balance_error, quartiles, relative_l2, scaled_matrix_error)

SECTIONS: dict[str, Callable[["EvalContext"], dict]] = {}
DEFAULT_SECTIONS = ("accelerations", "rollouts", "energy")
REPORT_SECTIONS = ("accelerations", "rollouts", "energy", "predictability", "mass_matrix", "torques", "friction",
                   "free_decay", "horizons", "ood", "stability")


def section(name: str):
    """Register a report section: ``fn(ctx: EvalContext) -> dict`` (merged into the result; ``{}``
    when it does not apply)."""
    def register(fn):
        SECTIONS[name] = fn
        return fn
    return register


# ---------------------------------------------------------------------------- models
class ClosedForm:
    """A scene's closed-form dynamics behind the model interface (the ceiling rows of reports)."""

    variant = "closed form"

    def __init__(self, system) -> None:
        self.system = system

    def acceleration(self, q, qd, params, tau=None, check: bool = False):
        return self.system.acceleration(q, qd, params, tau)

    def rollout(self, q0, qd0, params, dt: float, num_steps: int, method: str = "rk4", tau=None):
        return rollout(self.system.acceleration, q0, qd0, params, dt, num_steps, method, tau=tau)


@contextlib.contextmanager
def counting_failures(model):
    """Within the block, a model whose accelerations can be undefined (the black-box LNN's singular
    Hessians) returns NaN there instead of raising, so that batched evaluations count them."""
    previous = getattr(model, "raise_on_singular", None)
    if previous is not None:
        model.raise_on_singular = False
    try:
        yield model
    finally:
        if previous is not None:
            model.raise_on_singular = previous


def model_accelerations(model, q, qd, params, tau=None, max_batch: int = 16384) -> torch.Tensor:
    """A model's accelerations at states ``(B, T, dof)`` of trajectories with parameters ``(B, P)``
    (and inputs ``tau (B, T, n_u)``): ``(B, T, dof)`` in ``q``'s dtype; NaN where undefined. No
    autograd graph."""
    B, T, dof = q.shape
    flat_q, flat_qd = q.reshape(-1, dof), qd.reshape(-1, dof)
    flat_p = params[:, None, :].expand(-1, T, -1).flatten(0, 1)
    flat_tau = None if tau is None else tau.reshape(B * T, -1)
    out = []
    with torch.no_grad(), counting_failures(model):
        for i in range(0, B * T, max_batch):
            sl = slice(i, i + max_batch)
            out.append(model.acceleration(flat_q[sl], flat_qd[sl], flat_p[sl],
                                          None if flat_tau is None else flat_tau[sl], check=False))
    return torch.cat(out).reshape(B, T, dof)


def model_rollout(model, q0, qd0, params, dt: float, num_steps: int, method: str = "rk4", tau=None):
    """A model's rollout (inputs ``tau (B, num_steps, n_u)`` held over each step) without an autograd
    graph; trajectories through undefined accelerations become NaN (counted by the metrics)."""
    with torch.no_grad(), counting_failures(model):
        q, qd = model.rollout(q0, qd0, params, dt, num_steps, method, tau=tau)
    return q.detach(), qd.detach()


# ---------------------------------------------------------------------------- the pipeline
@dataclass
class EvalContext:
    """What every section sees; ``rollouts()`` is computed once and shared."""

    model: object
    system: object
    data: Trajectories
    integrator: str = "rk4"
    dt: float | None = None
    horizon: float | None = None
    thresholds: tuple = (0.1, 0.5)
    accel_stride: int = 10
    num_rollouts: int | None = None
    options: dict = field(default_factory=dict)
    _rollouts: dict | None = None

    def grid(self) -> tuple[float, int, int, int]:
        """``(rollout dt, stride, sub, steps)``: the rollout takes ``steps * sub`` steps of ``dt`` and
        is compared every ``sub`` steps with every ``stride``-th data point (a step coarser than the
        data's is a multiple of it, a finer one divides it)."""
        data_dt = self.data.dt
        dt = self.dt or data_dt
        stride, sub = max(1, int(round(dt / data_dt))), max(1, int(round(data_dt / dt)))
        if abs(stride * data_dt / sub - dt) > 1e-9 * data_dt:
            raise ValueError(f"dt = {dt} and the data's sampling interval {data_dt} are not multiples of each other")
        length = self.data.num_points if self.data.lengths is None else int(self.data.lengths.min())
        available = (length - 1) // stride
        steps = available if self.horizon is None else min(int(round(self.horizon / (stride * data_dt))), available)
        return dt, stride, sub, steps

    def rollouts(self) -> dict:
        """The model's rollouts of the first ``num_rollouts`` trajectories from their true initial
        states, driven by the recorded inputs: ``q_true``, ``qd_true``, ``q``, ``qd`` (each ``(B,
        steps + 1, dof)`` on the compared grid), ``tau`` (the inputs over each grid interval, or
        None), ``params``, ``grid_dt`` and the wall time. A rollout step finer than the data's holds
        each recorded input over its sub-steps (exact); a coarser one holds the input at its start."""
        if self._rollouts is None:
            data = self.data.head(self.num_rollouts)
            dt, stride, sub, steps = self.grid()
            q_true = data.q[:, : steps * stride + 1 : stride]
            qd_true = data.qd[:, : steps * stride + 1 : stride]
            tau = None if data.tau is None else data.tau[:, : steps * stride : stride]
            start = time.perf_counter()
            q, qd = model_rollout(self.model, q_true[:, 0], qd_true[:, 0], data.params, dt, steps * sub, self.integrator,
                                  None if tau is None else tau.repeat_interleave(sub, 1))
            self._rollouts = {"q_true": q_true, "qd_true": qd_true, "q": q[:, ::sub], "qd": qd[:, ::sub], "tau": tau,
                              "params": data.params, "grid_dt": stride * self.data.dt,
                              "seconds": time.perf_counter() - start}
        return self._rollouts


def evaluate_model(model, system, data: Trajectories, *, sections=DEFAULT_SECTIONS, integrator: str = "rk4",
                   dt: float | None = None, horizon: float | None = None, thresholds=(0.1, 0.5),
                   accel_stride: int = 10, num_rollouts: int | None = None, **options) -> dict:
    """Evaluate ``model`` on trajectories of ``system`` (SI units).

    Args:
        model: a ``DynamicsModel`` (``module.model``), ``ClosedForm(system)`` or any object with the
            same ``acceleration``/``rollout`` methods.
        data: the reference trajectories (``Trajectories``, float64).
        sections: names in ``SECTIONS`` to compute.
        integrator, dt: the rollouts' method and step (default: the data's sampling interval).
        horizon: rollout length in s (default: the whole trajectories).
        thresholds: coordinate errors (rad or m) that define divergence times.
        accel_stride: accelerations are evaluated at every ``accel_stride``-th point.
        num_rollouts: roll out only the first so many trajectories (default: all).
        options: section options (``perturbation``, ``stability_seconds``, ``long_horizon_steps``).

    Returns a JSON-ready dict; keys starting with ``_`` hold tensors for plots.
    """
    unknown = [s for s in sections if s not in SECTIONS]
    if unknown:
        raise ValueError(f"unknown evaluation sections {unknown}; known: {', '.join(SECTIONS)}")
    ctx = EvalContext(model, system, data, integrator, dt, horizon, tuple(thresholds), accel_stride, num_rollouts,
                      dict(options))
    out: dict = {"variant": getattr(model, "variant", type(model).__name__), "num_trajectories": len(data),
                 "integrator": integrator, "dt": ctx.grid()[0], "horizon_s": ctx.grid()[3] * ctx.grid()[1] * data.dt}
    for name in sections:
        for key, value in SECTIONS[name](ctx).items():
            if isinstance(value, dict) and isinstance(out.get(key), dict):
                out[key].update(value)  # sections may add to each other's entries
            else:
                out[key] = value
    return out


# ---------------------------------------------------------------------------- sections
@section("accelerations")
def _accelerations(ctx: EvalContext) -> dict:
    data = ctx.data
    if data.qdd is None:
        return {}
    sub = slice(0, None, ctx.accel_stride)
    start = time.perf_counter()
    pred = model_accelerations(ctx.model, data.q[:, sub], data.qd[:, sub], data.params,
                               None if data.tau is None else data.tau[:, sub])
    seconds = time.perf_counter() - start
    return {"acc_rel_err": acceleration_errors(pred, data.qdd[:, sub], ctx.system.coord_names),
            "acceleration_eval_seconds": seconds}


@section("rollouts")
def _rollouts(ctx: EvalContext) -> dict:
    r = ctx.rollouts()
    finite = torch.isfinite(r["q"]).all(-1).all(-1) & torch.isfinite(r["qd"]).all(-1).all(-1)
    out = {f"divergence_time@{thr:g}": {"model": quartiles(divergence_time(r["q"], r["q_true"], r["grid_dt"], thr,
                                                                           ctx.system.angle_mask))}
           for thr in ctx.thresholds}
    out["rollout_non_finite_fraction"] = float(1 - finite.double().mean())
    out["rollout_seconds"] = r["seconds"]
    out["_arrays"] = {"q_true": r["q_true"], "q_model": r["q"], "qd_model": r["qd"], "params": r["params"],
                      "dt": r["grid_dt"]}
    return out


@section("energy")
def _energy(ctx: EvalContext) -> dict:
    """The true-energy drift of the rollouts; with forces, their power-balance error."""
    if not ctx.system.closed_form:
        return {}
    r = ctx.rollouts()
    if ctx.system.has_forces:
        drift = power_balance_error(ctx.system, r["q"], r["qd"], r["params"], r["tau"], r["grid_dt"])
        key = "power_balance_error"
    else:
        drift, key = energy_drift(ctx.system, r["q"], r["qd"], r["params"]), "energy_drift"
    finite = torch.isfinite(drift).all(1)
    nan = float("nan")
    return {key: {"mean": float(drift[finite].mean()) if finite.any() else nan,
                  "max": float(drift[finite].max()) if finite.any() else nan,
                  "non_finite_fraction": float(1 - finite.double().mean())},
            "_arrays": {"drift": drift}}


@section("torques")
def _torques(ctx: EvalContext) -> dict:
    """Inverse dynamics: the inputs the model needs for the data's accelerations against the
    recorded inputs, normalised RMSE per input (structured models of actuated scenes)."""
    data, model = ctx.data, ctx.model
    if data.tau is None or data.qdd is None or not hasattr(model, "inverse_dynamics"):
        return {}
    sub = slice(0, None, ctx.accel_stride)
    B, T, dof = data.q[:, sub].shape
    flat = lambda x: x[:, sub].reshape(B * T, -1)  # noqa: E731
    params = data.params[:, None].expand(-1, T, -1).flatten(0, 1)
    with torch.no_grad():
        pred = model.inverse_dynamics(flat(data.q), flat(data.qd), flat(data.qdd), params)
    err = normalized_rmse(pred, flat(data.tau))
    names = getattr(ctx.system, "input_names", ()) or [f"u{i}" for i in range(err.numel())]
    return {"torque_nrmse": {"mean": float(err.mean()), **{n: float(e) for n, e in zip(names, err)}}}


@section("friction")
def _friction(ctx: EvalContext) -> dict:
    """Learned against true joint friction, per trajectory's parameters and joint, over the joint
    rates of the data: the relative L2 error of the friction-torque curve (where the true friction is
    not negligible) and the coefficients. Needs a model with ``forces`` and a scene with friction."""
    system, model, data = ctx.system, ctx.model, ctx.data
    forces = getattr(model, "forces", None)
    if not system.has_friction or forces is None or not forces.friction or not system.closed_form:
        return {}
    D = system.joint_map()
    rates = data.qd.reshape(-1, system.dof) @ D.T
    v_max = float(torch.quantile(rates.abs().double(), 0.99, dim=0).max())
    grid = torch.linspace(-v_max, v_max, 201, dtype=torch.float64)[None, :, None].expand(len(data), -1, D.shape[0])
    params = data.params[:, None].expand(-1, grid.shape[1], -1)
    true = system.friction_torque(grid, params)  # (B, 201, n_j)
    with torch.no_grad():
        p_n = model.normalizer.params(data.params.to(model.dtype))
        learned = forces.friction_torque(grid.to(model.dtype), p_n[:, None].expand(-1, grid.shape[1], -1)).double()
        b, c = (x.double() for x in forces.coefficients(p_n))
    scale = true.abs().amax(1)  # (B, n_j)
    err = (learned - true).norm(dim=1) / true.norm(dim=1).clamp_min(1e-30)  # (B, n_j)
    significant = scale > 0.1 * scale.max()
    out = {"curve_rel_err_median": float(err[significant].median()) if significant.any() else float("nan"),
           "curve_rel_err_p90": float(torch.quantile(err[significant], 0.9)) if significant.any() else float("nan"),
           "rate_range": v_max}
    true_coef = getattr(system, "friction_coefficients", None)
    if true_coef is not None:
        tb, tc = true_coef(data.params)
        out["viscous_abs_err_median"] = float((b - tb).abs().median())
        out["coulomb_abs_err_median"] = float((c - tc).abs().median())
    return {"friction": out, "_friction_arrays": {"rates": grid[0, :, 0], "true": true, "learned": learned}}


@section("free_decay")
def _free_decay(ctx: EvalContext) -> dict:
    """From rest at the trajectories' initial angles, inputs off: the model's own energy (in J,
    through its force scale) against the true energy along the true trajectory. A model whose
    dissipation is right loses the same energy: reports the relative error of the energy lost
    and the divergence time (structured models of scenes with friction)."""
    system, model, data = ctx.system, ctx.model, ctx.data
    if (not system.has_friction or not system.closed_form or not hasattr(model, "energy_norm")
            or getattr(model, "forces", None) is None):
        return {}
    rollouts = ctx.rollouts()
    n = rollouts["q_true"].shape[1] - 1
    dt = rollouts["grid_dt"]
    q0 = data.q[: len(rollouts["params"]), 0]
    params = rollouts["params"]
    zeros = None if not system.num_inputs else torch.zeros(len(q0), n, system.num_inputs, dtype=q0.dtype)
    qt, qdt = reference_rollout(system, q0, torch.zeros_like(q0), params, dt, n, tau=zeros)
    qm, qdm = model_rollout(model, q0, torch.zeros_like(q0), params, dt, n, ctx.integrator, tau=zeros)
    E_true = system.energy(qt, qdt, params[:, None].expand(-1, n + 1, -1))
    with torch.no_grad():
        B = len(q0)
        q_n, qd_n, p_n = model.normalize(qm.reshape(-1, system.dof).to(model.dtype),
                                         qdm.reshape(-1, system.dof).to(model.dtype),
                                         params[:, None].expand(-1, n + 1, -1).reshape(B * (n + 1), -1).to(model.dtype))
        H = model.energy_norm(q_n, qd_n, p_n)[0].reshape(B, n + 1).double()
    E_model = H / float(model.normalizer.force_scale) if system.num_inputs else H  # in J where inputs fix the scale
    lost_true = E_true[:, 0] - E_true[:, -1]
    lost_model = E_model[:, 0] - E_model[:, -1]
    rel = (lost_model - lost_true).abs() / lost_true.abs().clamp_min(1e-30)
    div = divergence_time(qm, qt, dt, ctx.thresholds[0], system.angle_mask)
    return {"free_decay": {"energy_lost_rel_err_median": float(rel.median()), "seconds": n * dt,
                           f"divergence_time@{ctx.thresholds[0]:g}_median": float(div.median())},
            "_decay_arrays": {"E_true": E_true - E_true[:, :1], "E_model": E_model - E_model[:, :1], "dt": dt}}


@section("predictability")
def _predictability(ctx: EvalContext) -> dict:
    if not ctx.system.closed_form:
        return {}
    r = ctx.rollouts()
    perturbation = ctx.options.get("perturbation", 1e-6)
    steps = r["q_true"].shape[1] - 1
    q_x, _ = reference_rollout(ctx.system, r["q_true"][:, 0] + perturbation, r["qd_true"][:, 0], r["params"],
                               r["grid_dt"], steps, tau=r["tau"])
    out = {f"divergence_time@{thr:g}": {"exact_perturbed": quartiles(
        divergence_time(q_x, r["q_true"], r["grid_dt"], thr, ctx.system.angle_mask))} for thr in ctx.thresholds}
    out["perturbation"] = perturbation
    out["_arrays"] = {"q_exact": q_x}
    return out


@section("mass_matrix")
def _mass_matrix(ctx: EvalContext) -> dict:
    """Relative Frobenius error of the learned M after the best scale per trajectory, and cond(M).

    The learned M lives in normalised velocities ``qd_n = qd * tau / scale``: it equals
    ``D M_n D`` (``D = diag(tau / scale)``) in SI units."""
    model, system, data = ctx.model, ctx.system, ctx.data
    if not hasattr(model, "mass_matrix_norm") or not system.quadratic_kinetic or not system.closed_form:
        return {}
    q = data.q[:, :: ctx.accel_stride]
    B, T, dof = q.shape
    qf = q.reshape(-1, dof)
    params = data.params[:, None, :].expand(-1, T, -1).flatten(0, 1)
    with torch.no_grad():
        M_n = model.mass_matrix(qf.to(model.dtype), params.to(model.dtype)).double()
    norm = model.normalizer
    D = norm.time_scale.double() / norm.coord_scale.double()
    M_model = (D[:, None] * M_n * D[None, :]).reshape(B, T, dof, dof)
    err = scaled_matrix_error(system.mass_matrix(qf, params).reshape(B, T, dof, dof), M_model)
    cond = condition_numbers(M_n)
    return {"mass_matrix": {"rel_frobenius_median": float(err.median()), "rel_frobenius_max": float(err.max()),
                            "cond_median": float(cond.median()), "cond_max": float(cond.max())}}


@section("ood")
def _ood(ctx: EvalContext) -> dict:
    system = ctx.system
    cases = system.ood_cases()
    if not cases:
        return {}
    f64 = lambda key: torch.tensor([c[key] for c in cases], dtype=torch.float64)  # noqa: E731
    params, q0, qd0 = f64("params"), f64("q0"), f64("qd0")
    dt, _, _, _ = ctx.grid()
    n = int(round((ctx.horizon or ctx.data.dt * (ctx.data.num_points - 1)) / dt))
    # an actuated scene's cases are free motion: inputs off
    tau = None if not system.num_inputs else torch.zeros(len(cases), n + 1, system.num_inputs, dtype=torch.float64)
    steps_tau = None if tau is None else tau[:, :n]
    qt, qdt = reference_rollout(system, q0, qd0, params, dt, n, tau=steps_tau)
    qm, qdm = model_rollout(ctx.model, q0, qd0, params, dt, n, ctx.integrator, tau=steps_tau)
    a_true = system.acceleration(qt, qdt, params[:, None].expand(-1, n + 1, -1), tau)
    a_pred = model_accelerations(ctx.model, qt, qdt, params, tau)
    drift = power_balance_error(system, qm, qdm, params, steps_tau, dt)
    rows = [{"params": list(c["params"]), "state0": [*c["q0"], *c["qd0"]],
             "acc_rel_err": float(relative_l2(a_pred[i], a_true[i])),
             "divergence_time@0.1": float(divergence_time(qm[i:i + 1], qt[i:i + 1], dt, 0.1, system.angle_mask)[0]),
             "energy_drift_mean": float(drift[i].mean()), "energy_drift_max": float(drift[i].max())}
            for i, c in enumerate(cases)]
    return {"ood": rows, "_ood_arrays": {"q_true": qt, "q_model": qm, "params": params, "dt": dt}}


@section("stability")
def _stability(ctx: EvalContext) -> dict:
    from .stability import HardCase, hard_cases, run_hard_cases

    seconds = ctx.options.get("stability_seconds", 5.0)
    long_steps = ctx.options.get("long_horizon_steps", 100_000)
    if seconds <= 0 or not ctx.system.closed_form:
        return {}
    dt = ctx.grid()[0]
    cases = hard_cases(ctx.system, num=8, dt=dt, num_steps=int(round(seconds / dt)))
    if long_steps:
        nominal = cases[0]
        cases.append(HardCase(f"long horizon: {long_steps:.0e} {ctx.integrator} steps", nominal.q0[:2],
                              nominal.qd0[:2], nominal.params[:2], dt=dt, num_steps=long_steps))
    rows = run_hard_cases(functools.partial(model_rollout, ctx.model), ctx.system, cases,
                          model=ctx.model if hasattr(ctx.model, "mass_matrix_norm") else None, method=ctx.integrator)
    return {"stability": rows}


@section("horizons")
def _horizons(ctx: EvalContext) -> dict:
    """Open-loop rollouts from many start points (every ``start_every`` s of each trajectory, with the
    data's velocity there), driven by the recorded inputs, over ``time_limit`` s (default: the longest
    of ``horizons``): the coordinate error after each horizon (median and 90th percentile over start
    points) and the time until it first exceeds each threshold (quartiles; censored at ``time_limit``)."""
    from .metrics import coordinate_error

    data, model = ctx.data, ctx.model
    horizons = tuple(ctx.options.get("horizons", (0.1, 0.25, 0.5, 1.0)))
    every = float(ctx.options.get("start_every", 0.5))
    dt = data.dt
    n = int(round(max(max(horizons), float(ctx.options.get("time_limit", 0))) / dt))
    step = max(1, int(round(every / dt)))
    lengths = [data.num_points] * len(data) if data.lengths is None else [int(x) for x in data.lengths]
    starts = [(j, s) for j, length in enumerate(lengths) for s in range(0, length - n, step)]
    if not starts:
        return {}
    js = torch.tensor([j for j, _ in starts])
    ss = torch.tensor([s for _, s in starts])
    window = ss[:, None] + torch.arange(n + 1)  # (S, n + 1)
    q_true = data.q[js[:, None], window]
    tau = None if data.tau is None else data.tau[js[:, None], window[:, :-1]]
    start = time.perf_counter()
    q, _ = model_rollout(model, q_true[:, 0], data.qd[js, ss], data.params[js], dt, n, ctx.integrator, tau)
    seconds = time.perf_counter() - start
    err = coordinate_error(q, q_true, ctx.system.angle_mask)  # (S, n + 1)
    out = {"num_starts": len(starts), "start_every_s": every, "horizon_s": n * dt, "rollout_seconds": seconds}
    for h in horizons:
        e = err[:, int(round(h / dt))]
        e = torch.where(torch.isfinite(e), e, torch.full_like(e, float("inf")))
        out[f"error@{h:g}s"] = {"median": float(e.median()), "p90": float(torch.quantile(e.double(), 0.9))}
    for thr in ctx.thresholds:
        out[f"time_to@{thr:g}"] = quartiles(divergence_time(q, q_true, dt, thr, ctx.system.angle_mask))
    return {"horizons": out}