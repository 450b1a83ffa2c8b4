"""Numerical stability on hard cases: extreme parameters, high energy, large angles, zero velocity.

``hard_cases(system)`` builds the cases for a scene: its own extreme parameter vectors
(``System.hard_parameter_cases``: extreme mass and length ratios for the pendula)
and the generic ones (parameters x10 and x0.1, inverted and whirling starts or 10x velocities,
angles of +-1e4 rad, zero and tiny velocities); ``run_hard_cases`` rolls a dynamics model (or the
closed form) out on each and reports, per case:

* ``non_finite_fraction``: trajectories whose rollout has a NaN or Inf anywhere;
* ``max_energy_drift``: max over finite trajectories of |E(t) - E(0)| / (V_max - V_min), with the
  scene's true energy;
* ``max_cond``: the largest condition number of the learned mass matrix along the rollouts
  (structured models only);
* ``error``: the message, where the model refuses the input with a clear error.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputError, UntrustedParameterWarning
from ..networks.capabilities import MASS_MATRIX, capabilities_of
from ..networks.normalization import Normalizer
from .metrics import condition_numbers, energy_drift
from .report import pct, table_header, table_row


@dataclass
class HardCase:
    name: str
    q0: torch.Tensor  # (B, dof)
    qd0: torch.Tensor  # (B, dof)
    params: torch.Tensor  # (B, P)
    dt: float = 0.005
    num_steps: int = 1000


def hard_cases(system, num: int = 8, seed: int = 0, dt: float = 0.005, num_steps: int = 1000) -> list[HardCase]:
    """The hard cases of a scene, ``num`` trajectories each (float64)."""
    rng = np.random.default_rng(seed)
    f64 = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float64)  # noqa: E731
    base_p = f64(system.sample_params(rng, num))
    q0, qd0 = (f64(x) for x in system.sample_state(rng, num))
    angles = torch.tensor(system.angle_mask)
    cases = [HardCase("nominal", q0, qd0, base_p)]

    def with_params(name, values):
        cases.append(HardCase(name, q0, qd0, f64(values)[None].expand(num, -1).clone()))

    for name, values in system.hard_parameter_cases().items():
        with_params(name, values)
    for k in (10, 0.1):
        scaled, label = system.scaled_params(base_p, k)
        cases.append(HardCase(label, q0, qd0, scaled))
    if system.speed_limit is None:
        if angles.any():
            # the angles only: a scene's other coordinates (a spring's length) keep their sampled state
            inverted = torch.where(angles, math.pi + f64(rng.uniform(-0.1, 0.1, q0.shape)), q0)
            fast = torch.where(angles, f64(rng.choice([-10.0, 10.0], qd0.shape)), qd0)
            cases.append(HardCase("inverted, |qd0| = 10 rad/s", inverted, fast, base_p))
            cases.append(HardCase("whirling from rest position", torch.where(angles, 0.0, q0), fast, base_p))
        else:
            cases.append(HardCase("|qd0| x 10", q0, qd0 * 10, base_p))
    else:  # a scene with a speed limit: close to it
        cases.append(HardCase("|qd0| = 0.99 c", q0, torch.sign(qd0) * 0.99 * system.speed_limit, base_p))
    if angles.any():
        turns = 2 * math.pi * torch.round(torch.tensor(1e4) / (2 * math.pi))
        cases.append(HardCase("angles +1e4 rad", torch.where(angles, q0 + turns, q0), qd0, base_p))
        cases.append(HardCase("angles -1e4 rad", torch.where(angles, q0 - turns, q0), qd0, base_p))
    cases.append(HardCase("zero velocity", q0, torch.zeros_like(qd0), base_p))
    cases.append(HardCase("tiny velocity 1e-9", q0, torch.full_like(qd0, 1e-9), base_p))
    for c in cases:
        c.dt, c.num_steps = dt, num_steps
    return cases


def _max_cond(model, q: torch.Tensor, params: torch.Tensor) -> float | None:
    """Largest condition number of the learned mass matrix over rollout states (structured models)."""
    if MASS_MATRIX not in capabilities_of(model):
        return None
    B, T, dof = q.shape
    finite = torch.isfinite(q).all(-1).all(-1)
    if not finite.any():
        return float("nan")
    qf = q[finite][:, :: max(1, T // 200)]  # at most ~200 states per trajectory
    params = params[finite][:, None].expand(-1, qf.shape[1], -1)
    with torch.no_grad():
        q_n, _, p_n = model.normalize(*(x.to(model.dtype) for x in (qf.reshape(-1, dof),) * 2),
                                      params.flatten(0, -2).to(model.dtype))
        M = model.mass_matrix_norm(q_n, p_n)
    return float(condition_numbers(M.double()).max())


def run_hard_cases(rollout_fn, system, cases: list[HardCase], model=None, method: str = "rk4") -> list[dict]:
    """Roll ``rollout_fn`` ``(q0, qd0, params, dt, num_steps, method[, tau=]) -> (q, qd)`` out on every
    case (an actuated scene's inputs are off: ``tau`` zeros). The energy column is the true-energy
    drift, and for a scene with friction the energy may only decrease: it is the drift all the same.

    ``model``: the dynamics model (for the condition number of its mass matrix), or None.
    """
    rows = []
    for case in cases:
        row = {"case": case.name, "num_trajectories": int(case.q0.shape[0]), "steps": case.num_steps, "dt": case.dt}
        inputs = {} if not system.num_inputs else {
            "tau": torch.zeros(case.q0.shape[0], case.num_steps, system.num_inputs, dtype=case.q0.dtype)}
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", UntrustedParameterWarning)
                q, qd = rollout_fn(case.q0, case.qd0, case.params, case.dt, case.num_steps, method, **inputs)
            for w in caught:
                if issubclass(w.category, UntrustedParameterWarning):
                    row["untrusted_parameters"] = str(w.message)
                else:
                    warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        except InputError as err:
            row["error"] = str(err)
            rows.append(row)
            continue
        q, qd = q.detach().double(), qd.detach().double()
        finite = torch.isfinite(q).all(-1).all(-1) & torch.isfinite(qd).all(-1).all(-1)
        row["non_finite_fraction"] = float(1 - finite.double().mean())
        if finite.any():
            drift = energy_drift(system, q[finite], qd[finite], case.params[finite])
            row["max_energy_drift"] = float(drift.max())
        else:
            row["max_energy_drift"] = float("nan")
        if model is not None:
            row["max_cond"] = _max_cond(model, q, case.params)
        rows.append(row)
    return rows


def _by_case(results: dict[str, list[dict]]):
    """``(case, {model: its row for that case})`` in the order of the cases."""
    for case in [r["case"] for r in next(iter(results.values()))]:
        yield case, {name: next(x for x in rows if x["case"] == case) for name, rows in results.items()}


def stability_markdown(results: dict[str, list[dict]]) -> str:
    """A Markdown table: one row per (case, model) with non-finite fraction, max drift and cond(M).
    Case names and refusals are written as they are (the shipped reports' text: a ``|`` in them is
    not escaped)."""
    lines = table_header(["case", "model", "non-finite rollouts", "max true-energy drift", "max cond(M)"])
    clamped: set[str] = set()  # the marks used: * beyond the training range, ** beyond the trusted range
    for case, row_of in _by_case(results):
        for name, r in row_of.items():
            if "error" in r:
                lines.append(table_row([case, name, f"refused: {r['error']}", "-", "-"]))
                continue
            cond = r.get("max_cond")
            message = r.get("untrusted_parameters", "")
            mark = " **" if "conditioned on the nearest" in message else " *" if message else ""
            clamped |= {mark.strip()} - {""}
            lines.append(table_row([case + mark, name, pct(r["non_finite_fraction"]), f"{r['max_energy_drift']:.2e}",
                                    "-" if cond is None else f"{cond:.3g}"]))
    if "*" in clamped:
        lines += ["", "\\* parameters beyond the range the model was trained on (its answers there are "
                      "extrapolation)."]
    if "**" in clamped:
        lines += ["", f"\\*\\* parameters beyond the model's trusted range ({Normalizer.TRUST:g} standard deviations "
                      "of its training parameters): the model is conditioned on the nearest trusted values."]
    return "\n".join(lines)


def stability_pivot(results: dict[str, list[dict]]) -> str:
    """The same results as a Markdown grid: one row per case, one column per model; each cell is the
    max true-energy drift, with the non-finite fraction where it is not 0 and cond(M) where known."""
    names = list(results)
    lines = table_header(["case", *names])
    for case, row_of in _by_case(results):
        cells = []
        for r in row_of.values():
            if "error" in r:
                cells.append("refused")
                continue
            cell = f"{r['max_energy_drift']:.1e}"
            if r.get("max_cond") is not None:
                cell += f" (cond {r['max_cond']:.3g})"
            if r["non_finite_fraction"] > 0:
                cell += f", **{100 * r['non_finite_fraction']:.0f} % non-finite**"
            cells.append(cell)
        lines.append(table_row([case.replace("|", "&#124;"), *cells]))
    return "\n".join(lines)
