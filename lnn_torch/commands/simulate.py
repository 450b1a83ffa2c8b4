"""``lnn-torch simulate``: roll a trained model out from a given state and parameters.

Writes the trajectory (CSV or HDF5, by the output's suffix) and a plot. By default the scene's
exact trajectory from the same state (``lnn_torch.systems.ground_truth.reference_rollout``) is written
beside it, with the true energy of the model's trajectory, so that the output shows how far the
model can be trusted.

    lnn-torch simulate pretrained:double_pendulum --params 1.0 0.6 1.2 1.1 --q0 1.0 -0.5 --duration 10 -o sim.csv
    lnn-torch simulate lightning_logs/version_0/checkpoints/last.ckpt --params ... --q0 ...

An actuated scene's model is driven by inputs: ``--inputs FILE.csv`` (a column per input, named as
the scene's inputs, e.g. ``tau1,tau2``, and optionally ``t``: the inputs are held from each row's
time to the next, zero-order) or a named excitation ``--excitation JSON`` (``lnn_torch.systems.excitation``,
e.g. ``'{"kind": "multisine", "amplitude": [1.0, 0.5]}'``; ``'{"kind": "none"}'`` for free motion).
The true-energy drift is then the power-balance error |E(t) - E(0) - W(t)|.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from ..mechanics.integrators import METHODS
from .parser import CommandParser


def _parser() -> argparse.ArgumentParser:
    from ..pretrained import available

    ap = CommandParser(prog="lnn-torch simulate", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", nargs="?", default=None, metavar="CHECKPOINT",
                    help="a .ckpt written by lnn-torch fit, or pretrained:NAME for a shipped model "
                         f"({', '.join(available()) or 'none'}; default pretrained:double_pendulum)")
    ap.add_argument("--pretrained", default=None, help=argparse.SUPPRESS)  # deprecated: CHECKPOINT
    ap.add_argument("--checkpoint", dest="checkpoint_option", default=None, help=argparse.SUPPRESS)  # deprecated
    ap.add_argument("--params", type=float, nargs="*", default=[],
                    help="physical parameters, SI, scene order (none for a scene without parameters)")
    ap.add_argument("--q0", type=float, nargs="+", required=True, help="initial coordinates (rad or m)")
    ap.add_argument("--qd0", type=float, nargs="+", default=None, help="initial velocities (default 0)")
    ap.add_argument("--duration", type=float, default=10.0, help="seconds")
    ap.add_argument("--dt", type=float, default=0.005, help="output and integration step, s")
    ap.add_argument("--integrator", default=None, choices=sorted(METHODS), help="default rk4")
    ap.add_argument("--method", default=None, choices=sorted(METHODS), help=argparse.SUPPRESS)  # deprecated
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    ap.add_argument("--output", "-o", default="simulation.csv", help="trajectory file: .csv or .h5")
    ap.add_argument("--plot", default=None, help="plot file (default: the output with .png)")
    ap.add_argument("--no-exact", action="store_true", help="skip the closed-form reference trajectory")
    ap.add_argument("--overwrite", action="store_true", help="replace existing output files")
    ap.add_argument("--compile", action="store_true",
                    help="accelerations through torch.compile (pays off for long rollouts; falls back to eager)")
    inputs = ap.add_mutually_exclusive_group()
    inputs.add_argument("--inputs", default=None, metavar="CSV",
                        help="inputs of an actuated scene: a column per input (and optionally t, in s), held "
                        "zero-order")
    inputs.add_argument("--excitation", default=None, metavar="JSON",
                        help="inputs of an actuated scene from a named excitation (lnn_torch.systems.excitation)")
    ap.add_argument("--seed", type=int, default=0, help="seed of --excitation")
    return ap


def read_inputs(path: str | Path, names, t: np.ndarray) -> np.ndarray:
    """Inputs ``(len(t), n_u)`` from a CSV with a column per input name and optionally ``t`` (s): the
    value of the last row at or before each time (zero-order hold; without ``t`` the rows are taken
    at the simulation's steps). One clear error naming the file and the column or row."""
    import csv

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"inputs file {path} does not exist")
    with path.open(newline="") as fh:
        rows = list(csv.reader(line for line in fh if line.strip() and not line.startswith("#")))
    if len(rows) < 2:
        raise ValueError(f"{path}: no input rows (a header and one row per step or time)")
    header = [h.strip() for h in rows[0]]
    missing = [n for n in names if n not in header]
    if missing:
        raise ValueError(f"{path}: missing input column(s) {', '.join(missing)} (columns: {', '.join(header)})")
    cols = [header.index(n) for n in (["t"] if "t" in header else []) + list(names)]
    values = np.empty((len(rows) - 1, len(cols)))
    for i, row in enumerate(rows[1:]):
        try:
            values[i] = [float(row[c]) for c in cols]
        except (ValueError, IndexError):
            raise ValueError(f"{path}: row {i + 2} is malformed: {','.join(row)!r}") from None
        if not np.isfinite(values[i]).all():
            raise ValueError(f"{path}: row {i + 2} has a NaN or Inf")
    if "t" not in header:
        if len(values) < len(t):
            raise ValueError(f"{path}: {len(values)} rows of inputs, but the simulation needs {len(t)} (one per step)")
        return values[: len(t)]
    times, u = values[:, 0], values[:, 1:]
    span, step = t[-1] - t[0], (t[1] - t[0] if len(t) > 1 else 0.0)
    # a time column in ms (every row 1000 times later: rows past the end dropped, one row held throughout)
    if len(times) > 1 and span > 0 and times[-1] - times[0] > 100 * span and np.median(np.diff(times)) > 100 * step:
        raise ValueError(f"{path}: column t runs over {times[-1] - times[0]:g} s in steps of "
                         f"{np.median(np.diff(times)):g}, the simulation over {span:g} s in steps of {step:g}: t is in "
                         "seconds (a column in ms?)")
    if (np.diff(times) <= 0).any():
        raise ValueError(f"{path}: column t does not increase at row {int(np.nonzero(np.diff(times) <= 0)[0][0]) + 3}")
    # each row's inputs hold until the next row's time, the last row's for one of the file's intervals
    held = times[-1] + (float(np.median(np.diff(times))) if len(times) > 1 else 0.0)
    if times[0] > t[0] + 1e-12 or held < t[-1] - 1e-12:
        raise ValueError(f"{path}: t covers [{times[0]:g}, {times[-1]:g}] s (its last row held to {held:g} s), the "
                         f"simulation's steps start in [{t[0]:g}, {t[-1]:g}] s")
    return u[np.searchsorted(times, t + 1e-12, side="right") - 1]


def simulate_model(model, params, q0, qd0, duration: float, dt: float, method: str = "rk4", exact: bool = True,
                   tau=None) -> dict:
    """Roll ``model`` (an ``LNNModule``) out from one state (float64), driven by the inputs ``tau
    (steps, n_u)`` of an actuated scene (held over each step). Returns numpy arrays: ``t``, ``q``,
    ``qd`` ``(T, dof)``, the true energy and its drift (power-balance error, with forces) along the
    model's trajectory, and (``exact``) the exact trajectory ``q_exact``
    (``lnn_torch.systems.ground_truth.reference_rollout``)."""
    from ..evaluation.metrics import power_balance_error
    from ..systems.ground_truth import reference_rollout

    system = model.system
    params = torch.tensor([params], dtype=torch.float64)
    q0 = torch.tensor([q0], dtype=torch.float64)
    qd0 = torch.tensor([qd0], dtype=torch.float64)
    for name, x, n in (("params", params, system.num_params), ("q0", q0, system.dof), ("qd0", qd0, system.dof)):
        if x.shape[-1] != n:
            expected = system.param_names if name == "params" else system.coord_names
            raise ValueError(f"{name} needs {n} values ({', '.join(expected)}), got {x.shape[-1]}")
    if not (dt > 0 and duration >= dt):
        raise ValueError(f"need dt > 0 and duration >= dt, got dt={dt}, duration={duration}")
    steps = int(round(duration / dt))
    if tau is not None:
        tau = torch.as_tensor(np.asarray(tau)[:steps], dtype=torch.float64)[None]
        if tau.shape[1:] != (steps, system.num_inputs):
            raise ValueError(f"inputs must be ({steps}, {system.num_inputs}) for {steps} steps, "
                             f"got {tuple(tau.shape[1:])}")
    with torch.no_grad():
        q, qd = model.rollout(q0, qd0, params, dt, steps, method, tau=tau)
        out = {"t": np.arange(steps + 1) * dt, "q": q[0].numpy(), "qd": qd[0].numpy()}
        if system.closed_form:  # a measured system has no true energy: its recordings are the reference
            out["energy"] = system.energy(q, qd, params[:, None].expand(-1, steps + 1, -1))[0].numpy()
            out["energy_drift"] = power_balance_error(system, q, qd, params, tau, dt)[0].numpy()
    if tau is not None:
        out["tau"] = np.concatenate([tau[0].numpy(), tau[0, -1:].numpy()])  # the last row repeats (held)
    if exact and system.closed_form:
        out["q_exact"] = reference_rollout(system, q0, qd0, params, dt, steps, tau=tau)[0][0].numpy()
    return out


def write_trajectory(path: Path, result: dict, system, meta: dict, overwrite: bool) -> Path:
    from ..data.hdf5 import check_writable, write_arrays

    if path.suffix in (".h5", ".hdf5"):
        return write_arrays(path, result, {"scene": system.name, "conventions": system.conventions,
                                           "coord_names": json.dumps(list(system.coord_names)),
                                           "meta": json.dumps(meta)}, overwrite=overwrite)
    path = check_writable(path, overwrite)
    names = list(system.coord_names)
    cols = ["t"] + names + [f"{n}_dot" for n in names]
    data = [result["t"][:, None], result["q"], result["qd"]]
    if "q_exact" in result:
        cols += [f"{n}_exact" for n in names]
        data.append(result["q_exact"])
    if "tau" in result:
        cols += list(system.input_names)
        data.append(result["tau"])
    if "energy" in result:
        cols += ["energy", "energy_drift"]
        data += [result["energy"][:, None], result["energy_drift"][:, None]]
    units = ", ".join(f"{n} [{u}]" for n, u in zip(names, system.coord_units, strict=True))
    described = [f"t [s], {units}, their time derivatives"]
    if "q_exact" in result:
        described.append("*_exact: the closed-form trajectory")
    if "tau" in result:
        described.append(f"{', '.join(system.input_names)}: the inputs held over each step")
    if "energy" in result:
        described.append("energy: the scene's true energy of the model's trajectory [J]; energy_drift: |E(t) - E(0) - "
                         "W(t)| / (V_max - V_min) (W the true work of inputs and friction; 0 for a conservative scene)")
    header = (f"lnn-torch simulate: {json.dumps(meta)}\nscene {system.name}: {system.conventions}\n"
              f"columns: {'; '.join(described)}")
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as fh:  # comment lines ("# "), then a plain header row that CSV readers take
        fh.write("".join(f"# {line}\n" for line in header.splitlines()) + ",".join(cols) + "\n")
        np.savetxt(fh, np.concatenate(data, axis=1), delimiter=",", fmt="%.10g")
    return path


def plot_trajectory(path: Path, result: dict, system) -> Path:
    from ..evaluation.plots import plt

    names = system.coord_names
    rows = system.dof + ("energy_drift" in result)
    fig, axes = plt.subplots(rows, 1, figsize=(7, 1.9 * rows), sharex=True, squeeze=False)
    axes = axes[:, 0]
    for i, ax in enumerate(axes[:system.dof]):
        if "q_exact" in result:
            ax.plot(result["t"], result["q_exact"][:, i], "k-", lw=1.4, label="exact")
        ax.plot(result["t"], result["q"][:, i], "C1--", lw=1.2, label="model")
        ax.set_ylabel(f"{names[i]} [{system.coord_units[i]}]")
    axes[0].legend(loc="upper right", fontsize=8)
    if "energy_drift" in result:
        axes[-1].semilogy(result["t"], np.maximum(result["energy_drift"], 1e-16), "C0")
        axes[-1].set_ylabel("power-balance error" if system.has_forces else "energy drift")
    axes[-1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def model_source(args) -> str:
    """The model to load: ``CHECKPOINT``, or the deprecated ``--checkpoint`` / ``--pretrained`` (with a
    note on stderr), or the shipped double pendulum."""
    import sys

    given = [x for x in (args.checkpoint, args.checkpoint_option, args.pretrained and f"pretrained:{args.pretrained}")
             if x]
    if len(given) > 1:
        raise ValueError("give the model once: CHECKPOINT (a path or pretrained:NAME)")
    if args.checkpoint_option or args.pretrained:
        print("lnn-torch simulate: --checkpoint PATH and --pretrained NAME are deprecated; give the model as the "
              "first argument (PATH or pretrained:NAME)", file=sys.stderr)
    return given[0] if given else "pretrained:double_pendulum"


def main(argv: list[str]) -> int:
    import sys

    args = _parser().parse_args(argv)
    if args.method is not None:
        print("lnn-torch simulate: --method is deprecated; use --integrator", file=sys.stderr)
    integrator = args.integrator or args.method or "rk4"
    torch.set_num_threads(args.threads)
    source = model_source(args)
    output = Path(args.output)
    plot = Path(args.plot) if args.plot else output.with_suffix(".png")
    for path in (output, plot):
        if path.exists() and not args.overwrite:
            raise FileExistsError(f"{path} exists; refusing to overwrite it (pass --overwrite)")
    from ..training.checkpoints import load_model

    model = load_model(source)
    if args.compile:
        model.model.compile_dynamics()
    qd0 = args.qd0 if args.qd0 is not None else [0.0] * model.system.dof
    system = model.system
    steps = int(round(args.duration / args.dt))
    t = np.arange(steps) * args.dt
    tau = None
    if system.num_inputs:
        if args.inputs:
            tau = read_inputs(args.inputs, system.input_names, t)
        elif args.excitation:
            from ..systems.excitation import sample

            tau = sample(json.loads(args.excitation), np.random.default_rng(args.seed), t, system.num_inputs)
        else:
            raise ValueError(f"scene '{system.name}' is actuated ({', '.join(system.input_names)}): pass --inputs CSV "
                             "or --excitation JSON (e.g. '{\"kind\": \"none\"}' for free motion)")
    elif args.inputs or args.excitation:
        raise ValueError(f"scene '{system.name}' has no inputs: --inputs/--excitation do not apply")
    result = simulate_model(model, args.params, args.q0, qd0, args.duration, args.dt, integrator,
                            exact=not args.no_exact, tau=tau)
    meta = {"model": source,
            "variant": model.hparams.variant, "params": args.params, "q0": args.q0, "qd0": qd0,
            "dt": args.dt, "method": integrator}
    write_trajectory(output, result, model.system, meta, args.overwrite)
    plot_trajectory(plot, result, model.system)
    line = f"wrote {output} ({len(result['t'])} points) and {plot}"
    if "energy_drift" in result:
        what = "power-balance error" if system.has_forces else "true-energy drift"
        line += f"; {what} max {result['energy_drift'].max():.2e}"
    else:
        line += f"; scene '{system.name}' has no closed form: no exact trajectory or true energy to compare"
    if "q_exact" in result:
        err = np.abs(result["q"] - result["q_exact"]).max(-1)
        over = np.nonzero(err > 0.1)[0]
        line += (f"; angle error vs exact first exceeds 0.1 at t = {result['t'][over[0]]:.2f} s" if len(over)
                 else f"; max error vs exact {err.max():.2e}")
    print(line)
    return 0
