"""Classical identification beside a learned model of a robot arm, as identification papers report it:
the joint-torque error per joint in N m on held-out data, for the learned model and for least squares
on the base parameters with the same drive model (ordinary, weighted, and physically consistent:
``lnn_torch.robots.classical``) fitted on the same training data, and for the description as written.

    result = compare_on_arm(module.model, system, train, test, drive="viscous+coulomb+offset")
    print(markdown(result))

``train`` and ``test`` are ``Trajectories`` with accelerations (the estimates the model was trained
on: the DataModule's ``targets``), SI units.
"""

from __future__ import annotations

import time

import torch

from .networks.calls import counting_failures
from .report import markdown_table

METHODS = ("least squares", "weighted least squares", "physically consistent")


def points(data, stride: int = 1) -> list[torch.Tensor]:
    """``q, qd, qdd, tau, params`` at the valid points of every trajectory (every ``stride``-th), float64."""
    out = {k: [] for k in ("q", "qd", "qdd", "tau", "params")}
    lengths = [data.num_points] * len(data) if data.lengths is None else [int(n) for n in data.lengths]
    for j, n in enumerate(lengths):
        for k in ("q", "qd", "qdd", "tau"):
            out[k].append(getattr(data, k)[j, :n:stride].double())
        out["params"].append(data.params[j].double().expand(len(out["q"][-1]), -1))
    return [torch.cat(v) for v in out.values()]


def torque_errors(predicted: torch.Tensor, measured: torch.Tensor, names) -> dict:
    """RMS per joint and its mean (N m), and the normalised MSE per joint (the torque's variance as unit)."""
    rms = (predicted - measured).pow(2).mean(0).sqrt()
    nmse = (predicted - measured).pow(2).mean(0) / measured.var(0)
    return {"rms": dict(zip(names, rms.tolist(), strict=True)), "rms_mean": float(rms.mean()),
            "nmse": dict(zip(names, nmse.tolist(), strict=True)), "nmse_mean": float(nmse.mean())}


def compare_on_arm(model, system, train, test, *, drive="viscous+coulomb+offset", methods=METHODS,
                   train_stride: int = 2, prior: float = 0.01) -> dict:
    """Held-out torque errors (``torque_errors``) of ``model`` (its inverse dynamics, ``None`` to leave
    it out) and of the classical fits on ``train`` (every ``train_stride``-th point), with the time
    each fit took; and the description as written (its rigid body without friction)."""
    from .robots import classical
    from .robots.kinematics import read_chain
    from .robots.mujoco_arm import load_description

    description = system.config().get("description")
    chain = read_chain(load_description(description))
    names = list(system.coord_names)
    q, qd, qdd, tau, params = points(test)
    rows = {}
    if model is not None:
        with torch.no_grad(), counting_failures(model):
            pred = model.inverse_dynamics(q.to(model.dtype), qd.to(model.dtype), qdd.to(model.dtype),
                                          params.to(model.dtype)).double()
        rows[getattr(model, "variant", "model")] = {**torque_errors(pred, tau, names), "fit_seconds": None}
    Xtr = points(train, train_stride)[:4]
    fits = {}
    for method in methods:
        start = time.perf_counter()
        if method == "physically consistent":
            fits[method] = classical.consistent_fit(chain, *Xtr, drive=drive, prior=prior,
                                                    start=fits.get("least squares"))
        else:
            fits[method] = classical.least_squares(chain, *Xtr, drive=drive, weighted=method.startswith("weighted"))
        seconds = time.perf_counter() - start
        rows[f"{method} + {classical.DriveModel.of(drive).name}"] = {
            **torque_errors(fits[method].torque(q, qd, qdd), tau, names), "fit_seconds": seconds}
    as_written = classical.ArmModel(chain, classical.DriveModel.of("viscous"), "description",
                                    {"b": chain.damping.numpy()},
                                    pi=classical.description_parameters(chain).numpy())
    rows["description as written"] = {**torque_errors(as_written.torque(q, qd, qdd), tau, names), "fit_seconds": None}
    return {"joints": names, "test_points": len(q), "train_points": len(Xtr[0]), "drive": classical.DriveModel.of(
        drive).name, "rows": rows, "fits": {k: v.report() for k, v in fits.items()},
        "torque_std": dict(zip(names, tau.std(0).tolist(), strict=True))}


def markdown(result: dict) -> str:
    """The held-out table: one row per model, RMS per joint and the mean in N m."""
    names = result["joints"]
    header = ["model", *names, "mean (N m)"]
    rows = [[name, *(f"{r['rms'][n]:.2f}" for n in names), f"{r['rms_mean']:.3f}"]
            for name, r in result["rows"].items()]
    rows.append(["torque std of the data", *(f"{result['torque_std'][n]:.2f}" for n in names), ""])
    return markdown_table(header, rows)
