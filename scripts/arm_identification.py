"""Identification on the 7-joint arm (scene ``robot_arm``): the payload from 2 s of motion, and the
arm's own inertial parameters (base parameters) — learned models beside classical least squares on the
same observations.

Payload study: for each of ``--payloads`` held-out payloads (the scene's sampler, a seed the training
data never used), the engine records ``--seconds`` of excitation tracked by feedback (the scene's own
data generation); encoder noise of ``--noise`` rad is added to the recorded angles; velocities and
accelerations are estimated from the noisy angles (a smoothing spline, the same estimate for every
method) and the torques pass through the same smoothing. Then

* ``least squares (true arm)``: the ceiling. The torques the payload adds, ``tau - tau_arm(q, qd, qdd)``
  (the engine's inverse dynamics of the arm without payload, which it knows exactly), are linear in
  the payload's ten inertial parameters (``MujocoArm.payload_regressor``); ordinary least squares, then
  ``m`` and ``c = (m c) / m``;
* each given checkpoint through ``lnn_torch.identification.learned.identify_batch`` (the acceleration fit of
  ``lnn-torch identify`` on every ``--stride``-th sample, ``--starts`` starts, in the model's training box).

Base-parameter study (``--perturbed-*``): on the held-out trajectories of the perturbed arm (``data``
of the perturbed configuration), the numerical base parameters of the arm (``lnn_torch.robots.regressor``)
as the engine's perturbed description has them (truth), as the shipped description has them (what a
user starts from), as the grey box learned them, and by least squares on the regressor of those
trajectories (the ceiling on the same observations).

    python scripts/arm_identification.py --film-lnn runs/robot_arm/checkpoints/last.ckpt \\
        --grey-box runs/robot_arm_grey_box/checkpoints/last.ckpt \\
        --perturbed-grey-box runs/robot_arm_perturbed_grey_box/checkpoints/last.ckpt \\
        --perturbed-data data/robot_arm_perturbed.h5

Writes ``identification.json`` and ``README.md`` to ``--output-dir`` (default results/robot_arm/identification).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from _common import HelpFormatter, add_output_dir, wrote

ROOT = Path(__file__).resolve().parents[1]


def observations(args):
    """Noise-free and noisy observations of ``--payloads`` payloads: dict of arrays ``(N, T, .)``."""
    from lnn_torch.data import DatasetSpec, generate_arrays

    spec = DatasetSpec(scene="robot_arm", num_trajectories=args.payloads, duration=args.seconds, dt=args.dt,
                       seed=args.seed, split=(1.0, 0.0, 0.0))
    arrays = generate_arrays(spec)
    rng = np.random.default_rng(args.seed)
    arrays["q_noisy"] = arrays["q"] + args.noise * rng.standard_normal(arrays["q"].shape)
    return spec, arrays


def smoothed(arrays, dt):
    """Velocities, accelerations and torques through one smoothing of the noisy angles (and torques)."""
    from lnn_torch.data import derivatives

    s = derivatives.settings({**derivatives.NOISY, "use_measured_velocity": False})
    qd, qdd, tau = [], [], []
    for i in range(len(arrays["q_noisy"])):
        a, b = derivatives.estimate(arrays["q_noisy"][i], dt, s)
        qd.append(a)
        qdd.append(b)
        tau.append(derivatives.smooth_inputs(arrays["tau"][i], dt, s))
    # the smoothed angles themselves: the smoothing that smooth_inputs applies to the torques
    q = np.stack([derivatives.smooth_inputs(x, dt, s) for x in arrays["q_noisy"]])
    return q, np.stack(qd), np.stack(qdd), np.stack(tau), derivatives.describe(s)


def errors(mass, com, truth) -> dict:
    m_true, c_true = truth[:, 0], truth[:, 1:4]
    rel = np.abs(mass - m_true) / m_true
    dc = np.linalg.norm(com - c_true, axis=1) * 1000
    heavy = m_true >= 0.5
    return {"mass_rel_median": float(np.median(rel)), "mass_rel_q75": float(np.quantile(rel, 0.75)),
            "com_mm_median": float(np.median(dc)), "com_mm_q75": float(np.quantile(dc, 0.75)),
            "mass_rel_median_heavy": float(np.median(rel[heavy])), "com_mm_median_heavy": float(np.median(dc[heavy])),
            "num_heavy": int(heavy.sum())}


def model_payloads(checkpoint, t, q_noisy, tau, starts, stride):
    from lnn_torch import load_model
    from lnn_torch.identification import identify_batch
    from lnn_torch.systems import get_system

    module = load_model(checkpoint)
    system = get_system("robot_arm")
    found = identify_batch(module.model, system, t, q_noisy, None, tau, None, starts=starts, accel_stride=stride)
    names = system.param_names
    est = np.array([[r.params[n] for n in names] for r in found])
    return est[:, 0], est[:, 1:4]


def payload_study(args) -> dict:
    from lnn_torch.identification import payload_least_squares

    spec, arrays = observations(args)
    truth = arrays["params"]
    t = arrays["t"]
    q, qd, qdd, tau, how = smoothed(arrays, args.dt)
    edge = int(round(0.1 / args.dt))
    rows = {}
    start = time.perf_counter()
    fits = payload_least_squares(q, qd, qdd, tau, edge)
    seconds = (time.perf_counter() - start) / 2
    rows["least squares, true arm, point mass (ceiling)"] = {**errors(*fits["point mass"], truth), "seconds": seconds}
    rows["least squares, true arm, ten inertial parameters"] = {**errors(*fits["linear"], truth), "seconds": seconds}
    # noise-free, exact accelerations: what the regressor gives without noise (a check of the study)
    exact = payload_least_squares(arrays["q"], arrays["qd"], arrays["qdd"], arrays["tau"], 0)
    rows["least squares, true arm, noise-free (check)"] = errors(*exact["linear"], truth)
    for name, ckpt in (("film_lnn", args.film_lnn), ("grey box", args.grey_box)):
        if ckpt:
            start = time.perf_counter()
            m, c = model_payloads(ckpt, t, arrays["q_noisy"], arrays["tau"], args.starts, args.stride)
            rows[name] = {**errors(m, c, truth), "seconds": time.perf_counter() - start, "checkpoint": str(ckpt)}
    return {"payloads": args.payloads, "seconds": args.seconds, "dt": args.dt, "noise_rad": args.noise,
            "derivatives": how, "spec": json.loads(spec.to_json()), "rows": rows}


def base_parameter_study(args) -> dict:
    from lnn_torch import load_model
    from lnn_torch.data import read_dataset
    from lnn_torch.identification import base_least_squares
    from lnn_torch.robots import MujocoArm, kinematics, regressor
    from lnn_torch.systems import get_system

    data = read_dataset(args.perturbed_data)
    system = get_system("robot_arm", **data.spec.get("scene_config", {}))
    test = data.trajectories("test", args.base_trajectories)
    stride = args.base_stride
    q, qd, qdd, tau = (x[:, ::stride].reshape(-1, 7).double() for x in (test.q, test.qd, test.qdd, test.tau))
    arm = MujocoArm("franka_panda")
    # each trajectory's payload is known in this experiment: its torques (on the same kinematics) come off
    per = test.q[:, ::stride].shape[1]
    payload_pi = torch.stack([MujocoArm.inertial_parameters(p) for p in test.params.double()])  # (N, 10)
    Y_pay = arm.payload_regressor(q, qd, qdd)  # (N * per, 7, 10)
    tau = tau - (Y_pay @ payload_pi.repeat_interleave(per, 0)[..., None])[..., 0]
    nominal = kinematics.read_chain(arm.model)
    true_chain = kinematics.read_chain(system.arm.model)
    Y = regressor.regressor(nominal, q, qd, qdd).reshape(-1, 12 * 7)
    base = regressor.base_parameters(Y)
    names = regressor.parameter_names(nominal)
    pis = {"truth (perturbed engine)": regressor.parameter_vector(true_chain.J, true_chain.armature,
                                                                  true_chain.damping),
           "shipped description": regressor.parameter_vector(nominal.J, nominal.armature, nominal.damping)}
    if args.perturbed_grey_box:
        module = load_model(args.perturbed_grey_box)
        part = module.model.kinetic["spatial"]
        rep = part.si_report()
        b, _ = module.model.forces.coefficients(module.model.normalizer.params(torch.zeros(1, 4)))
        pis["grey box (learned)"] = regressor.parameter_vector(rep["pseudo_inertia"], rep["armature"],
                                                               b.reshape(-1).double())
    betas = {k: base["map"] @ v.detach().numpy() for k, v in pis.items()}
    betas["least squares (ceiling)"] = base_least_squares(Y, tau, base)
    truth = betas["truth (perturbed engine)"]
    tau_np = tau.numpy().reshape(-1)
    YB = Y.numpy()[:, base["independent"]]
    rows = {}
    for k, beta in betas.items():
        rel = np.abs(beta - truth) / np.maximum(np.abs(truth), 1e-3 * np.abs(truth).max())
        pred = YB @ beta
        rows[k] = {"base_rel_err_median": float(np.median(rel)), "base_rel_err_max": float(rel.max()),
                   "torque_nmse": float(np.mean(((pred - tau_np).reshape(-1, 7) ** 2).mean(0)
                                                / tau_np.reshape(-1, 7).var(0)))}
    lead = [names[j] for j in base["independent"]]
    return {"data": str(args.perturbed_data), "trajectories": len(test), "stride": stride, "rank": base["rank"],
            "num_parameters": len(names), "unidentified": [names[j] for j in range(len(names))
                                                          if not base["map"][:, j].any()],
            "base_leading_names": lead, "rows": rows}


def markdown(result: dict) -> str:
    from lnn_torch.evaluation import table_header, table_row

    lines = ["# Identification on the 7-joint arm", "", f"Command: `{result['command']}`", ""]
    p = result.get("payload")
    if p:
        lines += [f"## The payload from {p['seconds']:g} s of motion", "",
                  f"{p['payloads']} held-out payloads (mass 0-3 kg, centre of mass within the scene's box), the "
                  f"scene's excitation at {1 / p['dt']:g} Hz, encoder noise {p['noise_rad']:g} rad; derivatives: "
                  f"{p['derivatives']} (every method sees the same estimates).", "",
                  *table_header(["method", "mass error, median (q75)", "centre-of-mass error, median (q75), mm",
                                 "payloads >= 0.5 kg: mass / com median", "time (s)"])]
        for name, r in p["rows"].items():
            lines.append(table_row([name, f"{100 * r['mass_rel_median']:.2f} % ({100 * r['mass_rel_q75']:.2f} %)",
                                    f"{r['com_mm_median']:.2f} ({r['com_mm_q75']:.2f})",
                                    f"{100 * r['mass_rel_median_heavy']:.2f} % / "
                                    f"{r['com_mm_median_heavy']:.2f} mm ({r['num_heavy']})",
                                    f"{r.get('seconds', float('nan')):.1f}"]))
        lines.append("")
    b = result.get("base")
    if b:
        lines += ["## The perturbed arm's base parameters", "",
                  f"{b['trajectories']} held-out trajectories of `{b['data']}` (every {b['stride']}th sample; each "
                  f"trajectory's known payload taken off the torques): the "
                  f"regressor has rank {b['rank']} of {b['num_parameters']} parameters (ten per link, armature and "
                  f"damping per joint); no number for {len(b['unidentified'])} that move no torque "
                  f"({', '.join(b['unidentified'])}).", "",
                  *table_header(["parameters", "base-parameter error vs truth, median / max",
                                 "torque nMSE on these trajectories (fraction)"])]
        for name, r in b["rows"].items():
            lines.append(table_row([name, f"{100 * r['base_rel_err_median']:.2f} % / "
                                          f"{100 * r['base_rel_err_max']:.1f} %", f"{r['torque_nmse']:.2e}"]))
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--film-lnn", help="checkpoint of the film_lnn arm model")
    ap.add_argument("--grey-box", help="checkpoint of the grey-box arm model")
    ap.add_argument("--perturbed-grey-box", help="checkpoint of the grey box trained on the perturbed arm")
    ap.add_argument("--perturbed-data", help="the perturbed arm's dataset (.h5) for the base-parameter study")
    ap.add_argument("--payloads", type=int, default=20, help="held-out payloads")
    ap.add_argument("--seconds", type=float, default=2.0, help="motion per payload, s")
    ap.add_argument("--dt", type=float, default=0.005, help="sample interval, s")
    ap.add_argument("--noise", type=float, default=1e-3, help="encoder noise, rad (standard deviation)")
    ap.add_argument("--starts", type=int, default=2, help="random starts of the learned models' fit")
    ap.add_argument("--stride", type=int, default=4, help="every n-th sample in the learned models' acceleration fit")
    ap.add_argument("--seed", type=int, default=1000, help="seed of the held-out payloads and the noise")
    ap.add_argument("--base-trajectories", type=int, default=20, help="held-out trajectories for the base parameters")
    ap.add_argument("--base-stride", type=int, default=5, help="use every n-th sample of them")
    add_output_dir(ap, str(ROOT / "results" / "robot_arm" / "identification"), "the folder of the results")
    args = ap.parse_args()
    torch.set_num_threads(1)
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = {"command": "python scripts/arm_identification.py " + " ".join(
        f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items() if v is not None and k != "output_dir")}
    result["payload"] = payload_study(args)
    if args.perturbed_data:
        result["base"] = base_parameter_study(args)
    (out / "identification.json").write_text(json.dumps(result, indent=1))
    (out / "README.md").write_text(markdown(result))
    print(markdown(result))
    wrote(out / "identification.json", out / "README.md")


if __name__ == "__main__":
    main()
