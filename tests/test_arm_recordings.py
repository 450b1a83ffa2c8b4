"""Robot-arm recordings as a lab has them (``lnn_torch.data.importer``): irregular stamps and gaps
repaired and reported, time windows of one recording as the split, known parameters per recording
(a payload or a named tool), motor currents with drive gains, the robot's description with the scene."""

import json

import numpy as np
import pytest
import torch

from lnn_torch import load_model
from lnn_torch.data import read_dataset
from lnn_torch.data.importer import ImportSpec, import_recordings
from lnn_torch.data.resampling import resampling_report
from lnn_torch.errors import InputError
from lnn_torch.training.datamodule import TrajectoryDataModule

from .helpers import quiet_trainer
from .test_recordings import write_csv

TARGETS = {"method": "butterworth", "cutoff": 10.0, "order": 4, "use_measured_velocity": False}


def signals(t: np.ndarray, phase: float = 0.0) -> dict:
    """Smooth two-joint motion (rad) and torques (N m) at times ``t``."""
    return {"time": t, "a": np.sin(1.3 * t + phase), "b": 0.5 * np.cos(2.1 * t + phase),
            "ta": np.cos(0.7 * t), "tb": np.sin(0.9 * t + phase)}


def spec(**kw) -> ImportSpec:
    return ImportSpec(**{"coordinates": ["a", "b"], "inputs": ["ta", "tb"], **kw})


def test_gaps_are_resampled_and_reported_and_only_a_gap_too_long_is_refused(tmp_path):
    t = np.arange(0, 4, 0.001)
    t = np.delete(t, np.r_[1000:1008, 2500:2504])  # two gaps: 9 ms and 5 ms at 1 ms sampling
    path = write_csv(tmp_path / "run.csv", signals(t))
    out = import_recordings([path], tmp_path / "run.h5", spec(split=[1.0, 0.0, 0.0]))
    (line,) = resampling_report(json.loads(read_dataset(out).attrs["provenance"]))
    assert "2 gaps over twice the median interval (largest 9 ms, 14 ms in all) interpolated across" in line
    assert read_dataset(out).num_points == 4000  # the whole span on the 1 ms grid
    t2 = np.delete(t, np.r_[3000:3030])  # a 31 ms gap: more than 25 median intervals
    long = write_csv(tmp_path / "long.csv", signals(t2))
    with pytest.raises(InputError, match=r"a gap of 0.031 s .* exceeds max_gap 0.025 s: too long to interpolate "
                                         r"across; split the recording there with windows, e.g. long\[0:3.011\] and "
                                         r"long\[3.042:\]"):
        import_recordings([long], tmp_path / "long.h5", spec(split=[1.0, 0.0, 0.0]))
    windows = {"train": ["long[0:2.5]"], "val": ["long[2.5:3.5]"], "test": ["long[3.5:]"]}
    with pytest.raises(InputError, match=r"the window 'long\[2.5:3.5\]' crosses it: end it by 3.011 s or start it "
                                         r"from 3.042 s"):
        import_recordings([long], tmp_path / "long.h5", spec(split=windows))
    # windows clear of the gap import; the filters' context beside a window stops at the gap (as at a recording's end)
    windows = {"train": ["long[0:2.0]"], "val": ["long[2.0:2.9]"], "test": ["long[3.1:]"]}
    out = import_recordings([long], tmp_path / "long.h5", spec(split=windows))
    entries = {e["name"]: e for e in json.loads(read_dataset(out).attrs["provenance"])["entries"]}
    assert entries["long[2.0:2.9]"]["to_s"] == pytest.approx(3.011)
    assert entries["long[3.1:]"]["from_s"] == pytest.approx(3.042)
    (line,) = resampling_report(json.loads(read_dataset(out).attrs["provenance"]))
    assert "interpolated across, but for 1 beyond max_gap (25 ms), which no window in use crosses" in line


def test_a_gap_in_epoch_seconds_gives_windows_that_hold_and_advice_that_imports(tmp_path):
    """Time stamps in seconds since 1970 (their rounding about 2e-7 s): windows that end or start at a gap's edge
    hold only recorded samples (no NaN, no empty slice), and the windows the refusal suggests import."""
    t = 1_700_000_000.123 + 0.001 * np.arange(5000)
    t = np.delete(t, np.r_[2022:2061])  # a gap of 40 ms after sample 2021
    path = write_csv(tmp_path / "run.csv", signals(t - t[0]) | {"time": t})
    with pytest.raises(InputError, match=r"split the recording there with windows, e.g. run\[0:(?P<a>[\d.]+)\] and "
                                         r"run\[(?P<b>[\d.]+):\]") as err:
        import_recordings([path], tmp_path / "x.h5", spec(split=[1.0, 0.0, 0.0]))
    import re

    a, b = re.search(r"run\[0:([\d.]+)\] and run\[([\d.]+):\]", str(err.value)).groups()
    for windows in ({"train": [f"run[0:{a}]"], "val": [], "test": [f"run[{b}:]"]},
                    {"train": ["run[0:2.021]"], "val": [], "test": ["run[2.061:]"]}):
        out = import_recordings([path], tmp_path / "x.h5", spec(split=windows), overwrite=True)
        f = read_dataset(out)
        w, lengths, q = np.asarray(f.read("windows")), np.asarray(f.read("lengths")), np.asarray(f.read("q"))
        for (lo, hi), n, qj in zip(w, lengths, q, strict=True):
            assert 0 <= lo < hi <= n and np.isfinite(qj[lo:hi]).all(), (windows, lo, hi, n)


def test_time_windows_are_entries_cut_after_the_filters_saw_the_recording_around_them(tmp_path):
    """A recording split into windows: its samples are the whole recording's at the same times, and its
    derivative estimates equal those of the whole recording there to the filter's edge effect beyond
    the 0.5 s of context (measured: 2.1e-6 of the largest velocity, 5.7e-5 of the largest
    acceleration); overlapping windows of two splits are refused."""
    t = np.arange(0, 12, 0.002)
    path = write_csv(tmp_path / "run.csv", signals(t))
    whole = import_recordings([path], tmp_path / "whole.h5", spec(split={"train": ["run"]}))
    split = {"train": ["run[1:6]"], "val": ["run[6:8]"], "test": ["run[8.5:11]"]}
    windows = import_recordings([path], tmp_path / "win.h5", spec(split=split))
    full = TrajectoryDataModule(path=str(whole), targets=TARGETS).trajectories("train")
    dm = TrajectoryDataModule(path=str(windows), targets=TARGETS)
    for part, (start, end) in zip(("train", "val", "test"), ((1, 6), (6, 8), (8.5, 11)), strict=True):
        data = dm.trajectories(part)
        a, b = round(start / 0.002), round(end / 0.002)
        assert int(data.lengths[0]) == b - a
        for key, tol in (("q", 0.0), ("tau", 0.0), ("qd", 1e-5), ("qdd", 2e-4)):
            got, ref = getattr(data, key)[0, : b - a], getattr(full, key)[0, a:b]
            torch.testing.assert_close(got, ref, rtol=0, atol=tol * float(ref.abs().max()))
    names = json.loads(read_dataset(windows).attrs["recordings"])
    assert names == ["run[1:6]", "run[6:8]", "run[8.5:11]"]
    with pytest.raises(InputError, match=r"'run\[5:8\]' \(val\) overlap"):
        import_recordings([path], tmp_path / "bad.h5", spec(split={"train": ["run[1:6]"], "val": ["run[5:8]"]}))
    with pytest.raises(InputError, match="unknown recording 'walk'"):
        import_recordings([path], tmp_path / "bad.h5", spec(split={"train": ["walk[1:6]"]}))


def test_parameters_per_recording_and_named_tools_are_stored_with_each_entry(tmp_path):
    t = np.arange(0, 3, 0.002)
    files = [write_csv(tmp_path / f"{name}.csv", signals(t, k)) for k, name in enumerate(("empty", "box", "grip"))]
    params = {"values": {"box": [1.5, 0.0, 0.01, 0.05], "grip": "gripper"},
              "tools": {"gripper": [0.8, 0.0, 0.0, 0.03]}}
    out = import_recordings(files, tmp_path / "p.h5", spec(robot=None, parameters={**params, "names": list("mxyz")},
                                                           split={"train": ["empty", "box"], "test": ["grip"]}))
    f = read_dataset(out)
    np.testing.assert_array_equal(np.asarray(f.read("params")), [[0, 0, 0, 0], [1.5, 0, 0.01, 0.05], [0.8, 0, 0, 0.03]])
    assert json.loads(f.attrs["param_names"]) == list("mxyz")
    with pytest.raises(InputError, match="unknown recording 'boxes'"):
        import_recordings(files, tmp_path / "q.h5", spec(parameters={"values": {"boxes": [1, 0, 0, 0]}}))
    with pytest.raises(InputError, match="names tool 'hand', which parameters.tools does not define"):
        import_recordings(files, tmp_path / "q.h5", spec(parameters={"values": {"box": "hand"}}))


def test_motor_currents_times_drive_gains_are_the_torques(tmp_path):
    t = np.arange(0, 2, 0.002)
    cols = signals(t)
    cols["ia"], cols["ib"] = cols["ta"] / 2.5, cols["tb"] / -0.4
    path = write_csv(tmp_path / "run.csv", cols)
    torques = import_recordings([path], tmp_path / "t.h5", spec(split=[1.0, 0.0, 0.0]))
    currents = import_recordings([path], tmp_path / "i.h5", spec(inputs=None, currents=["ia", "ib"],
                                                                drive_gains=[2.5, -0.4], split=[1.0, 0.0, 0.0]))
    np.testing.assert_allclose(read_dataset(currents).read("tau"), read_dataset(torques).read("tau"), rtol=1e-12)
    with pytest.raises(InputError, match="currents need drive_gains"):
        spec(inputs=None, currents=["ia", "ib"])


def test_a_robot_arms_recording_names_its_joints_and_carries_its_description(tmp_path):
    pytest.importorskip("mujoco")
    t = np.arange(0, 2, 0.002)
    cols = {"time": t, **{f"q{j}": 0.1 * np.sin(t + j) for j in range(7)}, **{f"u{j}": np.cos(t) for j in range(7)}}
    path = write_csv(tmp_path / "arm.csv", cols)
    robot = {"source": "franka_panda", "remove": ["hand"], "armature": "zero"}
    out = import_recordings([path], tmp_path / "arm.h5", ImportSpec(
        coordinates=[f"q{j}" for j in range(7)], inputs=[f"u{j}" for j in range(7)], robot=robot,
        parameters={"values": {"arm": [0.5, 0, 0, 0.1]}}, split=[1.0, 0.0, 0.0]))
    scene = json.loads(read_dataset(out).attrs["scene_json"])
    assert scene["coord_names"] == [f"joint{j}" for j in range(1, 8)]
    assert scene["config"]["description"]["remove"] == ["hand"]
    assert scene["param_names"] == ["payload_mass", "payload_x", "payload_y", "payload_z"]
    with pytest.raises(InputError, match="are not the joints of robot"):
        ImportSpec(coordinates=[f"q{j}" for j in range(7)], robot="franka_panda", coord_names=list("abcdefg"))
    # columns named as the description's joints need no coordinates; input names without input columns are refused
    named = {"time": t, **{f"joint{j + 1}": cols[f"q{j}"] for j in range(7)},
             **{f"u{j}": cols[f"u{j}"] for j in range(7)}}
    path = write_csv(tmp_path / "named.csv", named)
    out = import_recordings([path], tmp_path / "named.h5", ImportSpec(inputs=[f"u{j}" for j in range(7)], robot=robot,
                                                                     split=[1.0, 0.0, 0.0]))
    np.testing.assert_array_equal(read_dataset(out).read("q")[0], read_dataset(tmp_path / "arm.h5").read("q")[0])
    with pytest.raises(InputError, match="input_names names 2 inputs, but no input columns are given"):
        import_recordings([path], tmp_path / "bad.h5", ImportSpec(robot=robot, input_names=["a", "b"]))


def test_drive_gains_known_only_nominally_are_learned_one_per_input(tmp_path):
    """Currents imported with nominal gains (here 1: unknown); ``learn_input_matrix: gains`` gives the
    model ``B diag(k)`` with one positive gain per input, 1 at the start (the model as without it), the
    torques it needs divided by ``k``, a gradient from a torque loss, and the gains kept by a checkpoint."""
    from lnn_torch.networks import build_model
    from lnn_torch.systems import get_system

    t = np.arange(0, 2, 0.002)
    cols = signals(t)
    path = write_csv(tmp_path / "run.csv", cols)
    out = import_recordings([path], tmp_path / "i.h5", spec(inputs=None, currents=["ta", "tb"], drive_gains=[1.0, 1.0],
                                                            split=[1.0, 0.0, 0.0]))
    system = get_system("measured", **json.loads(read_dataset(out).attrs["scene_json"])["config"])
    torch.manual_seed(0)
    plain = build_model("film_lnn", system).double()
    torch.manual_seed(0)
    model = build_model("film_lnn", system, learn_input_matrix="gains").double()
    assert model.forces.input_gains().tolist() == [1.0, 1.0]
    q, qd, qdd = (torch.randn(5, 2, dtype=torch.float64) for _ in range(3))
    params = torch.zeros(5, 0, dtype=torch.float64)
    ref = plain.inverse(q, qd, qdd, params)
    torch.testing.assert_close(model.inverse(q, qd, qdd, params), ref, rtol=1e-12, atol=1e-12)
    k = torch.tensor([2.5, 0.4], dtype=torch.float64)
    with torch.no_grad():
        model.forces.input_gains_raw.copy_(k.log())
    torch.testing.assert_close(model.inverse(q, qd, qdd, params), ref / k, rtol=1e-10, atol=1e-12)
    model.inverse(q, qd, qdd, params).pow(2).sum().backward()
    assert model.forces.input_gains_raw.grad.abs().min() > 0
    assert model.forces.input_gains_raw in model.forces.coefficient_parameters()
    again = build_model("film_lnn", system, learn_input_matrix="gains").double()
    again.load_state_dict(model.state_dict())
    torch.testing.assert_close(again.forces.input_gains(), k)
    with pytest.raises(ValueError, match="learn_input_matrix must be"):
        build_model("film_lnn", system, learn_input_matrix="diagonal")


def test_a_force_residual_is_learned_only_where_validation_has_recordings_of_its_own(tmp_path, capsys):
    def fit_briefly(path, max_epochs=-1, max_steps=2, ckpt_path=None, **options):  # 2 steps a epoch
        from lnn_torch.training import LNNModule, TrajectoryDataModule

        dm = TrajectoryDataModule(path=str(path), chunk_len=4, chunks_per_batch=4, steps_per_epoch=2,
                                  targets={"method": "butterworth", "cutoff": 10.0})
        module = LNNModule(scene=scene, scene_config=config, model_options={"residual_force": {"local": True}},
                           val_rollouts=1, val_rollout_seconds=0.1, figure_every_n_epochs=0, compile=False,
                           **options)
        trainer = quiet_trainer(tmp_path, max_epochs=max_epochs, max_steps=max_steps, logger=False,
                                enable_checkpointing=False)
        trainer.fit(module, datamodule=dm, ckpt_path=ckpt_path)
        return trainer

    """Validation windows of the training recording (one trajectory split in time) cannot judge a force of the
    state: the model is built without its force residual (and saved so), and a line says why; validation
    recordings of their own leave it to be learned, for ``residual_min_steps`` steps; without a validation split
    it is left out too; ``learn_residual`` true or false overrides the judging."""
    from lnn_torch.training import LNNModule, TrajectoryDataModule

    t = np.arange(0, 4, 0.002)
    one = write_csv(tmp_path / "one.csv", signals(t))
    two = write_csv(tmp_path / "two.csv", signals(t, phase=0.5))
    windows = import_recordings([one], tmp_path / "w.h5", spec(split={"train": ["one[0:3]"], "val": ["one[3:]"],
                                                                      "test": []}))
    own = import_recordings([one, two], tmp_path / "r.h5", spec(split={"train": ["one"], "val": ["two"], "test": []}))
    for path, shared in ((windows, ["one"]), (own, [])):
        dm = TrajectoryDataModule(path=str(path))
        assert dm.shared_recordings() == shared
        scene, config = dm.model_scene()
        module = LNNModule(scene=scene, scene_config=config, model_options={"residual_force": {"local": True}})
        module._judge_residual(dm)
        assert (module.model.forces.residual is None) == bool(shared)
        assert ("residual_force" in module.hparams["model_options"]) != bool(shared)
        printed = capsys.readouterr().out
        assert ("force residual: left out: the validation windows come from the training recordings (one)"
                in printed) == bool(shared), printed
        # a run: residual_min_steps where the residual is learned (past an epoch limit too), the trainer's steps
        # where it is left out; the checkpoint loads as the model trained (with or without its residual)
        trainer = fit_briefly(path, max_epochs=1, max_steps=-1, residual_min_steps=4)
        assert trainer.global_step == (2 if shared else 4)
        assert ("4 steps (model.residual_min_steps) instead of 2" in capsys.readouterr().out) != bool(shared)
        trainer.save_checkpoint(tmp_path / f"{path.stem}.ckpt")
        assert (load_model(str(tmp_path / f"{path.stem}.ckpt")).model.forces.residual is None) == bool(shared)
    # init_from: a residual added beside a checkpoint without one is judged as any; learn_residual false drops one
    for path, start, options, dropped in ((windows, "w", {}, True), (own, "r", {"learn_residual": False}, True),
                                          (windows, "r", {}, False)):
        trainer = fit_briefly(path, init_from=str(tmp_path / f"{start}.ckpt"), **options)
        assert (trainer.lightning_module.model.forces.residual is None) == dropped, (path, start, options)
    # a resumed run whose set-up judged the residual otherwise takes the checkpoint's (and its raised steps)
    trainer = fit_briefly(own, ckpt_path=str(tmp_path / "r.ckpt"), learn_residual=False, max_steps=2)
    assert trainer.lightning_module.model.forces.residual is not None and trainer.max_steps == 4
    capsys.readouterr()
    # evaluating that checkpoint (as lnn-torch test does) resumes nothing: no line about its steps
    fresh = quiet_trainer(tmp_path, max_steps=2, logger=False, enable_checkpointing=False)  # its plan: 2 steps
    fresh.validate(trainer.lightning_module, datamodule=trainer.datamodule, ckpt_path=str(tmp_path / "r.ckpt"),
                   verbose=False)
    assert "a resumed run" not in capsys.readouterr().out
    unjudged = import_recordings([one, two], tmp_path / "n.h5", spec(split={"train": ["one"], "val": [],
                                                                            "test": ["two"]}))
    module = LNNModule(scene=scene, scene_config=config, model_options={"residual_force": {"local": True}})
    module._judge_residual(TrajectoryDataModule(path=str(unjudged)))  # no validation split: nothing judges it
    assert module.model.forces.residual is None
    assert "force residual: left out: the data have no validation split" in capsys.readouterr().out
    for wanted, path, kept in ((True, windows, True), (False, own, False)):  # learn_residual overrides the judging
        module = LNNModule(scene=scene, scene_config=config, model_options={"residual_force": {"local": True}},
                           learn_residual=wanted)
        module._judge_residual(TrajectoryDataModule(path=str(path)))
        assert (module.model.forces.residual is not None) == kept
    assert "force residual: left out: model.learn_residual is false" in capsys.readouterr().out
    with pytest.raises(InputError, match="residual_min_steps must be a positive number"):
        LNNModule(scene=scene, scene_config=config, residual_min_steps=0)
    with pytest.raises(InputError, match="learn_residual must be true, false or auto"):
        LNNModule(scene=scene, scene_config=config, learn_residual="yes")
