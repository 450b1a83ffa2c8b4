"""The ``regimes`` section: the model's accelerations in each regime of motion the scene names
(``System.regimes``: e.g. in distribution, out of the parameter range, high energy over the whole circle),
each reported apart so that one number never hides another: the pooled relative L2 error against the
scene's true accelerations, the median and 95th percentile of the per-state relative error, and the
states whose prediction is not finite. Inputs are off (free motion) for an actuated scene. Seeded: the
same states for every model.

    errors = regime_errors(model, system, num=2000, seed=0)   # {regime: {...}}
"""

from __future__ import annotations

import numpy as np
import torch

from ..networks.calls import model_accelerations
from .metrics import relative_l2
from .registry import EvalContext, SectionResult, _closed_form, section
from .report import pct, table_header, table_row

NUM_STATES = 2000  # states per regime in the report


def regime_errors(model, system, num: int = NUM_STATES, seed: int = 0, dtype=torch.float64) -> dict:
    """``{regime: {"states", "acc_rel_err" (pooled), "median", "p95" (per state), "non_finite"}}`` of
    ``model`` on ``num`` states of each of ``system.regimes()`` (the regimes' order, each its own generator
    seeded by ``(seed, index)``)."""
    out = {}
    for k, (name, sampler) in enumerate(system.regimes().items()):
        rng = np.random.default_rng([seed, k])
        q, qd, params = (torch.as_tensor(np.asarray(x), dtype=dtype) for x in sampler(rng, num))
        tau = q.new_zeros(num, 1, system.num_inputs) if system.num_inputs else None
        true = system.acceleration(q, qd, params, None if tau is None else tau[:, 0])
        pred = model_accelerations(model, q[:, None], qd[:, None], params, tau)[:, 0].to(dtype)
        finite = torch.isfinite(pred).all(-1)
        per_state = relative_l2(pred[finite], true[finite], dim=-1)
        out[name] = {"states": num, "acc_rel_err": float(relative_l2(pred[finite], true[finite])),
                     "median": float(per_state.median()) if len(per_state) else float("nan"),
                     "p95": float(torch.quantile(per_state, 0.95)) if len(per_state) else float("nan"),
                     "non_finite": int((~finite).sum())}
    return out


@section("regimes")
def _regimes(ctx: EvalContext) -> SectionResult:
    unavailable = _closed_form(ctx, "true accelerations to sample regimes with")
    if unavailable is not None:
        return unavailable
    errors = regime_errors(ctx.model, ctx.system)
    block = ["", f"Accelerations per regime of motion ({NUM_STATES} seeded states each; the scene's regimes):", "",
             *table_header(["regime", "acc. rel. L2 (pooled)", "per state: median", "95th percentile",
                            "non-finite"]),
             *(table_row([name, pct(r["acc_rel_err"]), pct(r["median"]), pct(r["p95"]), str(r["non_finite"])])
               for name, r in errors.items())]
    logs = {f"regime_{name.split(',')[0].replace(' ', '_')}": r["acc_rel_err"] for name, r in errors.items()}
    return SectionResult({"regimes": errors}, blocks=block, logs=logs)
