"""The registry of evaluation sections and what every section sees.

A section is one function of an ``EvalContext`` registered in ``SECTIONS`` by its
``@section(name, needs=...)`` line; it returns a ``SectionResult`` (its values, its rows and blocks
of the report, its figures and the scalars training logs), ``skip(reason)``, or simply a dict of
values (reported as rows of their scalars). The registration order is the report's order.

Also here: the small helpers the sections share (``_closed_form``: skip a scene without one,
``_units``, ``_inputs_note``, ``_figure``: a lazily drawn figure of ``lnn_torch.evaluation.plots``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from ..data.trajectories import Trajectories
from ..networks.calls import model_rollout
from .metrics import coordinate_error
from .report import scalar_rows

SECTIONS: dict[str, Callable[[EvalContext], SectionResult | dict]] = {}


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
    def of(cls, out) -> SectionResult:
        """A section's return value as a ``SectionResult``: a plain dict is its values, its scalars the
        report's rows (``{}``: not applicable)."""
        if isinstance(out, SectionResult):
            return out
        if not out:
            return skip("not applicable here")
        return cls(values=dict(out), rows=scalar_rows(out))


def skip(reason: str) -> SectionResult:
    """A section that does not apply, and why (stated in the report)."""
    return SectionResult(skipped=reason)


def section_logs(result: dict) -> dict[str, float]:
    """The scalars the computed sections of ``result`` (``evaluate_model``) give to training logs."""
    return {k: v for s in result.get("_sections", {}).values() for k, v in s.logs.items()}


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
        if self.dt is not None and not (math.isfinite(self.dt) and self.dt > 0):
            raise ValueError(f"dt must be a positive step in s, got {self.dt}")
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
        None), ``params``, ``grid_dt``, the wall time and ``stopped_early``. A rollout step finer than
        the data's holds each recorded input over its sub-steps (exact); a coarser one holds the input
        at its start.

        For measured recordings (no closed form: no energy to follow along the rollouts) the rollout runs
        in segments, the first of about one second, each next one twice as long, and stops at the end of
        the first segment in which every trajectory has left the largest threshold: the divergence times
        are those of the whole rollout, and a real arm's model leaves the threshold within a second of a
        recording minutes long. The arrays then end there (``steps`` the grid steps rolled out; the
        trajectory figure and the non-finite fraction cover that span). Every segment continues exactly
        from where the one before ended: the same numbers as one long rollout."""
        if self._rollouts is None:
            data = self.data.head(self.num_rollouts)
            dt, stride, sub, steps = self.grid()
            q_true = data.q[:, : steps * stride + 1 : stride]
            qd_true = data.qd[:, : steps * stride + 1 : stride]
            tau = None if data.tau is None else data.tau[:, : steps * stride : stride]
            segment = steps if self.system.closed_form else max(1, int(round(1.0 / (stride * self.data.dt))))
            start = time.perf_counter()
            qs, qds, done, stopped = [q_true[:, :1]], [qd_true[:, :1]], 0, False
            while done < steps:
                n = min(segment, steps - done)
                u = None if tau is None else tau[:, done : done + n].repeat_interleave(sub, 1)
                q, qd = model_rollout(self.model, qs[-1][:, -1], qds[-1][:, -1], data.params, dt, n * sub,
                                      self.integrator, u)
                qs.append(q[:, sub::sub])
                qds.append(qd[:, sub::sub])
                done += n
                segment *= 2
                if done < steps:
                    err = coordinate_error(torch.cat(qs, 1), q_true[:, : done + 1], self.system.angle_mask)
                    if bool((~(err <= max(self.thresholds))).any(1).all()):  # NaN counts as beyond
                        stopped = True
                        break
            self._rollouts = {"q_true": q_true[:, : done + 1], "qd_true": qd_true[:, : done + 1],
                              "q": torch.cat(qs, 1), "qd": torch.cat(qds, 1),
                              "tau": None if tau is None else tau[:, :done], "params": data.params,
                              "grid_dt": stride * self.data.dt, "seconds": time.perf_counter() - start,
                              "stopped_early": stopped}
        return self._rollouts


# ---------------------------------------------------------------------------- helpers of the sections
def _closed_form(ctx: EvalContext, what: str) -> SectionResult | None:
    """``skip`` for a scene without a closed form (measured recordings), which ``what`` needs."""
    if ctx.system.closed_form:
        return None
    return skip(f"scene '{ctx.system.name}' has no closed form (measured recordings): no {what}")


def _units(system) -> str:
    """The unit of the scene's coordinates in the report: ``rad``, or ``(rad or m)`` for mixed ones."""
    return "rad" if all(system.angle_mask) else "(rad or m)"


def _inputs_note(system) -> str:
    """", driven by the recorded inputs" for a scene with inputs, else nothing."""
    return ", driven by the recorded inputs" if getattr(system, "num_inputs", 0) else ""


def _figure(draw: Callable, *args, **kwargs) -> Callable[[dict], object]:
    """A figure builder ``fn(result)``: ``draw(*args, **kwargs)`` (a figure of ``lnn_torch.evaluation.plots``),
    drawn only when the builder is called, with tensors copied to the host (a model evaluated on a
    GPU: matplotlib reads host memory)."""
    def build(result: dict):
        return draw(*map(host, args), **{k: host(v) for k, v in kwargs.items()})
    return build


def host(x):
    """``x`` with every tensor in it (in dicts, lists and tuples too) copied to the CPU, for drawing."""
    if isinstance(x, torch.Tensor):
        return x.detach().cpu()
    if isinstance(x, dict):
        return {k: host(v) for k, v in x.items()}
    if type(x) in (list, tuple):  # not a named tuple's own type: left as it is
        return type(x)(host(v) for v in x)
    return x
