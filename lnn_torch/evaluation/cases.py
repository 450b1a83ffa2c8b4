"""The sections on the scene's own cases:

* ``ood``: the scene's out-of-distribution cases (``System.ood_cases``), inputs off: acceleration
  error, divergence time and energy drift (power-balance error with forces) per case;
* ``stability``: the scene's hard cases (``lnn_torch.evaluation.stability``: extreme parameters, high energy,
  large angles, zero velocity) and a long horizon.
"""

from __future__ import annotations

import functools

import torch

from ..networks.calls import model_accelerations, model_rollout
from ..networks.capabilities import MASS_MATRIX, capabilities_of
from ..systems.ground_truth import reference_rollout
from .metrics import divergence_time, power_balance_error, relative_l2
from .plots import frames_figure
from .registry import EvalContext, SectionResult, _closed_form, _figure, _units, section, skip
from .report import pct, table_header, table_row, time_cell
from .stability import HardCase, hard_cases, run_hard_cases, stability_markdown


@section("ood")
def _ood(ctx: EvalContext) -> SectionResult:
    system = ctx.system
    cases = system.ood_cases()
    if not cases:
        return skip(f"scene '{system.name}' defines no out-of-distribution cases")
    device = ctx.data.q.device
    f64 = lambda key: torch.tensor([c[key] for c in cases], dtype=torch.float64, device=device)  # noqa: E731
    params, q0, qd0 = f64("params"), f64("q0"), f64("qd0")
    dt, _, _, _ = ctx.grid()
    n = int(round((ctx.horizon or ctx.data.dt * (ctx.data.num_points - 1)) / dt))
    # an actuated scene's cases are free motion: inputs off
    tau = None if not system.num_inputs else q0.new_zeros(len(cases), n + 1, system.num_inputs)
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
    cap = n * dt
    block = ["", "Out-of-distribution cases (the scene's own):", "",
             *table_header([f"({', '.join(system.param_names)})", "[q0, qd0]", "acc. rel. L2",
                            f"time to 0.1 {_units(system)} error (s)",
                            f"{'power-balance error' if system.has_forces else 'energy drift'} mean / max"]),
             *(table_row([f"({', '.join(f'{v:.4g}' for v in c['params'])})", c["state0"], pct(c["acc_rel_err"]),
                          time_cell(c["divergence_time@0.1"], cap),
                          f"{c['energy_drift_mean']:.2e} / {c['energy_drift_max']:.2e}"]) for c in rows)]
    arrays = {"q_true": qt, "q_model": qm, "params": params, "dt": dt}
    return SectionResult({"ood": rows, "_ood_arrays": arrays}, blocks=block, figures={
        "frames_ood_case1.png": _figure(frames_figure, system, qt[0], qm[0], params[0], dt,
                                        title=f"out-of-distribution case 1: ({', '.join(system.param_names)}) = "
                                              f"{tuple(cases[0]['params'])}, true (solid) and model (dashed)")})


@section("stability")
def _stability(ctx: EvalContext) -> SectionResult:
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
    block = ["", f"Stability on hard cases ({ctx.integrator}, dt = {dt:g} s; `lnn_torch.evaluation.stability`):", "",
             stability_markdown({variant: rows})]
    return SectionResult({"stability": rows}, blocks=block)
