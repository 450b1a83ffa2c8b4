"""Classical identification beside a learned model of a robot arm, as identification papers report it:
the joint-torque error per joint in N m on held-out data, for the learned model and for least squares
on the base parameters with the same drive model (ordinary, weighted, and physically consistent:
``lnn_torch.identification.classical_arm``) fitted on the same training data, and for the description as written.

    fits = fit_classical(system, train, drive="viscous+coulomb+offset")
    print(markdown(compare_on_arm(module.model, system, test, fits)))

``train`` and ``test`` are ``Trajectories`` with accelerations (the estimates the model was trained
on: the DataModule's ``targets``), SI units.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np
import torch

from ..data.trajectories import points
from ..evaluation.report import markdown_table
from ..mechanics.integrators import held, rk4_step
from ..networks.calls import counting_failures

METHODS = ("least squares", "weighted least squares", "physically consistent")
# also available to ``fit_classical``: the physically consistent fit with the weighted fit's row weights
WEIGHTED_CONSISTENT = "weighted physically consistent"


def torque_errors(predicted: torch.Tensor, measured: torch.Tensor, names) -> dict:
    """RMS per joint and its mean (N m), and the normalised MSE per joint (the torque's variance as unit)."""
    rms = (predicted - measured).pow(2).mean(0).sqrt()
    nmse = (predicted - measured).pow(2).mean(0) / measured.var(0)
    return {"rms": dict(zip(names, rms.tolist(), strict=True)), "rms_mean": float(rms.mean()),
            "nmse": dict(zip(names, nmse.tolist(), strict=True)), "nmse_mean": float(nmse.mean())}


def arm_chain(system):
    """The kinematic chain of a robot-arm scene's description (``robots.kinematics.SerialChain``)."""
    from ..robots.kinematics import read_chain
    from ..robots.mujoco_arm import load_description

    return read_chain(load_description(system.config().get("description")))


def stacked_points(data, stride: int = 1) -> list[torch.Tensor]:
    """``q, qd, qdd, tau, params`` of ``data`` (``Trajectories``, or a list of them) at every ``stride``-th valid
    point of each trajectory, stacked (``data.points``)."""
    parts = [points(t, stride) for t in (data if isinstance(data, (list, tuple)) else [data])]
    return [torch.cat(column) for column in zip(*parts, strict=True)]


def fit_classical(system, train, *, drive="viscous+coulomb+offset", methods=METHODS, stride: int = 2,
                  prior=None, val=None, chain=None, extend: bool = True, block: int = 1) -> dict:
    """The classical fits ``{label: ArmModel}`` of ``methods`` (of ``METHODS`` and ``WEIGHTED_CONSISTENT``) with
    the drive model ``drive`` on ``train``
    (``Trajectories``, or a list of them fitted together; every ``stride``-th point), each with its fit
    time in ``info["fit_seconds"]``. The physically consistent fit's prior: ``prior`` (a value), or chosen
    among ``prior`` (a sequence; None: ``classical_arm.PRIORS``) on the validation data ``val`` (as
    ``train``) where given, else 0.01, and beyond the sequence's ends where validation prefers an end (``extend``:
    ``classical_arm.consistent_fit``). ``chain``: the kinematic chain to fit (default the scene's
    description's). ``block``: the least-squares fits' standard errors are cluster-robust over blocks of
    this many of the points fitted (after ``stride``; the residuals' correlation time of filtered data)."""
    from ..robots.regressor import payload_torque
    from . import classical_arm as classical

    chain = arm_chain(system) if chain is None else chain
    q, qd, qdd, tau, params = stacked_points(train, stride)
    X = [q, qd, qdd, tau - payload_torque(chain, q, qd, qdd, params)]  # the arm's own torques: payloads are known
    validation = None if val is None else stacked_points(val, stride)
    if prior is None:
        prior = classical.PRIORS if validation is not None else 0.01
    name = classical.DriveModel.of(drive).name
    fits, out = {}, {}
    for method in methods:
        start = time.perf_counter()
        if method in ("physically consistent", WEIGHTED_CONSISTENT):
            weights = None
            if method == WEIGHTED_CONSISTENT:  # each joint's rows divided by its ordinary residual's spread,
                weighted = fits.get("weighted least squares") or classical.least_squares(chain, *X, drive=drive,
                                                                                         weighted=True)
                # scaled to a mean square of one: the weights shape the joints' shares, not the error's size
                # against the prior (noise-free data would otherwise weigh it 1e12 times and stall the solver)
                weights = weighted.weights / np.sqrt(np.mean(np.square(weighted.weights)))
            fits[method] = classical.consistent_fit(chain, *X, drive=drive, weights=weights, prior=prior,
                                                    validation=validation, start=fits.get("least squares"),
                                                    extend=extend)
            fits[method].method = method
        else:
            fits[method] = classical.least_squares(chain, *X, drive=drive, weighted=method.startswith("weighted"),
                                                   block=block)
        fits[method].info["fit_seconds"] = time.perf_counter() - start
        fits[method].info["train_points"] = len(X[0])
        fits[method].info["stride"] = stride
        out[f"{method} + {name}"] = fits[method]
    return out


def description_model(system, description=None):
    """The description as written (or ``description``) as an ``ArmModel``: its rigid body, armature and
    damping (its only friction)."""
    from ..robots.kinematics import read_chain
    from ..robots.mujoco_arm import load_description
    from . import classical_arm as classical

    chain = arm_chain(system) if description is None else read_chain(load_description(description))
    return classical.ArmModel(chain, classical.DriveModel.of("viscous"), "description", {"b": chain.damping.numpy()},
                              pi=classical.description_parameters(chain).numpy())


def open_loop(forward, data, *, every: float = 0.25, limit: float = 1.0, threshold: float = 0.1) -> dict:
    """How long open-loop motion stays within ``threshold`` rad (largest joint error) of the recording,
    driven by the measured torques: from a start every ``every`` s of each trajectory (the recorded state
    there), RK4 steps of the data's ``dt`` with the torque held over each step, for at most ``limit`` s
    (times censored there). ``forward(q, qd, tau, params) -> qdd`` (float64 SI). Returns the quartiles
    of the times (s) and the number of starts."""
    dt = float(data.dt)
    steps, stride = int(round(limit / dt)), max(1, int(round(every / dt)))
    lengths = [data.num_points] * len(data) if data.lengths is None else [int(n) for n in data.lengths]
    starts = [(j, s) for j, n in enumerate(lengths) for s in range(0, n - steps, stride)]
    if not starts:
        return {"quartiles": [float("nan")] * 3, "starts": 0, "limit": limit, "threshold": threshold}
    js, ss = torch.tensor([j for j, _ in starts]), torch.tensor([s for _, s in starts])
    window = ss[:, None] + torch.arange(steps + 1)
    q_true, tau = data.q[js[:, None], window].double(), data.tau[js[:, None], window].double()
    params = data.params[js].double()
    q, qd = q_true[:, 0], data.qd[js, ss].double()
    within = torch.full((len(starts),), float(limit), dtype=torch.float64)
    alive = torch.ones(len(starts), dtype=torch.bool)

    def accel(q, qd, p, u):
        return forward(q, qd, u, p)

    with torch.no_grad():
        for k in range(steps):
            q, qd = rk4_step(held(accel, tau[:, k]), q, qd, params, dt)
            error = (q - q_true[:, k + 1]).abs().amax(-1)
            left = alive & ~(error <= threshold)  # NaN leaves too
            within[left] = k * dt
            alive &= ~left
            if not alive.any():
                break
    quartiles = torch.quantile(within, torch.tensor([0.25, 0.5, 0.75], dtype=torch.float64)).tolist()
    return {"quartiles": quartiles, "starts": len(starts), "limit": limit, "threshold": threshold}


def model_forward(model):
    """A learned model's forward dynamics in the form ``open_loop`` takes (float64 in and out)."""
    def forward(q, qd, tau, params):
        dtype = model.dtype
        return model.forward(q.to(dtype), qd.to(dtype), params.to(dtype), tau.to(dtype),
                                         check=False).double()
    return forward


def compare_on_arm(model, system, data, fits: dict, descriptions: dict | None = None,
                   open_loop_limit: float | None = None, model_params: torch.Tensor | None = None) -> dict:
    """Torque errors (``torque_errors``) on ``data`` of ``model`` (its inverse dynamics; None: left out),
    of the classical ``fits`` (``fit_classical``) and of ``descriptions`` (``{label: ArmModel}``; default:
    the scene's description as written); with ``open_loop_limit`` (s) each row's ``open_loop`` times
    too (``open_loop``: driven by the measured torques, censored at that limit). ``model_params``: the model's
    own parameters per trajectory ``(B, P)`` in place of ``data``'s (loads identified against it)."""
    names = list(system.coord_names)
    q, qd, qdd, tau, params = points(data)
    rows = {}

    def with_open_loop(row, forward, data=data):
        if open_loop_limit is not None:
            row["open_loop"] = open_loop(forward, data, limit=open_loop_limit)
        return row

    if model is not None:
        own = data if model_params is None else replace(data, params=model_params)
        pred = model_torque(model)(q, qd, qdd, params if model_params is None else points(own)[4])
        with torch.no_grad(), counting_failures(model):
            rows[getattr(model, "variant", "model")] = with_open_loop(torque_errors(pred, tau, names),
                                                                      model_forward(model), own)
    for label, fit in fits.items():
        rows[label] = with_open_loop({**torque_errors(fit.inverse(q, qd, qdd, params), tau, names),
                                      "fit_seconds": fit.info.get("fit_seconds")},
                                     lambda q, qd, u, p, fit=fit: fit.forward(q, qd, u, p))
    for label, fit in (descriptions if descriptions is not None
                       else {"description as written": description_model(system)}).items():
        rows[label] = with_open_loop(torque_errors(fit.inverse(q, qd, qdd, params), tau, names),
                                     lambda q, qd, u, p, fit=fit: fit.forward(q, qd, u, p))
    train_points = next((f.info.get("train_points") for f in fits.values()), None)
    stride = next((f.info.get("stride") for f in fits.values()), None)
    return {"joints": names, "test_points": len(q), "train_points": train_points, "train_stride": stride, "rows": rows,
            "fits": {k: v.report() for k, v in fits.items()},
            "torque_std": dict(zip(names, tau.std(0).tolist(), strict=True))}


def per_recording(model, system, data, fits: dict, names, model_params: torch.Tensor | None = None) -> dict:
    """``{name: {label: mean joint-torque RMS (N m)}}``: ``compare_on_arm``'s means on each trajectory of ``data``
    alone (``names``: one per trajectory, e.g. the dataset's recordings), the description as written included
    (``model_params`` as ``compare_on_arm``'s)."""
    return {name: {label: row["rms_mean"] for label, row in
                   compare_on_arm(model, system, data.entry(j), fits,
                                  model_params=None if model_params is None else model_params[j:j + 1])["rows"].items()}
            for j, name in enumerate(names)}


def per_recording_markdown(table: dict) -> str:
    """The per-recording table: one row per recording, each model's mean joint-torque RMS, the lowest in bold (every
    one that prints as the lowest: ties at the printed precision alike)."""
    labels = list(next(iter(table.values())))
    rows = []
    for name, errors in table.items():
        best = min((e for e in errors.values() if math.isfinite(e)), default=None)
        shown = {k: f"{errors[k]:.3f}" for k in labels}
        lowest = None if best is None else f"{best:.3f}"
        rows.append([name, *(f"**{shown[k]}**" if shown[k] == lowest else shown[k] for k in labels)])
    return markdown_table(["recording", *labels], rows)


def model_torque(model):
    """``(q, qd, qdd, params) -> torque`` (float64, N m) of a model's inverse dynamics, without gradients
    (NaN where a model's accelerations are undefined: ``counting_failures``)."""
    def torque(q, qd, qdd, params):
        with torch.no_grad(), counting_failures(model):
            return model.inverse(*(x.to(model.dtype) for x in (q, qd, qdd, params))).double()
    return torque


def classical_torque(fit):
    """``(q, qd, qdd, params) -> torque`` of a classical fit (``ArmModel``; the parameters: the payload each
    point carries at the flange, known)."""
    return lambda q, qd, qdd, params: fit.inverse(q, qd, qdd, params)


def feedback_band(datamodule, split: str) -> torch.Tensor:
    """``velocity_feedback.band`` at the valid points of a split of a ``TrajectoryDataModule`` with estimated
    targets, flattened like ``points``: the recorded velocity less the targets' smoothed one ``(N, dof)``."""
    from . import velocity_feedback

    data = datamodule.trajectories(split)
    recorded = replace(data, qd=datamodule.recorded_velocities(split))
    return velocity_feedback.band(points(recorded)[1], points(data)[1])


def feedback_rows(datamodule, predictors: dict, names, split: str = "test", split_params: dict | None = None) -> dict:
    """Rows ``LABEL + velocity feedback`` (``torque_errors`` on ``split``, with ``val_rms_mean`` and the
    ``feedback`` gains): each predictor ``(q, qd, qdd, params) -> torque`` (``model_torque``,
    ``classical_torque``) with the robot's feedback on its measured velocity
    (``lnn_torch.identification.velocity_feedback``)
    fitted on its training-split error and kept where the validation split prefers it (so a row's
    ``val_rms_mean`` is on the split that chose its gains). No open loop: the feedback is not a force of
    the state. Needs estimated targets and recorded velocities. ``split_params``: ``{label: (B, P)}``, the
    parameters per trajectory of ``split`` that predictor runs with there in place of the dataset's (a model's
    loads identified against it, as ``compare_on_arm``'s ``model_params``)."""
    from . import velocity_feedback

    # the recorded torques (never smoothed: the band the gains are fitted to is above the smoothing)
    data = {s: datamodule.trajectories(s, smooth_inputs=False) for s in dict.fromkeys(("train", "val", split))}
    splits = {s: points(d) for s, d in data.items()}
    bands = {s: feedback_band(datamodule, s) for s in splits}
    rows = {}
    for label, torque in predictors.items():
        own = (split_params or {}).get(label)
        error = {s: tau - torque(q, qd, qdd, p if own is None or s != split else
                                 points(replace(data[s], params=own))[4])
                 for s, (q, qd, qdd, tau, p) in splits.items()}
        fb = velocity_feedback.fit(error["train"], bands["train"], error["val"], bands["val"])
        tau = splits[split][3]
        row = torque_errors(tau - error[split] + fb.torque(bands[split]), tau, names)
        row["val_rms_mean"] = sum(fb.val_rms_after) / len(fb.val_rms_after)
        row["feedback"] = fb.report()
        rows[f"{label} + velocity feedback"] = row
    return rows


def markdown(result: dict) -> str:
    """The held-out table: one row per model, RMS per joint and the mean in N m."""
    names = result["joints"]
    header = ["model", *names, "mean (N m)"]
    rows = [[name, *(f"{r['rms'][n]:.2f}" for n in names), f"{r['rms_mean']:.3f}"]
            for name, r in result["rows"].items()]
    rows.append(["torque std of the data", *(f"{result['torque_std'][n]:.2f}" for n in names), ""])
    return markdown_table(header, rows)


def _never_moving(uncertainty: dict) -> str:
    """The clause naming which undetermined parameters no motion of the arm moves (more excitation cannot
    determine them) and which only these recordings leave out (older reports: nothing)."""
    never = uncertainty.get("never_moving")
    if never is None or not uncertainty["undetermined"]:
        return ""
    others = [k for k in uncertainty["undetermined"] if k not in set(never)]
    if not others:
        return " (no motion of this arm moves any of them: no recording can determine them)"
    if not never:
        return " (motions these recordings lack would move them)"
    return (f" ({len(never)} of them no motion of this arm moves, no recording can determine them; motions these "
            f"recordings lack would move {', '.join(others)})")


def uncertainty_markdown(uncertainty: dict, worst: int = 8) -> str:
    """What the recordings determine (``classical_arm.least_squares``' ``info["uncertainty"]``): the
    excitation, how many coefficients are determined to 10 % (relative standard error), the least
    determined ones with their 95 % intervals, and the parameters determined only in combination or not
    at all."""
    value, std = np.asarray(uncertainty["value"]), np.asarray(uncertainty["std"])
    relative = std / np.maximum(np.abs(value), 1e-12)
    order = np.argsort(-relative)[:worst]
    rows = [[uncertainty["names"][k], f"{value[k]:.4g}", f"{std[k]:.2g}",
             f"[{uncertainty['interval95'][k][0]:.4g}, {uncertainty['interval95'][k][1]:.4g}]"] for k in order]
    lines = [f"Excitation: condition number {uncertainty['condition_number']:.3g} of the scaled regressor; "
             f"{int((relative < 0.1).sum())} of {len(value)} coefficients (base parameters and friction) determined "
             f"to 10 % (standard errors cluster-robust over {uncertainty['block_samples']}-sample blocks). The least "
             "determined:", "", markdown_table(["coefficient", "value", "std", "95 % interval"], rows), "",
             f"Determined only in combination with others: {len(uncertainty['in_combination'])} parameters; not at "
             f"all (they move no torque on these recordings, the description's values stand): "
             f"{', '.join(uncertainty['undetermined']) or 'none'}"
             + _never_moving(uncertainty) + "."]
    return "\n".join(lines)
