"""An arm the package does not ship, as a lab meets it: a UR5-like 6-joint arm whose description (URDF) holds
the maker's nominal values, and logs of the real one. The real arm (MuJoCo, the truth) differs from its
description as real arms do: masses a few per cent off, centres of mass off the axes, full inertia tensors,
rotor armature the description lacks, a torque sensor offset and friction: viscous and Coulomb, plus, unless
``--clean``, what the library's drive model has no term for (a Stribeck breakaway and a Coulomb level that
ripples with the joint angle).

Ten recordings (``r01``..``r10``, 13-18 s each) of a five-harmonic exciting trajectory about a working
pose, logged as a UR controller's RTDE client writes them: epoch time stamps at about 500 Hz with jitter, 0.3 %
of the samples dropped and one 26 ms gap (in ``r05``), encoder-quantised joint angles and joint torques with 1.5 %
noise, no velocities. ``r03``, ``r06`` and ``r09`` carry a 1.2 kg tool whose centre of mass and inertia nobody
measured: ``import.yaml`` declares its mass alone. The split is by recording: training ``r01``-``r05``,
validation ``r06``-``r07``, held out ``r08``-``r10``.

    python scripts/other_arm_recordings.py -o runs/other_arm            # --clean: only the drive model's friction
    lnn-torch import runs/other_arm/r*.csv --config runs/other_arm/import.yaml -o data/other_arm.h5
    lnn-torch fit -c configs/real_panda.yaml --data.path data/other_arm.h5
    lnn-torch identify CHECKPOINT data/other_arm.h5                     # per held-out log, beside least squares

Writes ``description.urdf`` (what the lab has; its meshes, ``package://``, are not there), the CSV files,
``import.yaml`` and, for judging only, ``truth/`` (the real arm's URDF and each recording's exact signals). With
``--floor DATASET`` instead: the truth's own joint-torque RMS error on the dataset's held-out recordings at the
states a model sees there (the configuration's 10 Hz Butterworth targets): what the noise and the filter leave.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from _common import HelpFormatter, add_output_dir, wrote

JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
          "wrist_3_joint")
# per link: mass (kg), centre of mass (m), principal moments (kg m^2), their axes' roll-pitch-yaw (rad)
NOMINAL = {"base_link": (4.0, (0, 0, 0), (0.00443, 0.00443, 0.0072), (0, 0, 0)),
           "shoulder_link": (3.7, (0, 0, 0), (0.010267, 0.010267, 0.00666), (0, 0, 0)),
           "upper_arm_link": (8.393, (0, 0, 0.28), (0.22689, 0.22689, 0.0151074), (0, 0, 0)),
           "forearm_link": (2.275, (0, 0, 0.25), (0.049443, 0.049443, 0.004095), (0, 0, 0)),
           "wrist_1_link": (1.219, (0, 0, 0), (0.0021942, 0.0021942, 0.0021942), (0, 0, 0)),
           "wrist_2_link": (1.219, (0, 0, 0), (0.0021942, 0.0021942, 0.0021942), (0, 0, 0)),
           "wrist_3_link": (0.1879, (0, 0, 0), (0.000132, 0.000132, 0.0001782), (0, 0, 0))}
REAL = {"base_link": (4.0, (0, 0, 0.02), (0.0045, 0.0045, 0.0072), (0, 0, 0)),
        "shoulder_link": (3.85, (0.002, -0.012, 0.004), (0.0110, 0.0095, 0.0071), (0.15, -0.1, 0.3)),
        "upper_arm_link": (8.06, (0.004, 0.011, 0.212), (0.1335, 0.1310, 0.0168), (0.05, 0.08, 0.4)),
        "forearm_link": (2.46, (0.003, -0.006, 0.184), (0.0312, 0.0305, 0.0044), (-0.06, 0.04, 0.2)),
        "wrist_1_link": (1.30, (0.0, 0.095, 0.006), (0.0025, 0.0020, 0.0023), (0.3, 0.2, -0.1)),
        "wrist_2_link": (1.17, (0.002, 0.003, 0.091), (0.0024, 0.0021, 0.0019), (-0.2, 0.25, 0.1)),
        "wrist_3_link": (0.205, (0.001, 0.068, -0.002), (0.00016, 0.00013, 0.00017), (0.1, 0.3, 0.2))}
# the UR5's kinematics: joint, parent, child, origin xyz, origin rpy, axis, limit (rad)
CHAIN = (("shoulder_pan_joint", "base_link", "shoulder_link", (0, 0, 0.089159), (0, 0, 0), (0, 0, 1), 2 * np.pi),
         ("shoulder_lift_joint", "shoulder_link", "upper_arm_link", (0, 0.13585, 0), (0, np.pi / 2, 0), (0, 1, 0),
          2 * np.pi),
         ("elbow_joint", "upper_arm_link", "forearm_link", (0, -0.1197, 0.425), (0, 0, 0), (0, 1, 0), np.pi),
         ("wrist_1_joint", "forearm_link", "wrist_1_link", (0, 0, 0.39225), (0, np.pi / 2, 0), (0, 1, 0), 2 * np.pi),
         ("wrist_2_joint", "wrist_1_link", "wrist_2_link", (0, 0.093, 0), (0, 0, 0), (0, 0, 1), 2 * np.pi),
         ("wrist_3_joint", "wrist_2_link", "wrist_3_link", (0, 0, 0.09465), (0, 0, 0), (0, 1, 0), 2 * np.pi))
MESHES = ("base", "shoulder", "upperarm", "forearm", "wrist1", "wrist2", "wrist3")
# the real drives
ARMATURE = np.array([0.20, 0.20, 0.10, 0.03, 0.03, 0.03])  # reflected rotor inertia, kg m^2
VISCOUS = np.array([3.0, 3.2, 2.0, 0.6, 0.6, 0.5])  # N m s/rad
COULOMB = np.array([5.0, 5.5, 3.5, 1.2, 1.1, 1.0])  # N m
COULOMB_VELOCITY = 0.05  # rad/s, the tanh's
OFFSET = np.array([0.4, -0.6, 0.3, -0.15, 0.1, 0.05])  # the torque sensor's, N m
STRIBECK, STRIBECK_VELOCITY = 0.3, 0.15  # the breakaway's share of the Coulomb level, its decay (rad/s)
RIPPLE = 0.12  # the Coulomb level's ripple over the joint angle
# the tool at the flange (tool0's frame): mass (kg), centre of mass (m), inertia about it (Ixx Iyy Izz Ixy Ixz Iyz)
TOOL = {"mass": 1.2, "com": (0.012, -0.025, 0.045), "inertia": (0.0016, 0.0016, 0.0013, 0.0001, 0.0, 0.0)}
LOADED = ("r03", "r06", "r09")
# the motion: harmonics, working pose (rad) and the reach of each joint's position, velocity, acceleration
HARMONICS = 5
POSE = np.array([0.0, -1.6, 1.3, -1.5, 0.0, 0.0])
REACH = (np.array([1.6, 0.9, 1.1, 1.4, 1.5, 2.0]), np.array([1.6, 1.4, 1.8, 2.4, 2.4, 2.8]),
         np.array([5.0, 5.0, 7.0, 10.0, 10.0, 12.0]))
ENCODER = 2 * np.pi / 2**16  # rad per count
NOISE = 0.015  # the torque noise, of each joint's torque spread
EPOCH = 1718000000.0  # the first log's first stamp (s)


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    add_output_dir(ap, "runs/other_arm", "the folder the description, CSV recordings and import.yaml go to")
    ap.add_argument("--clean", action="store_true",
                    help="friction the drive model has terms for only (viscous, Coulomb, offset)")
    ap.add_argument("--seed", type=int, default=4, help="the trajectories', stamps' and noise's seed")
    ap.add_argument("--overwrite", action="store_true", help="replace existing files")
    ap.add_argument("--floor", metavar="DATASET",
                    help="instead: the truth's error on the held-out recordings of DATASET (imported from the folder)")
    return ap


def _rotation(rpy) -> np.ndarray:
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]]) @ np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]]) \
        @ np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])


def urdf(links: dict, meshes: bool) -> str:
    """The arm's URDF with ``links``' inertials (full tensors in the link frames) and UR's flange frames."""
    vec = lambda v: " ".join(f"{x:.9g}" for x in v)  # noqa: E731
    lines = ['<?xml version="1.0"?>', '<robot name="ur5_like">']
    for (link, (mass, com, moments, rpy)), mesh in zip(links.items(), MESHES, strict=True):
        R = _rotation(rpy)
        inertia = R @ np.diag(moments) @ R.T
        lines.append(f'  <link name="{link}">')
        if meshes:
            for kind, ext in (("visual", "dae"), ("collision", "stl")):
                lines.append(f'    <{kind}><geometry><mesh filename="package://ur_description/meshes/ur5/{kind}/'
                             f'{mesh}.{ext}"/></geometry></{kind}>')
        lines += [f'    <inertial><mass value="{mass}"/><origin xyz="{vec(com)}" rpy="0 0 0"/>',
                  '      <inertia ' + " ".join(f'i{a}="{inertia[i, j]:.9g}"' for a, i, j in
                                               (("xx", 0, 0), ("xy", 0, 1), ("xz", 0, 2), ("yy", 1, 1), ("yz", 1, 2),
                                                ("zz", 2, 2))) + '/></inertial>', '  </link>']
    for name, parent, child, xyz, rpy, axis, limit in CHAIN:
        lines.append(f'  <joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
                     f'<origin xyz="{vec(xyz)}" rpy="{vec(rpy)}"/><axis xyz="{vec(axis)}"/>'
                     f'<limit lower="{-limit:.6f}" upper="{limit:.6f}" effort="150" velocity="3.15"/>'
                     '<dynamics damping="0.0" friction="0.0"/></joint>')
    for link, parent, xyz, rpy in (("ee_link", "wrist_3_link", (0, 0.0823, 0), (0, 0, np.pi / 2)),
                                   ("tool0", "wrist_3_link", (0, 0.0823, 0), (-np.pi / 2, 0, 0)),
                                   ("base", "base_link", (0, 0, 0), (0, 0, np.pi))):
        lines += [f'  <link name="{link}"/>', f'  <joint name="{parent}-{link}_fixed_joint" type="fixed"><parent '
                  f'link="{parent}"/><child link="{link}"/><origin xyz="{vec(xyz)}" rpy="{vec(rpy)}"/></joint>']
    return "\n".join([*lines, "</robot>", ""])


def real_arm(path: Path, loaded: bool):
    """The real arm in MuJoCo: its URDF, the rotors' armature, the tool at the flange where ``loaded``."""
    import mujoco

    spec = mujoco.MjSpec.from_file(str(path))
    spec.compiler.fusestatic = False
    for name, armature in zip(JOINTS, ARMATURE, strict=True):
        joint = spec.joint(name)
        joint.armature, joint.damping, joint.frictionloss = float(armature), [0.0, 0.0, 0.0], 0.0
    if loaded:
        tool = spec.body("tool0").add_body(name="tool")
        tool.mass, tool.ipos, tool.fullinertia = TOOL["mass"], list(TOOL["com"]), list(TOOL["inertia"])
        tool.explicitinertial = True
    model = spec.compile()
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT | mujoco.mjtDisableBit.mjDSBL_CONTACT
    return model


def rigid_torque(model, q, qd, qdd) -> np.ndarray:
    """MuJoCo's inverse dynamics at each sample (N m)."""
    import mujoco

    data, out = mujoco.MjData(model), np.empty_like(q)
    for i in range(len(q)):
        data.qpos[:], data.qvel[:], data.qacc[:] = q[i], qd[i], qdd[i]
        mujoco.mj_inverse(model, data)
        out[i] = data.qfrc_inverse
    return out


def friction(q, qd, clean: bool) -> np.ndarray:
    """The real drives' friction and the torque sensor's offset (N m)."""
    step = np.tanh(qd / COULOMB_VELOCITY)
    if clean:
        return VISCOUS * qd + COULOMB * step + OFFSET
    level = COULOMB * (1 + RIPPLE * np.sin(q + np.arange(len(JOINTS))))
    breakaway = STRIBECK * COULOMB * np.exp(-(qd / STRIBECK_VELOCITY) ** 2)
    return VISCOUS * qd + (level + breakaway) * step + OFFSET


def motion(rng, t) -> tuple:
    """A random five-harmonic trajectory about the working pose, scaled into each joint's reach: q, qd, qdd."""
    base = 2 * np.pi * rng.uniform(0.08, 0.14)
    a, b = (rng.normal(size=(HARMONICS, len(JOINTS))) / np.arange(1, HARMONICS + 1)[:, None] for _ in range(2))

    def at(t, a, b):
        q, qd, qdd = (np.zeros((len(t), len(JOINTS))) for _ in range(3))
        for k in range(HARMONICS):
            w = base * (k + 1)
            s, c = np.sin(w * t)[:, None], np.cos(w * t)[:, None]
            q += a[k] * s + b[k] * c
            qd += w * (a[k] * c - b[k] * s)
            qdd -= w * w * (a[k] * s + b[k] * c)
        return q, qd, qdd

    period = np.linspace(0, 2 * np.pi / base, 4000)
    q, qd, qdd = at(period, a, b)
    q = q - q.mean(0)
    scale = np.min([reach / np.abs(x).max(0) for reach, x in zip(REACH, (q, qd, qdd), strict=True)], axis=0)
    a, b = a * scale, b * scale
    centre = POSE + rng.uniform(-0.3, 0.3, len(JOINTS)) - at(period, a, b)[0].mean(0)
    q, qd, qdd = at(t, a, b)
    return q + centre, qd, qdd


def write(out: Path, clean: bool, seed: int) -> list[Path]:
    rng = np.random.default_rng(seed)
    (out / "truth").mkdir(parents=True, exist_ok=True)
    (out / "description.urdf").write_text(urdf(NOMINAL, meshes=True))
    (out / "truth" / "real_arm.urdf").write_text(urdf(REAL, meshes=False))
    arms = {loaded: real_arm(out / "truth" / "real_arm.urdf", loaded) for loaded in (False, True)}
    names = [f"r{i:02d}" for i in range(1, 11)]
    signals = {}
    for name in names:
        n = int(rng.uniform(13, 18) / 0.002)
        t = np.arange(n) * 0.002 + rng.normal(0, 8e-5, n)
        t[0] = 0.0
        keep = rng.random(n) > 0.003
        if name == "r05":
            keep[3000:3012] = False  # 12 samples: a 26 ms interval
        t = np.sort(t[keep])
        q, qd, qdd = motion(rng, t)
        tau = rigid_torque(arms[name in LOADED], q, qd, qdd) + friction(q, qd, clean)
        signals[name] = {"t": t, "q": q, "qd": qd, "qdd": qdd, "tau": tau}
    noise = NOISE * np.concatenate([s["tau"] for s in signals.values()]).std(0)
    files = []
    for i, (name, s) in enumerate(signals.items()):
        s["tau_measured"] = s["tau"] + rng.normal(size=s["tau"].shape) * noise
        s["q_measured"] = np.round(s["q"] / ENCODER) * ENCODER
        np.savez(out / "truth" / f"{name}.npz", **s, loaded=name in LOADED)
        table = np.concatenate([(EPOCH + 100 * i + s["t"])[:, None], s["q_measured"], s["tau_measured"]], 1)
        header = ",".join(["timestamp", *(f"actual_q_{j}" for j in range(6)), *(f"joint_torque_{j}" for j in range(6))])
        np.savetxt(out / f"{name}.csv", table, delimiter=",", header=header, comments="",
                   fmt=["%.6f"] + ["%.7f"] * 6 + ["%.4f"] * 6)
        files.append(out / f"{name}.csv")
    config = {"label": "ur5_like", "time": "timestamp", "coordinates": [f"actual_q_{j}" for j in range(6)],
              "inputs": [f"joint_torque_{j}" for j in range(6)],
              "robot": {"source": "description.urdf", "flange": "tool0"},
              "conventions": "q: the joint angles as the URDF defines them (rad); tau: measured joint torques (N m)",
              "friction": True,
              "parameters": {"values": {name: "box" for name in LOADED}, "tools": {"box": {"mass": TOOL["mass"]}}},
              "split": {"train": names[:5], "val": names[5:7], "test": names[7:]}}
    import yaml

    kind = "the drive model's friction only" if clean else "friction the drive model lacks"
    (out / "import.yaml").write_text(f"# written by scripts/other_arm_recordings.py: ten logs of a UR5-like arm "
                                     f"({kind})\n" + yaml.safe_dump(config, sort_keys=False, default_flow_style=None))
    return files


def floor(dataset: str, folder: Path) -> dict:
    """Per held-out recording of ``dataset``: the real arm's joint-torque RMS error (N m, per joint and the mean)
    against the measured torques at the configuration's targets (``configs/real_panda.yaml``'s data.targets)."""
    from lnn_torch.data import read_dataset
    from lnn_torch.training import TrajectoryDataModule

    names = json.loads(read_dataset(dataset).attrs["recordings"])
    dm = TrajectoryDataModule(path=dataset, targets={"method": "butterworth", "cutoff": 10.0, "order": 4,
                                                     "use_measured_velocity": True})
    test = dm.trajectories("test")
    clean = "drive model's friction only" in (folder / "import.yaml").read_text()
    arms = {loaded: real_arm(folder / "truth" / "real_arm.urdf", loaded) for loaded in (False, True)}
    result = {}
    for j, index in enumerate(test.index.tolist()):
        n = test.num_points if test.lengths is None else int(test.lengths[j])
        q, qd, qdd, tau = (getattr(test, k)[j, :n].double().numpy() for k in ("q", "qd", "qdd", "tau"))
        name = names[int(index)]
        model = rigid_torque(arms[name in LOADED], q, qd, qdd) + friction(q, qd, clean)
        rms = np.sqrt(((model - tau) ** 2).mean(0))
        result[name] = {"rms": rms.tolist(), "rms_mean": float(rms.mean())}
    return result


def main() -> None:
    args = parser().parse_args()
    out = Path(args.output_dir)
    if args.floor:
        for name, row in floor(args.floor, out).items():
            print(f"{name}: the real arm's own error {row['rms_mean']:.3f} N m (per joint "
                  + ", ".join(f"{x:.3f}" for x in row["rms"]) + ")")
        return
    if (out / "import.yaml").exists() and not args.overwrite:
        raise SystemExit(f"{out / 'import.yaml'} exists: pass --overwrite to replace the recordings")
    files = write(out, args.clean, args.seed)
    print(f"import them with: lnn-torch import {out}/r*.csv --config {out}/import.yaml -o DATASET.h5")
    wrote(out / "description.urdf", out / "import.yaml", out / "truth", f"{out}/r*.csv ({len(files)} files)")


if __name__ == "__main__":
    main()
