"""One evaluation pipeline: ``evaluate_model(model, system, data, ...) -> dict``.

The LightningModule's validation and test, ``lnn-torch evaluate`` and the benchmarks all call it. A
report is made of *sections*, each one function of an ``EvalContext`` registered in ``SECTIONS`` by
its ``@section(name, needs=...)`` line (``registry``). A new metric is that one function plus that
one line, in the section module of its concept: it returns a ``SectionResult`` (its values, its rows
and blocks of the report, its figures and the scalars training logs) or ``skip(reason)``, or simply
a dict of values (reported as rows of their scalars). ``lnn-torch evaluate``
(``commands/evaluate.write_report``), the figures (``plots.section_figures``) and training's logging
loop over what the sections present; none of them knows a section by name. A section asks the model
only through its declared capabilities (``needs``; ``lnn_torch.networks.capabilities``: energy, mass
matrix, inverse dynamics, friction...) and its SI accessors; one the model or the scene cannot give
is skipped with its reason (``result["skipped"]``, and the report's last lines), never an error.

The sections, in the report's order (each module's docstring says what its sections measure):

* ``accelerations`` (``evaluation.accelerations``): the relative L2 acceleration error;
* ``rollouts``, ``energy``, ``predictability`` (``evaluation.rollouts``): rollouts from the true
  initial states, the time until the coordinate error exceeds each threshold, the true-energy drift
  (power-balance error with inputs or friction) along them, and the same times for the exact system
  started ``perturbation`` off;
* ``mass_matrix``, ``torques``, ``friction``, ``free_decay`` (``evaluation.structure``): the learned
  mass matrix, inverse dynamics, friction and dissipation against the scene's;
* ``horizons`` (``evaluation.horizons``): open-loop rollouts from many start points;
* ``ood``, ``stability`` (``evaluation.cases``): the scene's out-of-distribution and hard cases.

The sections that need a closed form (energy, predictability, mass matrix, friction, free decay,
stability) are skipped for a measured system, whose recordings are the reference.

Models are anything with ``acceleration(q, qd, params, tau=None, check=False)`` and ``rollout(q0,
qd0, params, dt, num_steps, method, tau=None)`` in SI units (every ``DynamicsModel``;
``lnn_torch.systems.ground_truth.ClosedForm(system)`` for the scene's own dynamics), and ``capabilities`` (a
set of the ``lnn_torch.networks.capabilities`` names; an object without it provides none). Rollouts
of an actuated scene are driven by the recorded inputs, held over each step (zero-order hold). The
exact reference is ``lnn_torch.systems.ground_truth.reference_rollout``.
"""

from __future__ import annotations

from ..data.trajectories import Trajectories
from ..errors import InputError
from ..networks.capabilities import INVERSE_DYNAMICS, capabilities_of, missing
from .metrics import (
    acceleration_errors,
    condition_numbers,
    divergence_time,
    energy_drift,
    normalized_rmse,
    power_balance_error,
    quartiles,
    relative_l2,
    scaled_matrix_error,
)
from .plots import section_figures, torque_figure
from .registry import SECTIONS, EvalContext, SectionResult, report_sections, section, section_logs, skip
from .report import markdown_table, number, pct, quartile_cell, scalar_rows, table_header, table_row, time_cell
from .stability import hard_cases, run_hard_cases, stability_markdown, stability_pivot

# the section modules register their sections on import: the report's order is this order, then the
# order within each module
# isort: off
from . import accelerations, rollouts, structure, horizons, cases, regimes  # noqa: F401 - registers the sections
# isort: on
from .regimes import regime_errors  # noqa: E402

__all__ = [
    "DEFAULT_SECTIONS", "REPORT_SECTIONS", "regime_errors", "SECTIONS", "EvalContext", "SectionResult",
    "evaluate_model",
    "evaluate_split",
    "report_sections", "section", "section_figures", "section_logs", "skip",
    # the metric functions (``metrics``)
    "acceleration_errors", "condition_numbers", "divergence_time", "energy_drift", "normalized_rmse",
    "power_balance_error", "quartiles", "relative_l2", "scaled_matrix_error",
    # the report's cells and Markdown tables (``report``), the figures (``plots``), the hard cases (``stability``)
    "markdown_table", "table_header", "table_row", "scalar_rows", "pct", "number", "time_cell", "quartile_cell",
    "torque_figure", "hard_cases", "run_hard_cases", "stability_markdown", "stability_pivot",
]

DEFAULT_SECTIONS = ("accelerations", "rollouts", "energy")  # what training's validation computes
REPORT_SECTIONS = report_sections()  # accelerations ... stability, in the order registered above


def evaluate_model(model, system, data: Trajectories, *, sections=DEFAULT_SECTIONS, integrator: str = "rk4",
                   dt: float | None = None, horizon: float | None = None, thresholds=(0.1, 0.5),
                   accel_stride: int = 10, num_rollouts: int | None = None, progress=None, **options) -> dict:
    """Evaluate ``model`` on trajectories of ``system`` (SI units).

    Args:
        model: a ``DynamicsModel`` (``module.model``; the ``LNNModule`` that ``load_model`` returns is taken as
            its ``model``), ``ClosedForm(system)`` or any object with the same ``acceleration``/``rollout`` methods;
            a model of another scene's coordinates or parameters is refused in one line.
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
    if hasattr(model, "model") and hasattr(model, "system"):  # what load_model returns: its network evaluates
        model = model.model
    scene = getattr(model, "scene", None)
    if scene is not None and (scene.dof, scene.num_params) != (system.dof, system.num_params):
        raise InputError(f"the model is of scene '{scene.name}' ({scene.dof} coordinates, {scene.num_params} "
                         f"parameters); the data are of '{system.name}' ({system.dof} coordinates, {system.num_params} "
                         "parameters)")
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


def evaluate_split(model, system, data: Trajectories, *, num_rollouts: int = -1, seconds: float = 5.0,
                   threshold: float = 0.1, accel_stride: int = 10) -> dict:
    """The evaluation training runs on a whole validation or test split (``LNNModule``): for a scene
    with a closed form, ``DEFAULT_SECTIONS`` with rollouts of ``num_rollouts`` trajectories over
    ``seconds`` (-1: all; 0: accelerations alone); for measured recordings, the accelerations and
    open-loop horizons (0.1 s, 0.5 s, ``seconds``) from many start points of every recording, and
    the inverse-dynamics torques where the model has them (measured torques are what a real arm's
    model is judged by)."""
    options = dict(thresholds=(threshold,), accel_stride=accel_stride)
    if not system.closed_form:
        torques = ("torques",) if INVERSE_DYNAMICS in capabilities_of(model) else ()
        return evaluate_model(model, system, data, sections=("accelerations", *torques, "horizons"),
                              horizons=(0.1, 0.5, seconds), **options)
    sections = DEFAULT_SECTIONS if num_rollouts != 0 else ("accelerations",)
    return evaluate_model(model, system, data, sections=sections, horizon=seconds,
                          num_rollouts=num_rollouts if num_rollouts > 0 else None, **options)
