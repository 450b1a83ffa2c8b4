"""MuJoCo's own identification (``mujoco.sysid``, inside the pinned ``mujoco``; its extras: ``pip install
'mujoco[sysid]'``) beside the classical fits and the grey box, on an imported arm recording, judged as
every other row: the joint-torque RMS error per joint in N m on the held-out split, against the measured
torques, at the targets' velocities and accelerations.

``mujoco.sysid`` fits by simulation: the description compiled with a torque motor and position and
velocity sensors per joint, rolled out from recorded states under the recorded torques, its parameters
(every moving body's inertia as a pseudo-inertia, each joint's damping, friction loss and armature)
moved by MuJoCo's least squares until the rolled-out positions and velocities match the recorded ones.
An arm driven open loop by measured torques leaves a real recording within a fraction of a second, so
the training split is cut into windows of ``--window`` s, each rolled out from its recorded state (the
multiple shooting a user of it would do). Its 95 % confidence intervals come from the Jacobian at the
optimum (``mujoco.sysid.calculate_intervals``). The identified model is then judged by MuJoCo's inverse
dynamics (``mj_inverse``: the rigid body, armature, damping, and friction loss as the constraint solver
sees it).

    python scripts/mujoco_sysid.py --data data/real_panda.h5 [LABEL=CHECKPOINT ...]

Writes ``metrics.json`` and ``README.md`` to ``--output-dir``; prints the table.
"""

from __future__ import annotations

import argparse
import json
import shlex
import time
from pathlib import Path

import numpy as np
import torch
from _common import HelpFormatter, add_output_dir, wrote


def _prepared_spec(description, dt: float):
    """The description's ``MjSpec`` as sysid rolls it out: its actuators and sensors replaced by a torque
    motor and a position and a velocity sensor per hinge joint, the recording's time step, no contacts."""
    import mujoco

    from lnn_torch.robots import ArmDescription

    spec = ArmDescription.of(description).spec()
    for item in list(spec.actuators) + list(spec.sensors):
        spec.delete(item)
    joints = [j.name for j in spec.joints if j.type == mujoco.mjtJoint.mjJNT_HINGE]
    for name in joints:
        spec.add_actuator(name=f"tau_{name}", target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
    for kind, tag in ((mujoco.mjtSensor.mjSENS_JOINTPOS, "pos"), (mujoco.mjtSensor.mjSENS_JOINTVEL, "vel")):
        for name in joints:
            spec.add_sensor(name=f"{name}_{tag}", type=kind, objtype=mujoco.mjtObj.mjOBJ_JOINT, objname=name)
    spec.option.timestep = dt
    spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    return spec, joints


def _parameters(spec, model, joints):
    """Every moving body's inertia (pseudo-inertia, sysid's bounds) and each joint's damping, friction loss
    and armature (non-negative; starting at small values: the description as logged has none)."""
    from mujoco import sysid

    params = sysid.ParameterDict()
    bodies = []
    for name in joints:
        body = model.body(int(model.jnt_bodyid[model.joint(name).id])).name
        bodies.append(body)
        param = sysid.body_inertia_param(spec, model, body, inertia_type=sysid.InertiaType.Pseudo)
        param.modifier = _inertia_setter(body)  # sysid's own writes the inertia element by element, which this
        params.add(param)                       # MjSpec does not keep (the compile then finds no inertia)

    def setter(joint, field):
        def modify(s, p):
            value = float(p.value[0])
            setattr(s.joint(joint), field, [value, 0.0, 0.0] if field == "damping" else value)
        return modify

    for name in joints:
        for field, start, top in (("damping", 0.1, 20.0), ("frictionloss", 0.1, 20.0), ("armature", 0.01, 2.0)):
            params.add(sysid.Parameter(f"{name}_{field}", start, 0.0, top, modifier=setter(name, field)))
    return params, bodies


def _inertia_setter(body: str):
    """The modifier of a body's pseudo-inertia parameter (sysid's log-Cholesky ``theta``): mass, centre of
    mass and the full inertia about it, written whole."""
    from mujoco.sysid import model_modifier

    def modify(spec, param):
        pi = model_modifier.pi_from_theta(np.asarray(param.value, dtype=np.float64))
        mass, com = float(pi[0]), pi[1:4] / pi[0]
        c = model_modifier.skew(com)
        full = pi[4:].reshape(3, 3) + mass * c @ c  # about the centre of mass
        b = spec.body(body)
        b.explicitinertial = True
        b.mass, b.ipos, b.inertia = mass, com, [0.0, 0.0, 0.0]  # the full inertia alone says it
        b.fullinertia = [full[0, 0], full[1, 1], full[2, 2], full[0, 1], full[0, 2], full[1, 2]]
    return modify


def _windows(dm, split: str, seconds: float, every: int = 1):
    """``(names, states, controls, sensors)``: the split cut into windows of ``seconds`` (every ``every``-th
    kept), each from its recorded state (angles, recorded velocities), under the recorded torques."""
    data = dm.trajectories(split, smooth_inputs=False)
    recorded = dm.recorded_velocities(split)
    dt = float(data.dt)
    steps = max(2, int(round(seconds / dt)))
    lengths = [data.num_points] * len(data) if data.lengths is None else [int(n) for n in data.lengths]
    out = ([], [], [], [])
    for j, n in enumerate(lengths):
        for s in range(0, n - steps, steps * every):
            q = data.q[j, s:s + steps + 1].double().numpy()
            qd = recorded[j, s:s + steps + 1].double().numpy()
            tau = data.tau[j, s:s + steps + 1].double().numpy()
            out[0].append(f"{split}{j}_{s}")
            out[1].append((q[0], qd[0]))
            out[2].append((np.arange(steps + 1) * dt, tau))
            out[3].append((np.arange(steps + 1) * dt, np.concatenate([q, qd], 1)))
    return out


SIM_ROBOT = {"source": "franka_panda", "remove": ["hand"]}  # the simulated arm's description (MuJoCo's settings)


def _simulated_dataset(seed: int, folder: Path, seconds: float = 10.0, dt: float = 0.002):
    """A recording of the Panda (``SIM_ROBOT``) perturbed by ``seed`` (``MujocoArm(perturbation=seed)``:
    masses, centres of mass, inertias, armature and damping off the description, known), driven by a
    computed-torque controller on its own dynamics along a sum of three sines per joint about a bent
    configuration, as CSV, imported with the description as written (what every method starts from):
    training 0.2-7 s, validation 7-8.5 s, test 8.5-10 s. Returns ``(dataset path, the truth's report)``."""
    from lnn_torch import ImportSpec, import_recordings
    from lnn_torch.robots import MujocoArm

    arm = MujocoArm(SIM_ROBOT, perturbation=seed)
    rng = np.random.default_rng(seed)
    centre = np.array([0.0, -0.6, 0.0, -2.0, 0.0, 1.6, 0.8])
    amp, freq, phase = rng.uniform(0.15, 0.35, (3, 7)), rng.uniform(0.2, 1.2, (3, 7)), rng.uniform(0, 6.3, (3, 7))
    w = 2 * np.pi * freq
    q, qd = centre + (amp * np.sin(phase)).sum(0), (amp * w * np.cos(phase)).sum(0)
    arm.start(q, qd)
    columns = {"time": []} | {f"{k}{j}": [] for k in ("q", "dq", "tau") for j in range(1, 8)}
    for k in range(int(round(seconds / dt))):
        t = k * dt
        ref = centre + (amp * np.sin(w * t + phase)).sum(0)
        ref_d, ref_dd = (amp * w * np.cos(w * t + phase)).sum(0), -(amp * w**2 * np.sin(w * t + phase)).sum(0)
        tau = arm.inverse(q[None], qd[None], (ref_dd + 400.0 * (ref - q) + 40.0 * (ref_d - qd))[None])[0].numpy()
        for j in range(7):
            for key, value in (("q", q), ("dq", qd), ("tau", tau)):
                columns[f"{key}{j + 1}"].append(value[j])
        columns["time"].append(t)
        arm.hold(tau, dt, 2)
        q, qd = arm.state()
    folder.mkdir(parents=True, exist_ok=True)
    csv = folder / f"perturbed_panda_{seed}.csv"
    names = list(columns)
    rows = np.stack([np.asarray(columns[n], dtype=np.float64) for n in names], -1)
    csv.write_text(",".join(names) + "\n" + "\n".join(",".join(f"{v:.17g}" for v in r) for r in rows) + "\n")
    stem = csv.stem
    spec = ImportSpec(time="time", coordinates=[f"q{j}" for j in range(1, 8)],
                      velocities=[f"dq{j}" for j in range(1, 8)], inputs=[f"tau{j}" for j in range(1, 8)],
                      coord_names=[f"joint{j}" for j in range(1, 8)], robot=SIM_ROBOT, friction=True,
                      coulomb_velocity=0.02, label="perturbed_panda", torque_delay="off",
                      split={"train": [f"{stem}[0.2:7.0]"], "val": [f"{stem}[7.0:8.5]"], "test": [f"{stem}[8.5:10.0]"]})
    path = import_recordings([csv], folder / f"perturbed_panda_{seed}.h5", spec, overwrite=True)
    return path, arm.perturbation_report()


def _inverse(model, q, qd, qdd) -> np.ndarray:
    """MuJoCo's inverse dynamics ``(N, n)`` of ``model`` at each point."""
    import mujoco

    data = mujoco.MjData(model)
    out = np.empty_like(q)
    for k in range(len(q)):
        data.qpos[:], data.qvel[:], data.qacc[:] = q[k], qd[k], qdd[k]
        mujoco.mj_inverse(model, data)
        out[k] = data.qfrc_inverse
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("models", nargs="*", help="LABEL=CHECKPOINT: learned models of the recording, in the same table")
    ap.add_argument("--data", default="data/real_panda.h5", help="an imported arm recording (lnn-torch import)")
    ap.add_argument("--targets", default='{"method": "butterworth", "cutoff": 10.0, "order": 4, '
                    '"use_measured_velocity": true}', help="derivative settings (JSON) of the judged accelerations")
    ap.add_argument("--drive", default="viscous+coulomb+offset", help="the classical fits' drive model")
    ap.add_argument("--window", type=float, default=0.25, help="seconds per rolled-out window of the training split")
    ap.add_argument("--every", type=int, default=2, help="keep every n-th window (the fit's time is the rollouts')")
    ap.add_argument("--max-iters", type=int, default=20, help="sysid's least-squares iterations")
    ap.add_argument("--threads", type=int, default=2, help="torch threads")
    ap.add_argument("--label", default=None, help="what the recording is, for the title (default: the real Panda, "
                    "or the simulated arm)")
    ap.add_argument("--simulate", type=int, default=None, metavar="SEED",
                    help="instead of --data: a recording of the Panda perturbed by SEED (known truth), simulated and "
                         "imported into --work; the table adds the truth's torques and the link masses")
    ap.add_argument("--work", default="runs/mujoco_sysid", help="where --simulate writes its recording and dataset")
    add_output_dir(ap, "mujoco_sysid", "the folder of metrics.json and README.md")
    args = ap.parse_args()
    from mujoco import sysid

    from lnn_torch import load_model
    from lnn_torch.data import points
    from lnn_torch.evaluation import markdown_table
    from lnn_torch.identification import fit_classical, model_torque, torque_errors
    from lnn_torch.systems import get_system
    from lnn_torch.training import TrajectoryDataModule

    torch.set_num_threads(args.threads)
    truth = None
    if args.simulate is not None:
        args.data, truth = _simulated_dataset(args.simulate, Path(args.work))
    title = args.label or ("the real Panda" if truth is None else
                           f"a simulated Panda perturbed by seed {args.simulate}")
    dm = TrajectoryDataModule(path=str(args.data), targets=json.loads(args.targets))
    scene, config = dm.model_scene()
    system = get_system(scene, **config)
    names = list(system.coord_names)
    spec, joints = _prepared_spec(system.config()["description"], dm.dt)
    model = spec.compile()
    params, bodies = _parameters(spec, model, joints)
    seq, states, controls, sensors = _windows(dm, "train", args.window, args.every)
    initial = [sysid.create_initial_state(model, q, qd) for q, qd in states]
    spec = _prepared_spec(system.config()["description"], dm.dt)[0]  # as written (the parameters read the other)
    ms = sysid.ModelSequences("arm", spec, seq, initial, [sysid.TimeSeries(t, u) for t, u in controls],
                              [sysid.TimeSeries.from_names(t, y, model) for t, y in sensors])
    residual_fn = sysid.build_residual_fn(models_sequences=[ms])
    began = time.perf_counter()
    fitted, result = sysid.optimize(initial_params=params, residual_fn=residual_fn, optimizer="mujoco",
                                    verbose=False, max_iters=args.max_iters)
    sysid_seconds = time.perf_counter() - began
    residuals, _, _ = residual_fn(fitted.as_vector(), fitted)
    _, half_widths = sysid.calculate_intervals(residuals, result.jac)
    identified = sysid.apply_param_modifiers(fitted, _prepared_spec(system.config()["description"], dm.dt)[0])

    rows = {}
    splits = {s: points(dm.trajectories(s)) for s in ("val", "test")}

    def judge(label, torque, seconds=None):
        row = {s: torque_errors(torque(*splits[s][:3], splits[s][4]), splits[s][3], names) for s in splits}
        rows[label] = {**row["test"], "val_rms_mean": row["val"]["rms_mean"], "fit_seconds": seconds}

    judge(f"mujoco.sysid (rollouts of {args.window:g} s windows, {len(seq)} of them)",
          lambda q, qd, qdd, p: torch.as_tensor(_inverse(identified, q.numpy(), qd.numpy(), qdd.numpy())),
          sysid_seconds)
    fits = fit_classical(system, dm.trajectories("train"), drive=args.drive, val=dm.trajectories("val"))
    for label, fit in fits.items():
        judge(label, lambda q, qd, qdd, p, fit=fit: fit.inverse(q, qd, qdd, p), fit.info["fit_seconds"])
    for item in args.models:
        label, path = item.split("=", 1)
        module = load_model(path)
        start = module.classical_start or {}
        judge(label, model_torque(module.model), start.get("fit_seconds"))

    masses = None
    if truth is not None:
        from lnn_torch.robots import MujocoArm

        arm = MujocoArm(SIM_ROBOT, perturbation=args.simulate)
        judge("the truth (the perturbed arm's own inverse dynamics)",
              lambda q, qd, qdd, p: arm.inverse(q, qd, qdd))
        consistent = next(f for f in fits.values() if f.method == "physically consistent")
        masses = {"truth": [v["mass"][1] for v in truth["bodies"].values()],
                  "description": [v["mass"][0] for v in truth["bodies"].values()],
                  "mujoco.sysid": [float(identified.body_mass[identified.body(b).id]) for b in bodies],
                  "physically consistent": consistent.report()["mass"]}
    vector = fitted.as_vector()
    finite = np.isfinite(half_widths)
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    metrics = {"data": str(args.data), "simulated_seed": args.simulate, "link_masses": masses,
               "targets": json.loads(args.targets), "window": args.window, "windows": len(seq),
               "max_iters": args.max_iters, "joints": names, "rows": rows,
               "sysid": {"parameters": vector.tolist(), "half_width95": half_widths.tolist(),
                         "finite_intervals": int(finite.sum()), "bodies": bodies}}
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    order = sorted(rows, key=lambda k: rows[k]["rms_mean"])
    table = markdown_table(
        ["model", *names, "mean, test", "mean, validation", "fit (s)"],
        [[k, *(f"{rows[k]['rms'][n]:.2f}" for n in names), f"**{rows[k]['rms_mean']:.3f}**",
          f"{rows[k]['val_rms_mean']:.3f}", "" if rows[k]["fit_seconds"] is None else f"{rows[k]['fit_seconds']:.0f}"]
         for k in order])
    source = f"--simulate {args.simulate}" if truth is not None else f"--data {args.data}"
    command = " ".join([source, *(shlex.quote(m) for m in args.models)])
    nth = f"every {args.every}{'nd' if args.every == 2 else 'th'} window" if args.every > 1 else "every window"
    mass_table = "" if masses is None else (
        "\n\nThe truth's own row is the error of the targets (velocities and accelerations estimated from the "
        "recording, as for a real arm), the floor of this table. Link masses (kg):\n\n") + markdown_table(
        ["", *bodies], [[k, *(f"{v:.3f}" for v in values)] for k, values in masses.items()])
    text = f"""# {title}: MuJoCo's own identification beside the classical fits and the grey box

`python scripts/mujoco_sysid.py {command}`
(`pip install -e '.[sysid]'`; the dataset imported as its config says). Held-out joint-torque RMS error in
N m, against the measured torques at the targets' velocities and accelerations
({json.loads(args.targets)['method']}), every model on the same points; fit time on this machine's 2 cores
(the grey box's: its classical start; its checkpoint was trained with the command in its own results).

{table}{mass_table}

`mujoco.sysid` fitted {len(vector)} parameters ({len(bodies)} bodies' pseudo-inertias, each joint's damping,
friction loss and armature) to the recorded angles and velocities of {len(seq)} windows of {args.window:g} s of
the training split ({nth}), each rolled out from its recorded state under the recorded torques
({args.max_iters} iterations at most of MuJoCo's least squares; the run prints its objective at each). Its 95 %
intervals (sysid's own: infinite where a direction the data do not determine moves the parameter) are
finite for {int(finite.sum())} of the {len(vector)} parameters (`metrics.json`). MuJoCo's friction loss is
its Coulomb friction (a constraint, no torque offset): the classical fits and the grey box have an offset
per joint too.
"""
    (out / "README.md").write_text(text)
    print(table)
    wrote([out / "metrics.json", out / "README.md"])


if __name__ == "__main__":
    main()
