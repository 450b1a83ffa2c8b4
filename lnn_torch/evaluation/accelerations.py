"""Section ``accelerations``: the relative L2 acceleration error (total, per coordinate, per-trajectory
median and 90th percentile, and the fraction of non-finite points) at every ``accel_stride``-th point
of every trajectory, against the data's accelerations (recorded or estimated)."""

from __future__ import annotations

import time

from ..networks.calls import model_accelerations
from .metrics import acceleration_errors
from .registry import EvalContext, SectionResult, section, skip
from .report import pct, table_row

_LABELS = {"per_trajectory_median": "per-trajectory median", "per_trajectory_p90": "per-trajectory p90",
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
                         rows=[table_row([f"acceleration rel. L2 error ({_LABELS.get(k, k)})", pct(v)])
                               for k, v in acc.items()], logs=logs)
