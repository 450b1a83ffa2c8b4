"""The sections that compare the model's physical parts with the scene's (each asks the model's
declared capabilities, ``lnn_torch.networks.capabilities``, and its SI accessors):

* ``mass_matrix``: the learned mass matrix against the scene's (structured models);
* ``torques``: inverse dynamics, the inputs the model needs for the data's accelerations against
  the recorded ones: the RMS error per input in N m beside the data's own standard deviation (what
  identification papers report for arms), the normalised RMSE and its square, the normalised MSE
  Deep Lagrangian Networks report (structured models of actuated scenes); a figure of measured and
  predicted torques over the first trajectory;
* ``friction``: learned against true joint friction (coefficients and curves; scenes with friction);
* ``free_decay``: from rest with the inputs off, the model's own energy against the true energy
  (it must decay like the truth; scenes with friction).
"""

from __future__ import annotations

import torch

from ..networks.calls import model_rollout
from ..networks.capabilities import ENERGY, FRICTION, INVERSE_DYNAMICS, MASS_MATRIX
from ..systems.ground_truth import reference_rollout
from .metrics import condition_numbers, divergence_time, normalized_rmse, scaled_matrix_error
from .plots import decay_figure, friction_figure, torque_figure
from .registry import EvalContext, SectionResult, _closed_form, _figure, section, skip
from .report import pct, table_row


def _finite_rows(*tensors) -> torch.Tensor:
    """Rows ``(N,)`` where every given ``(N, ...)`` tensor (None ignored) is finite: the valid points of
    recordings padded with NaN."""
    ok = None
    for x in tensors:
        if x is not None:
            f = torch.isfinite(x).reshape(x.shape[0], -1).all(-1)
            ok = f if ok is None else ok & f
    return ok


@section("mass_matrix", needs=(MASS_MATRIX,))
def _mass_matrix(ctx: EvalContext) -> SectionResult:
    """Relative Frobenius error of the learned M (SI velocities, ``mass_matrix``) after the best
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
        M_model = model.mass_matrix(qf, params).reshape(B, T, dof, dof)
        q_n, _, p_n = model.normalize(qf.to(model.dtype), qf.to(model.dtype), params.to(model.dtype))
        M_n = model.mass_matrix_norm(q_n, p_n).double()  # normalised units
    err = scaled_matrix_error(system.mass_matrix(qf, params).reshape(B, T, dof, dof), M_model)
    cond = condition_numbers(M_n)
    m = {"rel_frobenius_median": float(err.median()), "rel_frobenius_max": float(err.max()),
         "cond_median": float(cond.median()), "cond_max": float(cond.max())}
    return SectionResult({"mass_matrix": m}, rows=[
        table_row(["mass-matrix rel. Frobenius error (best scale per system): median, max",
                   f"{pct(m['rel_frobenius_median'])}, {pct(m['rel_frobenius_max'])}"]),
        table_row(["cond(M) of the learned mass matrix: median, max", f"{m['cond_median']:.1f}, {m['cond_max']:.1f}"])])


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
        pred = model.inverse(q, qd, qdd, params)
    err = normalized_rmse(pred, tau)
    names = list(getattr(ctx.system, "input_names", ()) or [f"u{i}" for i in range(err.numel())])

    def per_input(values) -> dict:
        return {"mean": float(values.mean()), **{n: float(e) for n, e in zip(names, values, strict=True)}}

    t = per_input(err)
    # Deep Lagrangian Networks report the normalised MSE (the square of the above) per joint
    mse = per_input(err.pow(2))
    rms = per_input((pred - tau).pow(2).mean(0).sqrt())  # N m, what identification papers report for arms
    std = per_input(tau.std(0))

    def row(what: str, e: dict, cell=pct) -> str:
        return table_row([f"inverse-dynamics torque error, {what}: mean ({', '.join(names)})",
                          f"{cell(e['mean'])} ({', '.join(cell(e[n]) for n in names)})"])

    nm = lambda x: f"{x:.3g}"  # noqa: E731
    first = int(ok.reshape(B, T)[0].sum()) if not ok.all() else T  # the first trajectory's valid points
    units = list(getattr(ctx.system, "input_units", ()) or ["N m"] * len(names))  # (a force on a length: N)
    unit = units[0] if len(set(units)) == 1 else "SI"
    arrays = {"t": torch.arange(first) * ctx.accel_stride * data.dt, "measured": tau[:first], "predicted": pred[:first],
              "names": names, "units": units}
    rows = [row("normalised RMSE", t), row("normalised MSE (DeLaN's)", mse), row(f"RMS ({unit})", rms, nm),
            table_row([f"torque standard deviation of the data ({unit}): mean ({', '.join(names)})",
                       f"{nm(std['mean'])} ({', '.join(nm(std[n]) for n in names)})"])]
    return SectionResult({"torque_nrmse": t, "torque_nmse": mse, "torque_rms_nm": rms, "torque_std_nm": std},
                         rows=rows, figures={"torques.png": _figure(torque_figure, arrays)},
                         logs={"torque_rms": rms["mean"], "torque_nrmse": t["mean"]})


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
        learned = model.friction_torque(grid, params)
        b, c = model.friction_coefficients(data.params)
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
        table_row(["friction-torque curve rel. L2 error, median [p90] over trajectories and joints",
                   f"{pct(out['curve_rel_err_median'])} [{pct(out['curve_rel_err_p90'])}]"])],
        figures={"friction.png": _figure(friction_figure, arrays)})


@section("free_decay", needs=(ENERGY, FRICTION))
def _free_decay(ctx: EvalContext) -> SectionResult:
    """From rest at the trajectories' initial angles, inputs off: the model's own energy
    (``energy``: in J where inputs fix its scale) against the true energy along the true
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
    zeros = None if not system.num_inputs else q0.new_zeros(len(q0), n, system.num_inputs)
    qt, qdt = reference_rollout(system, q0, torch.zeros_like(q0), params, dt, n, tau=zeros)
    qm, qdm = model_rollout(model, q0, torch.zeros_like(q0), params, dt, n, ctx.integrator, tau=zeros)
    E_true = system.energy(qt, qdt, params[:, None].expand(-1, n + 1, -1))
    B = len(q0)
    with torch.no_grad():
        E_model = model.energy(qm.reshape(-1, system.dof), qdm.reshape(-1, system.dof),
                                  params[:, None].expand(-1, n + 1, -1).reshape(B * (n + 1), -1)).reshape(B, n + 1)
    lost_true = E_true[:, 0] - E_true[:, -1]
    lost_model = E_model[:, 0] - E_model[:, -1]
    rel = (lost_model - lost_true).abs() / lost_true.abs().clamp_min(1e-30)
    div = divergence_time(qm, qt, dt, ctx.thresholds[0], system.angle_mask)
    d = {"energy_lost_rel_err_median": float(rel.median()), "seconds": n * dt,
         f"divergence_time@{ctx.thresholds[0]:g}_median": float(div.median())}
    arrays = {"E_true": E_true - E_true[:, :1], "E_model": E_model - E_model[:, :1], "dt": dt}
    return SectionResult({"free_decay": d, "_decay_arrays": arrays}, rows=[
        table_row([f"free decay over {d['seconds']:g} s, inputs off: energy lost, rel. error (median)",
                   pct(d["energy_lost_rel_err_median"])])],
        figures={"free_decay.png": _figure(decay_figure, arrays)})
