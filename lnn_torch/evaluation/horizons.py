"""Section ``horizons``: open-loop rollouts started at many points of every trajectory (every
``start_every`` s), driven by the recorded inputs: the coordinate error after fixed horizons
(``horizons``, s) and the time until it first exceeds each threshold, censored at the longest
horizon. It needs no closed form: for a measured system the recordings are the reference."""

from __future__ import annotations

import time

import torch

from ..networks.calls import model_rollout
from .metrics import coordinate_error, divergence_time, quartiles
from .registry import EvalContext, SectionResult, _inputs_note, _units, section, skip
from .report import quartile_cell, table_header, table_row


@section("horizons")
def _horizons(ctx: EvalContext) -> SectionResult:
    """Open-loop rollouts from many start points (every ``start_every`` s of each trajectory, with the
    data's velocity there), driven by the recorded inputs, over ``time_limit`` s (default: the longest
    of ``horizons``): the coordinate error after each horizon (median and 90th percentile over start
    points) and the time until it first exceeds each threshold (quartiles; censored at ``time_limit``)."""
    data, model = ctx.data, ctx.model
    horizons = tuple(ctx.options.get("horizons", (0.1, 0.25, 0.5, 1.0)))
    every = float(ctx.options.get("start_every", 0.5))
    dt = data.dt
    n = int(round(max(max(horizons), float(ctx.options.get("time_limit", 0))) / dt))
    step = max(1, int(round(every / dt)))
    starts = [(j, s) for j, length in enumerate(data.valid_lengths()) for s in range(0, length - n, step)]
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
    arrays = {"trajectory": js}  # per start point: its trajectory, and its time within each threshold
    for thr in ctx.thresholds:
        arrays[f"time_to@{thr:g}"] = divergence_time(q, q_true, dt, thr, ctx.system.angle_mask)
        out[f"time_to@{thr:g}"] = quartiles(arrays[f"time_to@{thr:g}"])
    hs = [f"error@{h:g}s" for h in horizons]
    units = _units(ctx.system)
    block = ["", f"Open-loop from {out['num_starts']} start points (every {every:g} s of each trajectory)"
                 f"{_inputs_note(ctx.system)}:", "",
             *table_header(["", *(k.replace("error@", "after ") for k in hs)]),
             table_row([f"coordinate error ({units}), median", *(f"{out[k]['median']:.2g}" for k in hs)]),
             table_row([f"coordinate error ({units}), 90th percentile", *(f"{out[k]['p90']:.2g}" for k in hs)]), ""]
    block.append(f"Time (s) until the error exceeds a threshold within {out['horizon_s']:g} s of each start point, "
                 "median [q25, q75]: " + "; ".join(
                     f"{thr:g} {units}: {quartile_cell(out[f'time_to@{thr:g}'], out['horizon_s'])}"
                     for thr in ctx.thresholds) + ".")
    logs = {"divergence_time": out[f"time_to@{ctx.thresholds[0]:g}"]["median"],
            "error_at_horizon": out[hs[-1]]["median"]}
    return SectionResult({"horizons": out, "_horizons_arrays": arrays}, blocks=block, logs=logs)
