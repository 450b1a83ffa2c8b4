"""One evaluation pipeline: ``evaluate_model(model, system, data, ...) -> dict``.

The LightningModule's validation and test, ``lnn-torch evaluate`` and ``scripts/benchmark.py`` all
call it. A report is made of *sections*, each one function of an ``EvalContext`` registered in
``SECTIONS`` by its ``@section(name, needs=...)`` line. A new metric is that one function plus
that one line, in this file: it returns a ``SectionResult`` (its values, its rows and blocks of the
report, its figures and the scalars training logs) or ``skip(reason)``, or simply a dict of values
(reported as rows of their scalars). ``lnn-torch evaluate`` (``commands/evaluate.write_report``),
the plots (``plots.evaluation_plots``) and the LightningModule's logging loop over what the sections
present; none of them knows a section by name. A section asks the model only through its declared
capabilities (``needs``; ``lnn_torch.networks.base``: energy, mass matrix, inverse dynamics,
friction...) and its SI accessors; one the model or the scene cannot give is skipped with its reason
(``result["skipped"]``, and the report's last lines), never an error. The sections:

* ``accelerations``: relative L2 acceleration error (total, per coordinate, per-trajectory median
  and 90th percentile) at every ``accel_stride``-th point of every trajectory;
* ``rollouts``: rollouts from the true initial states with a chosen integrator and step, and the
  time until the coordinate error first exceeds each threshold (quartiles over trajectories);
* ``energy``: the scene's true energy along those rollouts, drift relative to ``V_max - V_min``; for
  a scene with inputs or friction the power-balance error ``|E(t) - E(0) - W(t)|`` instead (``W``
  the true work of the inputs and of friction along the rollout);
* ``torques``: inverse dynamics, the inputs the model needs for the data's accelerations against
  the recorded ones (normalised RMSE per input, and its square, the normalised MSE Deep Lagrangian
  Networks report; structured models of actuated scenes);
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
``ClosedForm(system)`` for the scene's own dynamics), and ``capabilities`` (a set of the
``lnn_torch.networks.base`` capability names; an object without it provides none). Rollouts of an actuated scene are driven by the
recorded inputs, held over each step (zero-order hold). The exact reference is
``lnn_torch.ground_truth.reference_rollout``.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field
from typing import Callable

import torch

from .data.trajectories import Trajectories
from .ground_truth import ClosedForm, reference_rollout  # noqa: F401 - ClosedForm: also importable from here
from .metrics import (acceleration_errors, condition_numbers, divergence_time, energy_drift,  # noqa: F401
                      normalized_rmse, power_balance_error, quartiles, relative_l2, scaled_matrix_error)
from .networks.calls import counting_failures, model_accelerations, model_rollout  # noqa: F401 - also from here
from .networks.capabilities import ENERGY, FRICTION, INVERSE_DYNAMICS, MASS_MATRIX, capabilities_of, missing
from .report import pct as _pct
from .report import quartile_cell as _quartile_cell
from .report import scalar_rows as _scalar_rows
from .report import time_cell as _time

SECTIONS: dict[str, Callable[["EvalContext"], "SectionResult | dict"]] = {}
DEFAULT_SECTIONS = ("accelerations", "rollouts", "energy")


def section(name: str, needs: tuple[str, ...] = (), report: bool = True):
    """Register a report section: ``fn(ctx: EvalContext) -> SectionResult`` (or ``skip(reason)``, or a
    plain dict of values, ``{}`` when it does not apply). ``needs``: the model capabilities it asks
    for (a model without them skips it, the reason stated); ``report``: part of ``lnn-torch
    evaluate``'s report (``report_sections()``)."""
    def register(fn):
        fn.needs, fn.report = tuple(needs), bool(report)
        SECTIONS[name] = fn
        return fn
    return register


def report_sections() -> tuple[str, ...]:
    """The sections of ``lnn-torch evaluate``'s report, in their registration order."""
    return tuple(name for name, fn in SECTIONS.items() if getattr(fn, "report", True))


@dataclass
class SectionResult:
    """What a section gives: its ``values`` (merged into ``evaluate_model``'s JSON-ready result; keys
    starting with ``_`` hold tensors), how it presents itself (``rows`` of the report's main ``| metric
    | value |`` table, Markdown ``blocks`` after it, ``figures``: PNG name -> ``fn(result)`` giving a
    matplotlib figure or None, drawn only when asked; ``tags``: a figure's TensorBoard tag where it is
    not the PNG's stem), the scalars ``logs`` that training logs as ``{prefix}/{name}``, and
    ``skipped``: why it does not apply (then nothing else)."""

    values: dict = field(default_factory=dict)
    rows: list[str] = field(default_factory=list)
    blocks: list[str] = field(default_factory=list)
    figures: dict[str, Callable[[dict], object]] = field(default_factory=dict)
    logs: dict[str, float] = field(default_factory=dict)
    skipped: str | None = None
    tags: dict[str, str] = field(default_factory=dict)  # PNG name -> the logger's figure tag (default: its stem)

    @classmethod
    def of(cls, out) -> "SectionResult":
        """A section's return value as a ``SectionResult``: a plain dict is its values, its scalars the
        report's rows (``{}``: not applicable)."""
        if isinstance(out, SectionResult):
            return out
        if not out:
            return skip("not applicable here")
        return cls(values=dict(out), rows=_scalar_rows(out))


def skip(reason: str) -> SectionResult:
    """A section that does not apply, and why (stated in the report)."""
    return SectionResult(skipped=reason)


def _figure(name: str, *args, **kwargs):
    """A figure builder of ``lnn_torch.plots`` (imported only when a figure is drawn)."""
    def build(result: dict):
        from . import plots

        return getattr(plots, name)(*args, **kwargs)
    return build


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
                   accel_stride: int = 10, num_rollouts: int | None = None, progress=None, **options) -> dict:
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
        progress: called with each section's name before it is computed (e.g. to tell the user).
        options: section options (``perturbation``, ``stability_seconds``, ``long_horizon_steps``,
            ``horizons``, ``start_every``, ``time_limit``).

    Returns a JSON-ready dict: the sections' values merged; ``skipped``: ``{section: reason}`` for
    those that do not apply; keys starting with ``_`` hold tensors for plots and, under
    ``_sections``, each computed section's ``SectionResult`` (rows, figures, logs) in order.
    """
    unknown = [s for s in sections if s not in SECTIONS]
    if unknown:
        raise ValueError(f"unknown evaluation sections {unknown}; known: {', '.join(SECTIONS)}")
    ctx = EvalContext(model, system, data, integrator, dt, horizon, tuple(thresholds), accel_stride, num_rollouts,
                      dict(options))
    out: dict = {"variant": getattr(model, "variant", type(model).__name__), "scene": system.name,
                 "num_trajectories": len(data),
                 "integrator": integrator, "dt": ctx.grid()[0], "horizon_s": ctx.grid()[3] * ctx.grid()[1] * data.dt}
    presented: dict[str, SectionResult] = {}
    skipped: dict[str, str] = {}
    for name in sections:
        fn = SECTIONS[name]
        reason = missing(model, getattr(fn, "needs", ()))
        if progress is not None and reason is None:
            progress(name)
        result = skip(reason) if reason is not None else SectionResult.of(fn(ctx))
        if result.skipped is not None:
            skipped[name] = result.skipped
            continue
        presented[name] = result
        for key, value in result.values.items():
            if isinstance(value, dict) and isinstance(out.get(key), dict):
                out[key].update(value)  # sections may add to each other's entries
            else:
                out[key] = value
    if skipped:
        out["skipped"] = skipped
    out["_sections"] = presented
    return out


def section_logs(result: dict) -> dict[str, float]:
    """The scalars the computed sections of ``result`` (``evaluate_model``) give to training logs."""
    return {k: v for s in result.get("_sections", {}).values() for k, v in s.logs.items()}


def section_figures(result: dict, tags: bool = False, case: str | None = None) -> dict[str, Callable[[dict], object]]:
    """PNG name (with ``tags``: the figure's logger tag) -> figure builder ``fn(result)`` over the
    computed sections of ``result``. Each figure is titled with the model, the scene and ``case``
    (e.g. "test split"); its own axes say what it shows."""
    title = f"{result.get('variant', 'model')} on {result.get('scene', '?')}" + (f", {case}" if case else "")

    def titled(build):
        def draw(res: dict):
            fig = build(res)
            if fig is not None:
                fig.suptitle(title, fontsize=10)
                fig.tight_layout()
            return fig
        return draw

    return {(s.tags.get(k, k.removesuffix(".png")) if tags else k): titled(v)
            for s in result.get("_sections", {}).values() for k, v in s.figures.items()}


def _closed_form(ctx: EvalContext, what: str) -> SectionResult | None:
    """``skip`` for a scene without a closed form (measured recordings), which ``what`` needs."""
    if ctx.system.closed_form:
        return None
    return skip(f"scene '{ctx.system.name}' has no closed form (measured recordings): no {what}")


def _units(system) -> str:
    return "rad" if all(system.angle_mask) else "(rad or m)"


def _inputs_note(system) -> str:
    """", driven by the recorded inputs" for a scene with inputs, else nothing."""
    return ", driven by the recorded inputs" if getattr(system, "num_inputs", 0) else ""


def _finite_rows(*tensors) -> torch.Tensor:
    """Rows ``(N,)`` where every given ``(N, ...)`` tensor (None ignored) is finite: the valid points of
    recordings padded with NaN."""
    ok = None
    for x in tensors:
        if x is not None:
            f = torch.isfinite(x).reshape(x.shape[0], -1).all(-1)
            ok = f if ok is None else ok & f
    return ok


# ---------------------------------------------------------------------------- sections
_ACC_LABELS = {"per_trajectory_median": "per-trajectory median", "per_trajectory_p90": "per-trajectory p90",
               "non_finite_fraction": "non-finite points"}


@section("accelerations")
def _accelerations(ctx: EvalContext) -> SectionResult:
    data = ctx.data
    if data.qdd is None:
        return skip("the data have no accelerations (neither recorded nor estimated: set data.targets)")
    sub = slice(0, None, ctx.accel_stride)
    start = time.perf_counter()
    pred = model_accelerations(ctx.model, data.q[:, sub], data.qd[:, sub], data.params,
                               None if data.tau is None else data.tau[:, sub])
    seconds = time.perf_counter() - start
    acc = acceleration_errors(pred, data.qdd[:, sub], ctx.system.coord_names)
    logs = {"acc_rel_err": acc["total"], **{f"acc_rel_err_{n}": acc[n] for n in ctx.system.coord_names},
            "acc_rel_err_traj_median": acc.get("per_trajectory_median", float("nan")),
            "acc_non_finite": acc["non_finite_fraction"]}
    return SectionResult({"acc_rel_err": acc, "acceleration_eval_seconds": seconds},
                         rows=[f"| acceleration rel. L2 error ({_ACC_LABELS.get(k, k)}) | {_pct(v)} |"
                               for k, v in acc.items()], logs=logs)


@section("rollouts")
def _rollouts(ctx: EvalContext) -> SectionResult:
    r = ctx.rollouts()
    system = ctx.system
    finite = torch.isfinite(r["q"]).all(-1).all(-1) & torch.isfinite(r["qd"]).all(-1).all(-1)
    out = {f"divergence_time@{thr:g}": {"model": quartiles(divergence_time(r["q"], r["q_true"], r["grid_dt"], thr,
                                                                           system.angle_mask))}
           for thr in ctx.thresholds}
    out["rollout_non_finite_fraction"] = float(1 - finite.double().mean())
    out["rollout_seconds"] = r["seconds"]
    out["_arrays"] = {"q_true": r["q_true"], "q_model": r["q"], "qd_model": r["qd"], "params": r["params"],
                      "dt": r["grid_dt"]}
    cap = (r["q"].shape[1] - 1) * r["grid_dt"]
    rows = [f"| time to {thr:g} {_units(system)} error, model{_inputs_note(system)}: median [q25, q75] (s) | "
            f"{_quartile_cell(out[f'divergence_time@{thr:g}']['model'], cap)} |" for thr in ctx.thresholds]
    rows.append(f"| non-finite rollouts | {_pct(out['rollout_non_finite_fraction'])} |")
    arrays = out["_arrays"]

    def error_growth(result):
        from .plots import error_growth_figure

        exact = result["_arrays"].get("q_exact")
        return error_growth_figure(arrays["q_true"], arrays["q_model"], exact, arrays["dt"], system.angle_mask,
                                   result.get("perturbation", 1e-6), _units(system).strip("()"))

    figures = {"trajectory.png": _figure("trajectory_figure", arrays["q_true"][0], arrays["q_model"][0], arrays["dt"],
                                         system.coord_names, system.coord_units),
               "error_growth.png": error_growth}
    logs = {"rollout_non_finite": out["rollout_non_finite_fraction"],
            "divergence_time": out[f"divergence_time@{ctx.thresholds[0]:g}"]["model"]["median"]}
    return SectionResult(out, rows=rows, figures=figures, logs=logs)


@section("energy")
def _energy(ctx: EvalContext) -> SectionResult:
    """The true-energy drift of the rollouts; with forces, their power-balance error."""
    unavailable = _closed_form(ctx, "true energy")
    if unavailable:
        return unavailable
    r, system = ctx.rollouts(), ctx.system
    if system.has_forces:
        drift = power_balance_error(system, r["q"], r["qd"], r["params"], r["tau"], r["grid_dt"])
        key, log = "power_balance_error", "power_balance"
        label = "power-balance error \\|E(t) - E(0) - W(t)\\| / (V_max - V_min)"
    else:
        drift, key, log = energy_drift(system, r["q"], r["qd"], r["params"]), "energy_drift", "energy_drift"
        label = "true-energy drift / (V_max - V_min)"
    finite = torch.isfinite(drift).all(1)
    nan = float("nan")
    e = {"mean": float(drift[finite].mean()) if finite.any() else nan,
         "max": float(drift[finite].max()) if finite.any() else nan,
         "non_finite_fraction": float(1 - finite.double().mean())}
    png = "power_balance.png" if system.has_forces else "energy_drift.png"
    return SectionResult({key: e, "_arrays": {"drift": drift}},
                         rows=[f"| {label}: mean, max | {e['mean']:.2e}, {e['max']:.2e} |"],
                         figures={png: _figure("drift_figure", drift, r["grid_dt"], system.has_forces)},
                         logs={log: e["mean"], f"{log}_max": e["max"]}, tags={png: "energy"})


@section("predictability")
def _predictability(ctx: EvalContext) -> SectionResult:
    unavailable = _closed_form(ctx, "exact reference to perturb")
    if unavailable:
        return unavailable
    r = ctx.rollouts()
    perturbation = ctx.options.get("perturbation", 1e-6)
    steps = r["q_true"].shape[1] - 1
    q_x, _ = reference_rollout(ctx.system, r["q_true"][:, 0] + perturbation, r["qd_true"][:, 0], r["params"],
                               r["grid_dt"], steps, tau=r["tau"])
    out = {f"divergence_time@{thr:g}": {"exact_perturbed": quartiles(
        divergence_time(q_x, r["q_true"], r["grid_dt"], thr, ctx.system.angle_mask))} for thr in ctx.thresholds}
    out["perturbation"] = perturbation
    out["_arrays"] = {"q_exact": q_x}
    cap = (q_x.shape[1] - 1) * r["grid_dt"]
    rows = [f"| time to {thr:g} {_units(ctx.system)} error, exact system started {perturbation:g} off: median "
            f"[q25, q75] (s) | {_quartile_cell(out[f'divergence_time@{thr:g}']['exact_perturbed'], cap)} |"
            for thr in ctx.thresholds]
    return SectionResult(out, rows=rows)


@section("mass_matrix", needs=(MASS_MATRIX,))
def _mass_matrix(ctx: EvalContext) -> SectionResult:
    """Relative Frobenius error of the learned M (SI velocities, ``mass_matrix_si``) after the best
    scale per trajectory, and the condition number of the M the model's solve sees (``mass_matrix``,
    normalised units)."""
    model, system, data = ctx.model, ctx.system, ctx.data
    unavailable = _closed_form(ctx, "true mass matrix")
    if unavailable:
        return unavailable
    if not system.quadratic_kinetic:
        return skip(f"scene '{system.name}' has no mass matrix (its kinetic energy is not quadratic)")
    q = data.q[:, :: ctx.accel_stride]
    B, T, dof = q.shape
    qf = q.reshape(-1, dof)
    params = data.params[:, None, :].expand(-1, T, -1).flatten(0, 1)
    with torch.no_grad():
        M_model = model.mass_matrix_si(qf, params).reshape(B, T, dof, dof)
        M_n = model.mass_matrix(qf.to(model.dtype), params.to(model.dtype)).double()  # normalised units
    err = scaled_matrix_error(system.mass_matrix(qf, params).reshape(B, T, dof, dof), M_model)
    cond = condition_numbers(M_n)
    m = {"rel_frobenius_median": float(err.median()), "rel_frobenius_max": float(err.max()),
         "cond_median": float(cond.median()), "cond_max": float(cond.max())}
    return SectionResult({"mass_matrix": m}, rows=[
        f"| mass-matrix rel. Frobenius error (best scale per system): median, max | "
        f"{_pct(m['rel_frobenius_median'])}, {_pct(m['rel_frobenius_max'])} |",
        f"| cond(M) of the learned mass matrix: median, max | {m['cond_median']:.1f}, {m['cond_max']:.1f} |"])


@section("torques", needs=(INVERSE_DYNAMICS,))
def _torques(ctx: EvalContext) -> SectionResult:
    """Inverse dynamics: the inputs the model needs for the data's accelerations against the
    recorded inputs, normalised RMSE per input (at the valid points of recordings)."""
    data, model = ctx.data, ctx.model
    if data.tau is None or data.qdd is None:
        return skip("the data have no " + ("inputs" if data.tau is None else "accelerations"))
    sub = slice(0, None, ctx.accel_stride)
    B, T, dof = data.q[:, sub].shape
    flat = lambda x: x[:, sub].reshape(B * T, -1)  # noqa: E731
    q, qd, qdd, tau = flat(data.q), flat(data.qd), flat(data.qdd), flat(data.tau)
    params = data.params[:, None].expand(-1, T, -1).flatten(0, 1)
    ok = _finite_rows(q, qd, qdd, tau)
    if not ok.all():  # recordings padded with NaN
        q, qd, qdd, tau, params = (x[ok] for x in (q, qd, qdd, tau, params))
    with torch.no_grad():
        pred = model.inverse_dynamics(q, qd, qdd, params)
    err = normalized_rmse(pred, tau)
    names = list(getattr(ctx.system, "input_names", ()) or [f"u{i}" for i in range(err.numel())])
    t = {"mean": float(err.mean()), **{n: float(e) for n, e in zip(names, err)}}
    row = ("| inverse-dynamics torque error, normalised RMSE: mean (" + ", ".join(k for k in t if k != "mean")
           + f") | {_pct(t['mean'])} (" + ", ".join(_pct(v) for k, v in t.items() if k != "mean") + ") |")
    # Deep Lagrangian Networks report the normalised MSE (the square of the above) per joint
    mse = {"mean": float(err.pow(2).mean()), **{n: float(e) ** 2 for n, e in zip(names, err)}}
    row_mse = ("| inverse-dynamics torque error, normalised MSE (DeLaN's): mean (" + ", ".join(names)
               + f") | {_pct(mse['mean'])} (" + ", ".join(_pct(mse[n]) for n in names) + ") |")
    return SectionResult({"torque_nrmse": t, "torque_nmse": mse}, rows=[row, row_mse])


@section("friction", needs=(FRICTION,))
def _friction(ctx: EvalContext) -> SectionResult:
    """Learned against true joint friction, per trajectory's parameters and joint, over the joint
    rates of the data: the relative L2 error of the friction-torque curve (where the true friction is
    not negligible) and the coefficients."""
    system, model, data = ctx.system, ctx.model, ctx.data
    unavailable = _closed_form(ctx, "true friction")
    if unavailable:
        return unavailable
    D = system.joint_map()
    rates = data.qd.reshape(-1, system.dof) @ D.T
    v_max = float(torch.quantile(rates.abs().double(), 0.99, dim=0).max())
    grid = torch.linspace(-v_max, v_max, 201, dtype=torch.float64)[None, :, None].expand(len(data), -1, D.shape[0])
    params = data.params[:, None].expand(-1, grid.shape[1], -1)
    true = system.friction_torque(grid, params)  # (B, 201, n_j)
    with torch.no_grad():
        learned = model.friction_torque_si(grid, params)
        b, c = model.friction_coefficients_si(data.params)
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
    arrays = {"rates": grid[0, :, 0], "true": true, "learned": learned}
    return SectionResult({"friction": out, "_friction_arrays": arrays}, rows=[
        f"| friction-torque curve rel. L2 error, median [p90] over trajectories and joints | "
        f"{_pct(out['curve_rel_err_median'])} [{_pct(out['curve_rel_err_p90'])}] |"],
        figures={"friction.png": _figure("friction_figure", arrays)})


@section("free_decay", needs=(ENERGY, FRICTION))
def _free_decay(ctx: EvalContext) -> SectionResult:
    """From rest at the trajectories' initial angles, inputs off: the model's own energy
    (``energy_si``: in J where inputs fix its scale) against the true energy along the true
    trajectory. A model whose dissipation is right loses the same energy: reports the relative error
    of the energy lost and the divergence time."""
    system, model, data = ctx.system, ctx.model, ctx.data
    unavailable = _closed_form(ctx, "true energy")
    if unavailable:
        return unavailable
    rollouts = ctx.rollouts()
    n = rollouts["q_true"].shape[1] - 1
    dt = rollouts["grid_dt"]
    q0 = data.q[: len(rollouts["params"]), 0]
    params = rollouts["params"]
    zeros = None if not system.num_inputs else torch.zeros(len(q0), n, system.num_inputs, dtype=q0.dtype)
    qt, qdt = reference_rollout(system, q0, torch.zeros_like(q0), params, dt, n, tau=zeros)
    qm, qdm = model_rollout(model, q0, torch.zeros_like(q0), params, dt, n, ctx.integrator, tau=zeros)
    E_true = system.energy(qt, qdt, params[:, None].expand(-1, n + 1, -1))
    B = len(q0)
    with torch.no_grad():
        E_model = model.energy_si(qm.reshape(-1, system.dof), qdm.reshape(-1, system.dof),
                                  params[:, None].expand(-1, n + 1, -1).reshape(B * (n + 1), -1)).reshape(B, n + 1)
    lost_true = E_true[:, 0] - E_true[:, -1]
    lost_model = E_model[:, 0] - E_model[:, -1]
    rel = (lost_model - lost_true).abs() / lost_true.abs().clamp_min(1e-30)
    div = divergence_time(qm, qt, dt, ctx.thresholds[0], system.angle_mask)
    d = {"energy_lost_rel_err_median": float(rel.median()), "seconds": n * dt,
         f"divergence_time@{ctx.thresholds[0]:g}_median": float(div.median())}
    arrays = {"E_true": E_true - E_true[:, :1], "E_model": E_model - E_model[:, :1], "dt": dt}
    return SectionResult({"free_decay": d, "_decay_arrays": arrays}, rows=[
        f"| free decay over {d['seconds']:g} s, inputs off: energy lost, rel. error (median) | "
        f"{_pct(d['energy_lost_rel_err_median'])} |"], figures={"free_decay.png": _figure("decay_figure", arrays)})


@section("horizons")
def _horizons(ctx: EvalContext) -> SectionResult:
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
        return skip(f"no trajectory is longer than the longest horizon, {n * dt:g} s")
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
    hs = [f"error@{h:g}s" for h in horizons]
    units = _units(ctx.system)
    block = ["", f"Open-loop from {out['num_starts']} start points (every {every:g} s of each trajectory)"
                 f"{_inputs_note(ctx.system)}:", "",
             "| | " + " | ".join(k.replace("error@", "after ") for k in hs) + " |", "|---" * (len(hs) + 1) + "|",
             f"| coordinate error ({units}), median | " + " | ".join(f"{out[k]['median']:.2g}" for k in hs) + " |",
             f"| coordinate error ({units}), 90th percentile | " + " | ".join(f"{out[k]['p90']:.2g}" for k in hs)
             + " |", ""]
    block.append(f"Time (s) until the error exceeds a threshold within {out['horizon_s']:g} s of each start point, "
                 "median [q25, q75]: " + "; ".join(
                     f"{thr:g} {units}: {_quartile_cell(out[f'time_to@{thr:g}'], out['horizon_s'])}"
                     for thr in ctx.thresholds) + ".")
    logs = {"divergence_time": out[f"time_to@{ctx.thresholds[0]:g}"]["median"],
            "error_at_horizon": out[hs[-1]]["median"]}
    return SectionResult({"horizons": out}, blocks=block, logs=logs)


@section("ood")
def _ood(ctx: EvalContext) -> SectionResult:
    system = ctx.system
    cases = system.ood_cases()
    if not cases:
        return skip(f"scene '{system.name}' defines no out-of-distribution cases")
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
    block = ["", "Out-of-distribution cases (the scene's own):", "",
             f"| ({', '.join(system.param_names)}) | [q0, qd0] | acc. rel. L2 | time to 0.1 {_units(system)} error (s) | "
             f"{'power-balance error' if system.has_forces else 'energy drift'} mean / max |", "|---|---|---|---|---|"]
    cap = n * dt
    block += [f"| ({', '.join(f'{v:.4g}' for v in c['params'])}) | {c['state0']} | {_pct(c['acc_rel_err'])} | "
              f"{_time(c['divergence_time@0.1'], cap)} | "
              f"{c['energy_drift_mean']:.2e} / {c['energy_drift_max']:.2e} |" for c in rows]
    arrays = {"q_true": qt, "q_model": qm, "params": params, "dt": dt}
    return SectionResult({"ood": rows, "_ood_arrays": arrays}, blocks=block, figures={
        "frames_ood_case1.png": _figure("frames_figure", system, qt[0], qm[0], params[0], dt,
                                        title=f"out-of-distribution case 1: ({', '.join(system.param_names)}) = "
                                              f"{tuple(cases[0]['params'])}, true (solid) and model (dashed)")})


@section("stability")
def _stability(ctx: EvalContext) -> SectionResult:
    from .stability import HardCase, hard_cases, run_hard_cases, stability_markdown

    seconds = ctx.options.get("stability_seconds", 5.0)
    long_steps = ctx.options.get("long_horizon_steps", 100_000)
    if seconds <= 0:
        return skip("stability_seconds is 0")
    unavailable = _closed_form(ctx, "true energy or parameter ranges for hard cases")
    if unavailable:
        return unavailable
    dt = ctx.grid()[0]
    cases = hard_cases(ctx.system, num=8, dt=dt, num_steps=int(round(seconds / dt)))
    if long_steps:
        nominal = cases[0]
        cases.append(HardCase(f"long horizon: {long_steps:.0e} {ctx.integrator} steps", nominal.q0[:2],
                              nominal.qd0[:2], nominal.params[:2], dt=dt, num_steps=long_steps))
    with_m = MASS_MATRIX in capabilities_of(ctx.model)  # the condition number of its mass matrix
    rows = run_hard_cases(functools.partial(model_rollout, ctx.model), ctx.system, cases,
                          model=ctx.model if with_m else None, method=ctx.integrator)
    variant = getattr(ctx.model, "variant", type(ctx.model).__name__)
    block = ["", f"Stability on hard cases ({ctx.integrator}, dt = {dt:g} s; `lnn_torch.stability`):", "",
             stability_markdown({variant: rows})]
    return SectionResult({"stability": rows}, blocks=block)


REPORT_SECTIONS = report_sections()  # accelerations ... stability, in the order above
