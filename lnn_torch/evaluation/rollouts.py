"""The sections over the model's rollouts from the true initial states (``EvalContext.rollouts``: one
integrator and step, driven by the recorded inputs, zero-order hold; computed once and shared):

* ``rollouts``: the time until the coordinate error first exceeds each threshold (quartiles over
  trajectories), and the fraction of non-finite rollouts;
* ``energy``: the scene's true energy along those rollouts, drift relative to ``V_max - V_min``; for
  a scene with inputs or friction the power-balance error ``|E(t) - E(0) - W(t)|`` instead (``W``
  the true work of the inputs and of friction along the rollout);
* ``predictability``: the same divergence times for the exact system started ``perturbation`` off
  (the limit any model can reach on chaotic trajectories).
"""

from __future__ import annotations

import torch

from ..systems.ground_truth import reference_rollout
from .metrics import divergence_time, energy_drift, power_balance_error, quartiles
from .plots import drift_figure, error_growth_figure, trajectory_figure
from .registry import EvalContext, SectionResult, _closed_form, _figure, _inputs_note, _units, host, section
from .report import pct, quartile_cell, table_row


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
    rows = [table_row([f"time to {thr:g} {_units(system)} error, model{_inputs_note(system)}: median [q25, q75] (s)",
                       quartile_cell(out[f"divergence_time@{thr:g}"]["model"], cap)]) for thr in ctx.thresholds]
    span = f" within the first {cap:g} s" if r["stopped_early"] else ""
    rows.append(table_row([f"non-finite rollouts{span}", pct(out["rollout_non_finite_fraction"])]))
    if r["stopped_early"]:
        out["rollout_stopped_at_s"] = cap
        units = _units(system)
        rows.append(table_row([f"rollouts stopped once every one had left {max(ctx.thresholds):g} {units} "
                               "(measured recordings) after (s)", f"{cap:g}"]))
    arrays = out["_arrays"]

    def error_growth(result):
        exact = result["_arrays"].get("q_exact")  # the predictability section's, where it was computed
        return error_growth_figure(host(arrays["q_true"]), host(arrays["q_model"]), host(exact), arrays["dt"],
                                   system.angle_mask, result.get("perturbation", 1e-6), _units(system).strip("()"))

    figures = {"trajectory.png": _figure(trajectory_figure, arrays["q_true"][0], arrays["q_model"][0], arrays["dt"],
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
                         rows=[table_row([f"{label}: mean, max", f"{e['mean']:.2e}, {e['max']:.2e}"])],
                         figures={png: _figure(drift_figure, drift, r["grid_dt"], system.has_forces)},
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
    rows = [table_row([f"time to {thr:g} {_units(ctx.system)} error, exact system started {perturbation:g} off: "
                       "median [q25, q75] (s)", quartile_cell(out[f"divergence_time@{thr:g}"]["exact_perturbed"], cap)])
            for thr in ctx.thresholds]
    return SectionResult(out, rows=rows)
