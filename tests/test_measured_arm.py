"""Export and control of a model learned from a robot arm's recordings (issue 36): a recording of the
Panda as a lab logs it (its description without the hand, armature and damping zero, simulated by
MuJoCo: joint angles, velocities and torques of a tracking motion), imported with its description
(``lnn-torch import``), the grey box of ``configs/real_panda.yaml`` fitted for a few steps; then every
exported function equal to the eager model on arm states within the joint ranges (``.pt2``; and
AOTInductor, slow), and ``lnn-torch control`` moving the arm's description (MuJoCo) to a goal.
One thread: the recording, import and fit about 15 s; the AOTInductor test several minutes."""

from __future__ import annotations

import copy
import dataclasses
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch

mujoco = pytest.importorskip("mujoco")
pytestmark = pytest.mark.slow  # the fixture alone (a recording, its import and a short fit) takes 15-20 s

from lnn_torch.cli import main  # noqa: E402
from lnn_torch.commands.config_files import read_config  # noqa: E402
from lnn_torch.export import programs as ex  # noqa: E402
from lnn_torch.robots.mujoco_arm import MujocoArm  # noqa: E402
from lnn_torch.training.checkpoints import load_model  # noqa: E402

from .helpers import ROOT, cli_in_process, session_file  # noqa: E402
from .test_export import (  # noqa: E402
    arguments,
    assert_close_float32,
    assert_onnx_equals_eager,
    assert_programs_equal_eager,
    eager,
)
from .test_recordings import write_csv  # noqa: E402

ROBOT = {"source": "franka_panda", "remove": ["hand"], "armature": "zero", "damping": "zero"}
HOME = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])


def record(path, seconds: float = 4.0, dt: float = 0.002, seed: int = 0, feedback=None, noise: float = 0.0,
           robot=None, payload=None, friction=None):
    """The arm (``ROBOT``, by MuJoCo) tracking a sum of sines about its home configuration by computed torque
    on its own dynamics: time, joint angles (rad), velocities (rad/s) and torques (N m) every ``dt``. With
    ``noise`` (rad/s) the recorded velocities hold white noise of that size, and with ``feedback`` (gains
    per joint, N m s/rad) the arm's controller answers it: the applied (and recorded) torque holds
    ``-feedback * noise`` (``lnn_torch.identification.velocity_feedback``). ``robot``: another
    description (default ``ROBOT``); ``payload``: a load it carries at the flange (mass, centre of mass);
    ``friction``: the drives' friction torque ``friction(qd)``, which the recorded torque overcomes too."""
    arm = MujocoArm(ROBOT if robot is None else robot)
    rng = np.random.default_rng(seed)
    amp, freq, phase = rng.uniform(0.2, 0.4, 7), rng.uniform(0.3, 0.8, 7), rng.uniform(0, 2 * np.pi, 7)
    gains = np.zeros(7) if feedback is None else np.asarray(feedback, dtype=np.float64)
    q, qd = HOME.copy(), np.zeros(7)
    arm.start(q, qd, payload)
    load = None if payload is None else np.asarray(payload, dtype=np.float64)[None]
    rows = {"time": [], **{f"{k}{j}": [] for k in ("q", "dq", "tau") for j in range(1, 8)}}
    for k in range(int(round(seconds / dt))):
        t = k * dt
        w = 2 * np.pi * freq
        ref = HOME + amp * (np.sin(w * t + phase) - np.sin(phase))
        ref_d, ref_dd = amp * w * np.cos(w * t + phase), -amp * w**2 * np.sin(w * t + phase)
        qdd = ref_dd + 100.0 * (ref - q) + 20.0 * (ref_d - qd)
        measured = rng.normal(0.0, noise, 7) if noise else np.zeros(7)
        tau = arm.inverse(q[None], qd[None], qdd[None], payload=load)[0].numpy() - gains * measured
        recorded = tau if friction is None else tau + friction(qd)
        rows["time"].append(t)
        for j in range(7):
            rows[f"q{j + 1}"].append(q[j]), rows[f"dq{j + 1}"].append(qd[j] + measured[j])
            rows[f"tau{j + 1}"].append(recorded[j])
        arm.hold(tau, dt, 2)
        q, qd = arm.state()
    return write_csv(path, rows)


@pytest.fixture(scope="module")
def learned(tmp_path_factory):
    """``(checkpoint, module)``: the grey box of ``configs/real_panda.yaml`` fitted for 20 steps on the
    recording, imported as ``configs/import/real_panda.yaml`` imports the real one (once per test session:
    the pytest-xdist workers share the checkpoint, ``session_file``)."""
    from lnn_torch.data.importer import ImportSpec, import_recordings

    def fit(path):
        root = Path(tempfile.mkdtemp(prefix="measured_arm_", dir=path.parent))
        csv = record(root / "arm.csv")
        spec = ImportSpec(time="time", coordinates=[f"q{j}" for j in range(1, 8)],
                          velocities=[f"dq{j}" for j in range(1, 8)], inputs=[f"tau{j}" for j in range(1, 8)],
                          coord_names=[f"joint{j}" for j in range(1, 8)], robot=ROBOT, friction=True,
                          coulomb_velocity=0.02, label="synthetic_panda",
                          split={"train": ["arm[0.2:3.0]"], "val": ["arm[3.0:3.5]"], "test": ["arm[3.5:3.9]"]})
        data = import_recordings([csv], root / "arm.h5", spec)
        out = cli_in_process("fit", "-c", str(ROOT / "configs" / "real_panda.yaml"), "--data.path", str(data),
                             "--trainer.max_steps", "20", "--trainer.enable_progress_bar", "false", cwd=root)
        assert out.returncode == 0, out.stderr[-3000:]
        (ckpt,) = root.glob("lightning_logs/version_*/checkpoints/last.ckpt")
        shutil.copyfile(ckpt, path)

    ckpt = session_file(tmp_path_factory, "measured_arm.ckpt", fit)
    return str(ckpt), load_model(str(ckpt))


def arm_states(n, dtype, seed=1):
    """Arm states within the joint ranges (0.1 rad inside each end), velocities up to 1.5 rad/s, torques up
    to 20 N m, accelerations N(0, 3) rad/s^2; no parameters (a measured arm has none)."""
    arm = MujocoArm(ROBOT)
    rng = np.random.default_rng(seed)
    q = torch.tensor(arm.sample_q(rng, n, margin=0.1))
    qd = torch.tensor(rng.uniform(-1.5, 1.5, (n, 7)))
    tau = torch.tensor(rng.uniform(-20.0, 20.0, (n, 7)))
    qdd = torch.tensor(rng.normal(0.0, 3.0, (n, 7)))
    return q.to(dtype), qd.to(dtype), torch.zeros(n, 0, dtype=dtype), tau.to(dtype), qdd.to(dtype)


def test_the_model_learned_from_arm_recordings_is_the_arms_grey_box(learned):
    _, module = learned
    model = module.model
    assert module.system.name == "measured" and module.system.num_params == 0 and module.system.num_inputs == 7
    assert json.loads(model.scene.robot_description)["remove"] == ["hand"]
    assert ex.available_functions(module) == ex.FUNCTIONS


def test_every_exported_function_of_the_learned_arm_equals_the_eager_model(learned):
    """``.pt2`` programs of every function in float64 on arm states, to 1e-10 (the model's own float32:
    the AOTInductor test)."""
    _, module = learned
    assert_programs_equal_eager(module, arm_states(17, torch.float64), torch.float64)


@pytest.mark.skipif(shutil.which("g++") is None and shutil.which("clang++") is None, reason="no C++ compiler")
def test_every_format_of_the_learned_arm_equals_the_eager_model(learned, tmp_path):
    """``lnn-torch export CKPT --format pt2 aoti --functions mass_matrix`` (whose package once read the
    links' inertias wrongly, so that the forward dynamics' failed its first call in Cholesky; every
    function's ``.pt2``: the test above; ONNX where its optional packages are installed): both formats
    equal to the eager model on arm states at batch 1 and 33 (AOTInductor: 30-60 s per function on one
    thread, so one function here)."""
    ckpt, module = learned
    formats, functions = ["pt2", "aoti"], ["mass_matrix"]
    assert main(["export", ckpt, "-o", str(tmp_path), "--format", *formats, "--functions", *functions]) == 0
    meta = json.loads((tmp_path / "export.json").read_text())
    assert meta["scene"]["name"] == "measured" and list(meta["functions"]) == functions
    model = copy.deepcopy(module.model)
    for function in functions:
        for fmt in formats:
            program = ex.load_program(tmp_path / ex.output_name(function, fmt))
            for batch in (1, 33):
                q, qd, params, tau, qdd = arm_states(batch, torch.float32, seed=batch)
                with torch.no_grad():
                    out = program(*arguments(function, q, qd, params, tau, qdd))
                    ref = eager(model, function, q, qd, params, tau, qdd)
                assert_close_float32(out, ref, f"{function} {fmt} batch {batch}")


def test_onnx_of_the_learned_arm_equals_the_eager_model(learned, tmp_path):
    """ONNX (optional packages: ``pip install 'lnn-torch[export]'``) of every function through ONNX Runtime."""
    ort = pytest.importorskip("onnxruntime", reason="ONNX Runtime is not installed (optional: lnn-torch[export])")
    if ex.missing_onnx_packages():
        pytest.skip(ex.onnx_requirement())
    _, module = learned
    ex.export_model(module, tmp_path, formats=["onnx"], dtype="float64")
    assert_onnx_equals_eager(ort, module, tmp_path, ex.FUNCTIONS, [arm_states(9, torch.float64)])


def test_control_moves_the_arms_description_with_the_learned_model(learned, tmp_path):
    """``lnn-torch control CKPT -c configs/control/real_panda_reach.yaml`` (2 episodes, 3 s): designed on
    the model learned from the recordings, run on the robot's description through MuJoCo (``robot:
    model``): every episode reaches the goal and the report names the reach path; the same model on the
    scenario of the simulated arm with a 2 kg payload says that the model does not know the payload."""
    ckpt, _ = learned
    scenario = read_config(ROOT / "configs" / "control" / "real_panda_reach.yaml")
    assert scenario["plant"] == {"robot": "model"} and scenario["controller"]["kind"] == "reach"
    path = tmp_path / "reach.json"
    path.write_text(json.dumps({**scenario, "duration": 3.0}))
    out = tmp_path / "reach"
    assert main(["control", ckpt, "-c", str(path), "--episodes", "2", "--no-animation", "-o", str(out)]) == 0
    report = json.loads((out / "control.json").read_text())
    assert report["success_rate"] == 1.0, report
    assert report["plant"].startswith("franka_panda (remove=['hand'], armature=zero, damping=zero) (MuJoCo)")
    assert report["holding_torque_at_goal"]["largest_difference"] < 1.0, report
    text = (out / "report.md").read_text()
    assert "tracking error along the reach path" in text and "swing-up" not in text

    sim = read_config(ROOT / "configs" / "control" / "robot_arm_reach.yaml")
    path.write_text(json.dumps({**sim, "duration": 0.5, "success": {**sim["success"], "hold": 0.25}}))
    assert main(["control", ckpt, "-c", str(path), "--episodes", "1", "--no-animation", "-o", str(out)]) == 0
    report = json.loads((out / "control.json").read_text())
    assert report["unknown_to_the_model"]["params"] == sim["plant"]["params"]
    assert "are unknown to the model" in (out / "report.md").read_text()


def test_identify_finds_the_arms_feedback_on_its_measured_velocity(learned, tmp_path):
    """``lnn-torch identify CKPT DATA --feedback`` on a recording whose controller answers the noise of its
    measured velocities with known gains: the rows ``+ velocity feedback`` recover the gains (fitted on the
    training split) and remove that torque from the error on the held-out one."""
    from lnn_torch.data.importer import ImportSpec, import_recordings

    ckpt, _ = learned
    # the arm with its rotors (Menagerie's armature, 0.1 kg m^2): the feedback torque then moves each joint
    # too little to show in its velocity, as on a real arm (without them the wrist's links alone, a few
    # hundredths of a kg m^2, answer the noise, and the recorded velocity no longer holds it alone)
    rotors = {**ROBOT, "armature": "as_written"}
    D = np.array([25.0, 30.0, 20.0, 30.0, 6.0, 5.0, 3.0])
    csv = record(tmp_path / "arm.csv", seed=3, feedback=D, noise=0.01, robot=rotors)
    spec = ImportSpec(time="time", coordinates=[f"q{j}" for j in range(1, 8)],
                      velocities=[f"dq{j}" for j in range(1, 8)], inputs=[f"tau{j}" for j in range(1, 8)],
                      coord_names=[f"joint{j}" for j in range(1, 8)], robot=rotors, friction=True,
                      label="synthetic_panda", split={"train": ["arm[0.2:3.0]"], "val": ["arm[3.0:3.5]"],
                                                      "test": ["arm[3.5:3.7]", "arm[3.7:3.9]"]})
    data = import_recordings([csv], tmp_path / "arm.h5", spec)
    assert main(["identify", ckpt, str(data), "--feedback", "-o", str(tmp_path / "id")]) == 0
    result = json.loads((tmp_path / "id" / "identification.json").read_text())
    rows = result["rows"]
    # not the model's own dataset (another recording of the arm): said, as the fits and the excitation are its
    assert result["note"].startswith(f"{data} is not the dataset this model was trained on (")
    assert "Note: " in (tmp_path / "id" / "report.md").read_text()
    # each recording of the split on its own too (the measure: every held-out log), in the report as well
    per = result["per_recording"]
    assert list(per) == ["arm[3.5:3.7]", "arm[3.7:3.9]"], list(per)
    assert all(set(errors) == {k for k in rows if "velocity feedback" not in k} for errors in per.values())
    assert per["arm[3.5:3.7]"] != per["arm[3.7:3.9]"] and "Per recording of the split" in \
        (tmp_path / "id" / "report.md").read_text()
    # what the training window determines: the excitation and an interval per coefficient, in the report too
    u = result["uncertainty"]
    assert 0 < u["condition_number"] < float("inf") and len(u["interval95"]) == len(u["names"])
    assert all(lo <= v <= hi for v, (lo, hi) in zip(u["value"], u["interval95"], strict=True))
    assert "What the training recordings determine" in (tmp_path / "id" / "report.md").read_text()
    # the consistent row's own prior (chosen on validation for its weighting and drive model) is named
    assert "The prior towards the description of physically consistent" in (tmp_path / "id" / "report.md").read_text()
    consistent = "physically consistent + viscous+coulomb+offset"
    for base in ("film_lnn", "least squares + viscous+coulomb+offset", consistent):
        with_it = rows[f"{base} + velocity feedback"]
        assert all(with_it["feedback"]["kept"])
        np.testing.assert_allclose(with_it["feedback"]["gains"], D, rtol=0.1)
        assert with_it["rms_mean"] < rows[base]["rms_mean"]
    # a fit of this recording's rigid body (the rotors included; the checkpoint was fitted without them)
    # misses little else: the feedback torque (0.03-0.3 N m RMS per joint) was most of its error
    assert rows[f"{consistent} + velocity feedback"]["rms_mean"] < 0.5 * rows[consistent]["rms_mean"]


def test_identify_returns_the_load_a_new_recording_carries(learned, tmp_path, capsys):
    """A new log of the arm carrying a load nobody measured (imported alone, ``tools: {load: {}}``, all of it
    held out): ``lnn-torch identify CKPT new.h5`` identifies the load against the model's own arm (mass
    within 2 %, centre of mass within 5 mm; the interval's width stated) and says the classical comparison
    needs a training split; ``lnn-torch export CKPT --format mjcf --tool new.h5 load`` writes that load as
    the description's payload body."""
    from lnn_torch.data.importer import ImportSpec, import_recordings

    ckpt, _ = learned
    load = [1.2, 0.03, -0.02, 0.07]
    csv = record(tmp_path / "new.csv", seconds=3.0, seed=5, payload=load)
    spec = ImportSpec(time="time", coordinates=[f"q{j}" for j in range(1, 8)],
                      velocities=[f"dq{j}" for j in range(1, 8)], inputs=[f"tau{j}" for j in range(1, 8)],
                      coord_names=[f"joint{j}" for j in range(1, 8)], robot=ROBOT, friction=True,
                      label="synthetic_panda", parameters={"values": {"new": "load"}, "tools": {"load": {}}},
                      split={"train": [], "val": [], "test": ["new"]})
    data = import_recordings([csv], tmp_path / "new.h5", spec)
    assert main(["identify", ckpt, str(data), "-o", str(tmp_path / "id")]) == 0
    printed = capsys.readouterr().out
    result = json.loads((tmp_path / "id" / "identification.json").read_text())
    tool = result["tools"]["tools"]["load"]
    got = [tool["parameters"][k]["value"] for k in ("mass", "x", "y", "z")]
    assert abs(got[0] / load[0] - 1) < 0.02 and np.abs(np.subtract(got[1:], load[1:])).max() < 5e-3, got
    assert tool["recordings"] == ["new"] and "the model's arm" in result["tools"]["against"]
    assert "no training split" in result["comparison"] and "Loads identified against the model" in printed
    assert "they hold the torque noise, not what the fit leaves out (a point tool's own inertia" in printed
    assert "rows" not in result  # a model of the bare arm cannot carry the load: no error of its own
    # a new log without a load, imported alone: no classical comparison, the model's own error all the same
    alone = dataclasses.replace(spec, parameters=None, split={"train": [], "val": [], "test": ["bare"]})
    bare = import_recordings([record(tmp_path / "bare.csv", seconds=1.0, seed=6)], tmp_path / "bare.h5", alone)
    assert main(["identify", ckpt, str(bare), "-o", str(tmp_path / "bare")]) == 0
    printed = capsys.readouterr().out
    result = json.loads((tmp_path / "bare" / "identification.json").read_text())
    (model_row, description_row) = result["rows"].values()
    assert list(result["rows"])[1] == "description as written" and "Joint-torque RMS error on the split" in printed
    assert "no training split" in result["comparison"]
    # (the recording is the description's own arm: both explain it to a few per cent of its torques)
    assert max(model_row["rms_mean"], description_row["rms_mean"]) < 0.05 * np.mean(list(result["torque_std"].values()))
    # and the identified arm handed back with that tool as its payload body (the import's identification)
    import mujoco

    from lnn_torch.commands.export import tool_row

    row, how = tool_row(str(data), "load", load_model(ckpt), ckpt)
    assert abs(row[0] / load[0] - 1) < 0.02 and how.startswith("identified against the model from this split")
    assert row == got  # as identify identified it
    out = tmp_path / "arm.xml"
    assert main(["export", ckpt, "--format", "mjcf", "--tool", str(data), "load", "-o", str(out)]) == 0
    written = mujoco.MjModel.from_xml_path(str(out))
    body = mujoco.mj_name2id(written, mujoco.mjtObj.mjOBJ_BODY, "payload")
    assert abs(written.body_mass[body] - row[0]) < 1e-9
    np.testing.assert_allclose(written.body_ipos[body], row[1:4], atol=1e-9)


def test_identify_compares_the_model_on_a_new_log_with_the_load_identified_against_it(tmp_path, capsys):
    """A new loaded log held out beside an unloaded one split in time (the classical fits' training and
    validation windows), and a grey box that conditions on the payload (the description's, untrained): the
    import identifies the new load against the classical arm, ``identify`` against the model, from the held-out
    log (no other carries it); the model's row is its error with the load identified against it, the classical
    rows use the dataset's; so is its row with the robot's velocity feedback (``--feedback``). A load the
    training recordings carry is identified from those, never from the recordings judged: the same whichever
    split is judged."""
    from lnn_torch.commands.identify import tools_on_split
    from lnn_torch.data import read_dataset
    from lnn_torch.data.importer import ImportSpec, import_recordings
    from lnn_torch.identification.arm_comparison import feedback_rows, model_torque, points
    from lnn_torch.training import LNNModule
    from lnn_torch.training.datamodule import TrajectoryDataModule

    from .helpers import save_checkpoint

    load = [1.2, 0.03, -0.02, 0.07]
    csv = record(tmp_path / "new.csv", seconds=4.0, seed=5, payload=load, friction=None)
    base = record(tmp_path / "base.csv", seconds=4.0, seed=6, friction=None)
    spec = ImportSpec(time="time", coordinates=[f"q{j}" for j in range(1, 8)],
                      velocities=[f"dq{j}" for j in range(1, 8)], inputs=[f"tau{j}" for j in range(1, 8)],
                      coord_names=[f"joint{j}" for j in range(1, 8)], robot=ROBOT, friction=True,
                      label="synthetic_panda", parameters={"values": {"new": "load"}, "tools": {"load": {}}},
                      split={"train": ["base[0:3.0]"], "val": ["base[3.0:]"], "test": ["new"]})
    data = import_recordings([csv, base], tmp_path / "new.h5", spec)
    targets = {"method": "butterworth", "cutoff": 10.0, "order": 4, "use_measured_velocity": True}
    dm = TrajectoryDataModule(path=str(data), targets=targets)
    scene, config = dm.model_scene()
    module = LNNModule(scene=scene, scene_config=config, torque_weight=1.0, acceleration_weight=0.0, eps=0.0,
                       model_options={"kinetic": {"spatial": {"prior": 1.0e-4}}, "potential": {"spatial": {}},
                                      "friction": "viscous+coulomb+offset"})
    module.model.fit_normalizer(dm.normalization_data())
    ckpt = save_checkpoint(module, tmp_path / "grey.ckpt")
    raw = torch.load(ckpt, weights_only=False)
    raw["datamodule_hyper_parameters"] = {"path": str(data), "targets": targets}
    torch.save(raw, ckpt)
    assert main(["identify", ckpt, str(data), "--feedback", "-o", str(tmp_path / "id")]) == 0
    printed = capsys.readouterr().out
    assert "the model carries the loads the import left unknown as identified against it" in printed
    assert "not the dataset this model was trained on" not in printed  # (its own)
    result = json.loads((tmp_path / "id" / "identification.json").read_text())
    assert result["tools"]["tools"]["load"]["from"] == "this split's recordings"
    tool = result["tools"]["tools"]["load"]["parameters"]
    own = torch.tensor([[tool[k]["value"] for k in ("mass", "x", "y", "z")]], dtype=torch.float64)
    model = load_model(ckpt).model.double()
    q, qd, qdd, tau, params = points(dm.trajectories("test"))

    def mean_rms(p):
        return float((model_torque(model)(q, qd, qdd, p) - tau).pow(2).mean(0).sqrt().mean())

    mine, dataset = mean_rms(own.expand(len(q), -1)), mean_rms(params)
    got = result["rows"]["film_lnn"]["rms_mean"]  # (identify runs the model in its own float32)
    assert abs(got - mine) < 1e-4 * mine and abs(got - dataset) > 1e-3 * dataset, (got, mine, dataset)
    names = result["joints"]
    mine, dataset = (feedback_rows(dm, {"m": model_torque(model)}, names, split_params=loads)["m + velocity feedback"]
                     ["rms_mean"] for loads in ({"m": own}, None))
    got = result["rows"]["film_lnn + velocity feedback"]["rms_mean"]
    assert abs(got - mine) < 1e-4 * mine and abs(got - dataset) > 1e-3 * dataset, (got, mine, dataset)
    # the loaded log split in time: the load from its training and validation windows, whichever split is judged
    spec.split = {"train": ["new[0:2.0]"], "val": ["new[2.0:2.5]"], "test": ["new[2.5:]"]}
    windows = import_recordings([csv], tmp_path / "windows.h5", spec)
    dm = TrajectoryDataModule(path=str(windows), targets=targets)
    loads = {split: tools_on_split(load_model(ckpt), read_dataset(windows), dm, split) for split in ("val", "test")}
    assert loads["test"][0]["tools"]["load"]["from"] == "training and validation recordings"
    assert loads["val"][0]["tools"]["load"]["from"] == ("training and validation recordings (the judged split "
                                                        "among them)")
    torch.testing.assert_close(loads["val"][1][0], loads["test"][1][0], rtol=0, atol=0)
