"""Matplotlib figures (headless): the figures the evaluation sections present (trajectories, energy,
error growth, friction, free decay, frames), and their assembly for the writers: ``section_figures``
(titled builders by PNG name or logger tag, for ``lnn-torch evaluate`` and training's TensorBoard
logging) and ``evaluation_plots`` (the PNG files).

matplotlib is imported at the first figure drawn, not with this module: the evaluation sections name
their figures here, and a user who draws none (training without a logger, the physics) never loads it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path

import torch

from .metrics import coordinate_error


@functools.cache
def _pyplot():
    """``matplotlib.pyplot`` on the headless Agg backend, imported at the first figure (matplotlib
    is heavy and optional for the physics: imported in the function)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def __getattr__(name: str):
    """``plots.plt``: pyplot on the Agg backend, imported when first asked for (``from lnn_torch.evaluation.plots
    import plt``, as ``lnn-torch simulate`` draws its figure)."""
    if name == "plt":
        return _pyplot()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def trajectory_figure(q_true: torch.Tensor, q_pred: torch.Tensor, dt: float, names, units=None):
    """Predicted vs true coordinates of one trajectory: ``(T, dof)`` each; ``units`` per coordinate."""
    plt = _pyplot()
    t = torch.arange(q_true.shape[0]) * dt
    units = units or [""] * len(names)
    fig, axes = plt.subplots(q_true.shape[1], 1, figsize=(7, 2.2 * q_true.shape[1]), sharex=True, squeeze=False)
    for i, ax in enumerate(axes[:, 0]):
        ax.plot(t, q_true[:, i], "k-", lw=1.5, label="true")
        ax.plot(t, q_pred[: len(t), i], "C1--", lw=1.2, label="model")
        ax.set_ylabel(f"{names[i]} [{units[i]}]" if units[i] else names[i])
    axes[0, 0].legend(loc="upper right")
    axes[0, 0].set_title("the first trajectory: model rollout from its true initial state", fontsize=9)
    axes[-1, 0].set_xlabel("t [s]")
    fig.tight_layout()
    return fig


def frames_figure(system, q_true: torch.Tensor, q_model: torch.Tensor, params: torch.Tensor, dt: float,
                  num_frames: int = 6, title: str | None = None):
    """Snapshots of one trajectory, true against model: ``q (T, dof)``, ``params (P,)``. The bodies
    (``System.positions``, any number of links) are drawn as a chain from the origin. None for a
    scene that is not drawn."""
    plt = _pyplot()
    T = q_true.shape[0]
    frames = [int(i) for i in torch.linspace(0, T - 1, num_frames)]
    params = params[None].expand(T, -1)
    xy_true, xy_model = system.positions(q_true, params), system.positions(q_model, params)
    if xy_true is None:
        return None
    finite = torch.isfinite(xy_model)
    reach = 1.1 * float(torch.cat([xy_true.abs().flatten(), xy_model[finite].abs().flatten()]).max())
    fig, axes = plt.subplots(1, num_frames, figsize=(2.2 * num_frames, 2.6))
    for ax, k in zip(axes, frames, strict=True):
        for xy, style, label in ((xy_true[k], "k-o", "true"), (xy_model[k], "C1--o", "model")):
            chain = torch.cat([torch.zeros(1, 2, dtype=xy.dtype), xy])  # from the origin through every body
            ax.plot(chain[:, 0], chain[:, 1], style, ms=4, label=label)
        ax.set_xlim(-reach, reach)
        ax.set_ylim(-reach, reach)
        ax.set_aspect("equal")
        ax.set_title(f"t = {k * dt:.1f} s", fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    axes[0].legend(fontsize=7, loc="upper left")
    if title:
        fig.supxlabel(title, fontsize=9)
    fig.tight_layout()
    return fig


def _solid_and_dashed(ax, x, true, model, curves: int = 6) -> None:
    """The first ``curves`` rows of ``true`` (solid) and ``model`` (dashed, the same colour) against ``x``."""
    for b in range(min(curves, true.shape[0])):
        line = ax.plot(x, true[b], "-", lw=1.4)[0]
        ax.plot(x, model[b], "--", lw=1.2, color=line.get_color())


def drift_figure(drift: torch.Tensor, dt: float, forces: bool):
    """Median and max over rollouts ``(B, T)`` of the true-energy drift (power-balance error with forces)."""
    plt = _pyplot()
    t = torch.arange(drift.shape[1]) * dt
    fig, ax = plt.subplots(figsize=(7, 2.8))
    ax.plot(t, drift.median(0).values, label="median")
    ax.plot(t, drift.amax(0), label="max")
    ax.set_title(f"{'power-balance error' if forces else 'true-energy drift'} of {drift.shape[0]} model rollouts",
                 fontsize=9)
    ax.set_yscale("log")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("|E(t)-E(0)-W(t)| / (Vmax-Vmin)" if forces else "|E(t)-E(0)| / (Vmax-Vmin)")
    ax.legend()
    fig.tight_layout()
    return fig


def error_growth_figure(q_true, q_model, q_exact, dt: float, angle_mask, perturbation: float = 1e-6,
                        unit: str = "rad"):
    """Median coordinate error over rollouts ``(B, T, dof)`` against time, with the exact system
    started ``perturbation`` off (``q_exact``, or None) for the predictability limit."""
    plt = _pyplot()
    t = torch.arange(q_true.shape[1]) * dt

    def err(q):
        return coordinate_error(q, q_true, angle_mask).median(0).values.clamp_min(1e-16)

    fig, ax = plt.subplots(figsize=(7, 2.8))
    ax.plot(t, err(q_model), label="model")
    if q_exact is not None:
        ax.plot(t, err(q_exact), label=f"exact system, {perturbation:g} off")
    ax.axhline(0.1, color="k", lw=0.8, ls=":", label=f"0.1 {unit}")
    ax.set_yscale("log")
    ax.set_title(f"error growth, median over {q_true.shape[0]} rollouts", fontsize=9)
    ax.set_xlabel("t [s]")
    ax.set_ylabel(f"max |coordinate error| [{unit}]")
    ax.legend()
    fig.tight_layout()
    return fig


def friction_figure(fa: dict):
    """True (solid) and learned (dashed) friction torque against each joint's rate: ``fa`` holds
    ``rates (R,)``, ``true`` and ``learned`` ``(B, R, n_j)``."""
    plt = _pyplot()
    n_j = fa["true"].shape[-1]
    fig, axes = plt.subplots(1, n_j, figsize=(4.2 * n_j, 3.2), squeeze=False)
    for j, ax in enumerate(axes[0]):
        _solid_and_dashed(ax, fa["rates"], fa["true"][..., j], fa["learned"][..., j])
        ax.set_xlabel(f"joint {j + 1} rate [rad/s]")
        ax.set_ylabel("friction torque [N m]")
        ax.set_title("true (solid) and learned (dashed)", fontsize=9)
    fig.tight_layout()
    return fig


def torque_figure(ta: dict):
    """Measured (solid) and predicted (dashed) input torques of one trajectory against time, one panel
    per input: ``ta`` holds ``t (T,)``, ``measured`` and ``predicted`` ``(T, n_u)`` (N m), ``names``."""
    plt = _pyplot()
    n_u = ta["measured"].shape[-1]
    cols = 2 if n_u > 3 else 1
    rows = -(-n_u // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(6.5 * cols, 1.9 * rows + 0.6), sharex=True, squeeze=False)
    for j, ax in enumerate(axes.flat):
        if j >= n_u:
            ax.set_visible(False)
            continue
        ax.plot(ta["t"], ta["measured"][:, j], "k-", lw=1.0, label="measured")
        ax.plot(ta["t"], ta["predicted"][:, j], "C1--", lw=1.0, label="model (inverse dynamics)")
        ax.set_ylabel(f"{ta['names'][j]} [{(ta.get('units') or ['N m'] * n_u)[j]}]")
    axes.flat[0].legend(loc="upper right", fontsize=8)
    axes.flat[0].set_title("the first trajectory: measured and predicted torques", fontsize=9)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    fig.tight_layout()
    return fig


def decay_figure(da: dict):
    """Free decay: the true energy (solid) and the model's own (dashed), ``E_true``, ``E_model (B, T)``."""
    plt = _pyplot()
    t_d = torch.arange(da["E_true"].shape[1]) * da["dt"]
    fig, ax = plt.subplots(figsize=(7, 2.8))
    _solid_and_dashed(ax, t_d, da["E_true"], da["E_model"])
    ax.set_xlabel("t [s]")
    ax.set_ylabel("E(t) - E(0) [J]")
    ax.set_title("free decay, inputs off: true energy (solid), the model's own (dashed)", fontsize=9)
    fig.tight_layout()
    return fig


def section_figures(result: dict, tags: bool = False, case: str | None = None) -> dict[str, Callable[[dict], object]]:
    """PNG name (with ``tags``: the figure's logger tag) -> figure builder ``fn(result)`` over the
    computed sections of ``result`` (``lnn_torch.evaluation.evaluate_model``: each section's
    ``SectionResult.figures`` and ``tags``). Each figure is titled with the model, the scene and
    ``case`` (e.g. "test split"); its own axes say what it shows."""
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


def evaluation_plots(result: dict, output_dir, system=None) -> list:
    """Every figure the computed sections of ``result`` (``lnn_torch.evaluation.evaluate_model``)
    present, saved as PNG in ``output_dir`` (a section's figure may be None: not drawn for this
    scene). Returns the PNG paths. ``system`` is not needed (the sections know their scene); kept
    for callers."""
    output_dir = Path(output_dir)
    paths = []
    split = result.get("split")
    for name, build in section_figures(result, case=f"{split} split" if split else None).items():
        fig = build(result)
        if fig is None:
            continue
        paths.append(output_dir / name)
        fig.savefig(paths[-1], dpi=110)
        _pyplot().close(fig)
    return paths
