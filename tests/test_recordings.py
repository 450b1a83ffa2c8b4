"""Measured recordings: import, a system without parameters or closed form, derivative estimates,
trajectory matching, and the command line from CSV files to an evaluated checkpoint."""

import dataclasses
import gzip
import hashlib
import json
import math

import numpy as np
import pytest
import torch

from lnn_torch.cli import main
from lnn_torch.data import DatasetSpec, derivatives, generate_arrays, read_dataset
from lnn_torch.data.importer import ImportSpec, import_recordings
from lnn_torch.systems import InputError, get_system

from .helpers import session_arrays

ADP = get_system("actuated_double_pendulum")


def write_csv(path, columns: dict, header_order=None, gz=False):
    names = header_order or list(columns)
    rows = np.stack([np.asarray(columns[n], dtype=np.float64) for n in names], -1)
    text = ",".join(names) + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n"
    if gz:
        with gzip.open(path, "wt") as fh:
            fh.write(text)
    else:
        path.write_text(text)
    return path


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """Three synthetic recordings of the actuated arm (exact signals), written as CSVs with irregular
    time stamps (2 ms +- 0.5 ms jitter), angles in degrees, the columns in another order, one gzipped."""
    root = tmp_path_factory.mktemp("rec")
    # 2 RK8 substeps per 1 ms sample: a finer step than the scene's default (8 per 5 ms sample), a quarter of
    # the default's cost at this sampling rate; the generator's power-balance check still applies
    arrays = session_arrays(tmp_path_factory, "arm_recordings", lambda: generate_arrays(DatasetSpec(
        scene="actuated_double_pendulum", num_trajectories=3, duration=2.0, dt=0.001, seed=8, substeps=2)))
    rng = np.random.default_rng(0)
    files, truth = [], []
    for i in range(3):
        t_fine = arrays["t"]
        n = 1700 - 200 * i  # different lengths
        t = np.cumsum(np.r_[0, 0.002 + rng.uniform(-0.0005, 0.0005, n - 1)])
        t = t[t <= t_fine[-1]]
        cols = {"stamp": t}
        for j in range(2):
            cols[f"angle{j}"] = np.degrees(np.interp(t, t_fine, arrays["q"][i, :, j]))
            cols[f"rate{j}"] = np.degrees(np.interp(t, t_fine, arrays["qd"][i, :, j]))
            cols[f"motor{j}"] = np.interp(t, t_fine, arrays["tau"][i, :, j])
        order = ["motor1", "stamp", "angle0", "rate0", "angle1", "rate1", "motor0"]
        files.append(write_csv(root / (f"run{i}.csv" + (".gz" if i == 2 else "")), cols, order, gz=i == 2))
        truth.append({k: arrays[k][i] for k in ("q", "qd", "tau")} | {"t": t_fine})
    spec = ImportSpec(time="stamp", coordinates=["angle0", "angle1"], velocities=["rate0", "rate1"],
                      inputs=["motor0", "motor1"], angle_units="deg", coord_names=["q1", "q2"],
                      conventions="q1 from the downward vertical, q2 relative to link 1", angle_combinations=[[1, 1]],
                      dt=0.002, split={"train": ["run0", "run2"], "val": ["run1"], "test": []}, label="synthetic_arm")
    return root, files, truth, spec


def test_import_round_trip_resamples_converts_and_records_provenance(recordings):
    root, files, truth, spec = recordings
    path = import_recordings(files, root / "arm.h5", spec)
    f = read_dataset(path)
    assert f.measured and f.num_trajectories == 3 and f.dt == pytest.approx(0.002) and f.num_inputs == 2
    assert f.splits["train"].tolist() == [0, 2] and f.splits["val"].tolist() == [1] and len(f.splits["test"]) == 0
    data = f.trajectories(None)
    assert data.qdd is None and data.params.shape == (3, 0)
    for i in range(3):
        n = int(data.lengths[i])
        assert torch.isnan(data.q[i, n:]).all() and torch.isfinite(data.q[i, :n]).all()
        t = 0.002 * np.arange(n)
        for key, got in (("q", data.q), ("qd", data.qd), ("tau", data.tau)):
            exact = np.stack([np.interp(t, truth[i]["t"], truth[i][key][:, j]) for j in range(2)], -1)
            # two linear interpolations of a smooth signal sampled every 2 ms (measured ~1e-4 of the range)
            assert np.abs(got[i, :n].numpy() - exact).max() < 5e-3 * np.abs(exact).max(), key
    scene = f.scene
    assert scene["name"] == "measured" and scene["config"]["label"] == "synthetic_arm"
    assert scene["angle_combinations"] == [[1.0, 1.0]] and scene["input_names"] == ["tau1", "tau2"]
    assert "relative to link 1" in f.attrs["conventions"]
    provenance = json.loads(f.attrs["provenance"])
    assert [s["file"] for s in provenance["sources"]] == [p.name for p in files]
    assert provenance["sources"][0]["sha256"] == hashlib.sha256(files[0].read_bytes()).hexdigest()
    assert provenance["settings"]["angle_units"] == "deg" and "linearly interpolated" in provenance["resampling"]
    # without velocity columns the file has none (NaN), and fractions split by recording, seeded
    spec2 = ImportSpec(time="stamp", coordinates=["angle0", "angle1"], angle_units="deg", split=[0.34, 0.33, 0.33],
                       seed=1)
    f2 = read_dataset(import_recordings(files, root / "noqd.h5", spec2))
    assert torch.isnan(f2.trajectories(None).qd).all() and f2.num_inputs == 0
    assert sorted(np.concatenate(list(f2.splits.values())).tolist()) == [0, 1, 2]
    # the fractions as a dict of the parts give the same split; a recording named alone is a list of one
    spec3 = ImportSpec(time="stamp", coordinates=["angle0", "angle1"], angle_units="deg",
                       split={"train": 0.34, "val": 0.33, "test": 0.33}, seed=1)
    f3 = read_dataset(import_recordings(files, root / "dict_fractions.h5", spec3))
    assert {k: v.tolist() for k, v in f3.splits.items()} == {k: v.tolist() for k, v in f2.splits.items()}
    spec4 = ImportSpec(time="stamp", coordinates=["angle0", "angle1"], split={"train": "run0", "test": ["run1"]})
    assert read_dataset(import_recordings(files[:2], root / "named.h5", spec4)).splits["train"].tolist() == [0]


@pytest.mark.parametrize("split, message", [
    ({"train": 0.7}, r"split must be three fractions summing to 1"),
    ({"train": ["run0"], "val": 0.5}, r"split: val must be a list of recording names or windows"),
    ({"train": ["run0"], "holdout": ["run1"]}, r"split: unknown part\(s\) 'holdout' \(train, val, test\)"),
])
def test_a_malformed_split_is_refused_in_one_line(recordings, split, message, tmp_path):
    _, files, _, _ = recordings
    with pytest.raises(InputError, match=message):
        import_recordings(files[:2], tmp_path / "x.h5", ImportSpec(time="stamp", coordinates=["angle0", "angle1"],
                                                                   split=split))


@pytest.mark.parametrize("problem, message", [
    ("missing", r"run\.csv: no column 'angle1'"),
    ("decreasing", r"run\.csv: line 5: time decreases"),
    ("duplicate", r"run\.csv: line 5: time repeats"),
    ("nan", r"run\.csv: line 4: NaN or Inf in column 'angle0'"),
    ("text", r"run\.csv: line 4: column 'angle0': 'abc' is not a number$"),
    ("gap", r"run\.csv: line 6: a gap of 0\.05 s after t = 0\.006 s exceeds max_gap 0\.01 s"),
])
def test_import_refusals_name_the_file_and_line_and_write_nothing(problem, message, tmp_path):
    t = np.arange(20) * 0.002
    cols = {"time": t.copy(), "angle0": np.sin(t), "angle1": np.cos(t)}
    if problem == "missing":
        cols.pop("angle1")
    elif problem == "decreasing":
        cols["time"][3] = cols["time"][2] - 0.001
    elif problem == "duplicate":
        cols["time"][3] = cols["time"][2]
    elif problem == "nan":
        cols["angle0"][2] = np.nan
    elif problem == "gap":
        cols["time"][4:] += 0.048
    path = write_csv(tmp_path / "run.csv", cols)
    if problem == "text":
        lines = path.read_text().splitlines()
        lines[3] = lines[3].replace(lines[3].split(",")[1], "abc", 1)
        path.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out.h5"
    with pytest.raises(InputError, match=message):
        import_recordings([path], out, ImportSpec(coordinates=["angle0", "angle1"], max_gap=0.01))
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["run.csv"]


def test_import_command_refuses_an_existing_output_and_reports_one_line(recordings, tmp_path, capsys):
    root, files, _, _ = recordings
    out = tmp_path / "a.h5"
    argv = ["import", *map(str, files), "-o", str(out), "--time", "stamp", "--coordinates", "angle0", "angle1",
            "--inputs", "motor0", "motor1", "--angle-units", "deg",
            "--split-recordings", "train=run0,run1", "test=run2"]
    assert main(argv) == 0
    assert "3 recordings" in capsys.readouterr().out
    before = out.read_bytes()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "refusing to overwrite" in err and len(err.splitlines()) == 1 and out.read_bytes() == before
    argv[argv.index("-o") + 1] = str(tmp_path / "b.h5")
    assert main(argv[:-2] + ["test=run9"]) == 2
    assert "unknown recording(s) run9" in capsys.readouterr().err
    assert main(argv[:-2] + ["train=run0,run1", "val=run1", "test=run2"]) == 2
    assert "split: a recording is named in more than one split: run1 (train and val)" in capsys.readouterr().err


def test_a_measured_system_has_no_parameters_and_no_closed_form():
    system = get_system("measured", dof=2, input_names=["tau1", "tau2"], angle_combinations=[[1, 1]])
    assert system.num_params == 0 and system.num_inputs == 2 and system.has_forces and not system.closed_form
    with pytest.raises(NotImplementedError, match="has no closed-form"):
        system.acceleration(torch.zeros(1, 2), torch.zeros(1, 2), torch.zeros(1, 0), torch.zeros(1, 2))
    with pytest.raises(InputError, match="cannot be generated"):
        DatasetSpec(scene="measured", scene_config={"dof": 2})
    from lnn_torch.networks import build_model

    for variant in ("film_lnn", "delan", "lnn", "mlp", "hnn"):
        kw = {"hnn_coordinates": "velocity"} if variant == "hnn" else {}
        if variant == "hnn":  # no momentum map (no closed form), and (q, qd) coordinates have no force port
            with pytest.raises(InputError):
                build_model(variant, system, hidden_dims=(8,), **kw)
            continue
        model = build_model(variant, system, hidden_dims=(8,))
        assert not getattr(model, "_has_film", False)  # nothing to condition on
        a = model.acceleration(torch.zeros(3, 2), torch.ones(3, 2), torch.zeros(3, 0), torch.zeros(3, 2))
        assert a.shape == (3, 2) and torch.isfinite(a).all()


# ---------------------------------------------------------------------------- derivative estimates
@pytest.mark.slow
@pytest.mark.parametrize("method, settings, tol_qd, tol_qdd", [  # bounds: 3x the measured worst case
    ("finite_difference", {}, 1.2e-4, 1e-3),  # measured 4.1e-5, 3.4e-4
    ("butterworth", {"cutoff": 25.0}, 1.2e-4, 1e-3),  # measured 4.1e-5, 3.4e-4
    ("savgol", {"window": 21, "polyorder": 4}, 4e-5, 2e-4),  # measured 1.2e-5, 6.5e-5
    ("spline", {}, 1e-3, 9e-3),  # measured 3.3e-4, 2.8e-3 (generalised cross-validation smooths a little)
])
def test_derivative_estimates_recover_exact_derivatives_of_clean_signals(method, settings, tol_qd, tol_qdd):
    """Noise-free positions of the double pendulum at 500 Hz: every method recovers qd and qdd in the
    interior (relative to their range)."""
    arrays = generate_arrays(DatasetSpec(scene="double_pendulum", num_trajectories=2, duration=4.0, dt=0.002, seed=1))
    s = derivatives.settings({"method": method, "use_measured_velocity": False, **settings})
    inner = slice(100, -100)
    rel = lambda a, b: np.abs(a[inner] - b[inner]).max() / np.abs(b).max()  # noqa: E731
    for i in range(2):
        qd, qdd = derivatives.estimate(arrays["q"][i], 0.002, s)
        assert rel(qd, arrays["qd"][i]) < tol_qd, (method, rel(qd, arrays["qd"][i]))
        assert rel(qdd, arrays["qdd"][i]) < tol_qdd, (method, rel(qdd, arrays["qdd"][i]))
    with pytest.raises(InputError, match="targets method must be one of"):
        derivatives.settings({"method": "kalman"})
    with pytest.raises(InputError, match="cutoff"):
        derivatives.estimate(arrays["q"][0], 0.002, derivatives.settings({"method": "butterworth", "cutoff": 400}))
    # settings given on the command line arrive as text (--data.targets.cutoff=25): read as numbers and flags
    assert derivatives.settings({"method": "butterworth", "cutoff": "25", "order": "2",
                                 "use_measured_velocity": "false"}) == {
        "method": "butterworth", "use_measured_velocity": False, "cutoff": 25.0, "order": 2}
    for bad, message in (({"cutoff": "fast"}, "targets cutoff must be a number, got 'fast'"),
                         ({"order": 2.5}, "targets order must be a whole number"),
                         ({"use_measured_velocity": "maybe"}, "use_measured_velocity must be true or false")):
        with pytest.raises(InputError, match=message):
            derivatives.settings({"method": "butterworth", **bad})


@pytest.mark.slow
def test_the_splines_smoothing_follows_the_noise_and_identification_is_unbiased():
    """Double-pendulum positions at 200 Hz with 1e-4 rad of noise, identified on the true equations from the
    accelerations a smoothing spline estimates: with the smoothing cross-validation chooses
    (``derivatives.gcv_lambda``) the lengths come out unbiased (mean over 12 trajectories within 0.12 %; measured
    -0.06 %). SciPy's own choice stops its search at 1e-5 s^3, far more smoothing than this noise asks for: the
    lengths were 0.27 % short (beyond their reported uncertainty), more at higher rates. Never less smoothing than
    the floor (noise-free motion)."""
    from lnn_torch.identification import identify_batch
    from lnn_torch.systems import ClosedForm, get_system

    arrays = generate_arrays(DatasetSpec(scene="double_pendulum", num_trajectories=12, duration=2.0, dt=0.005, seed=4))
    rng = np.random.default_rng(0)
    q = arrays["q"] + rng.normal(0.0, 1e-4, arrays["q"].shape)
    t = np.arange(q.shape[1]) * 0.005
    system = get_system("double_pendulum")
    found = identify_batch(ClosedForm(system), system, t, q, starts=2, steps=60)
    error = np.array([r.quantities["l1"]["value"] / arrays["params"][i, 2] - 1 for i, r in enumerate(found)])
    assert abs(error.mean()) < 1.2e-3, error
    flat = derivatives.gcv_lambda(t, np.sin(t))  # noise-free: the floor (no less smoothing than half a sample)
    assert flat == pytest.approx(derivatives.GCV_FLOOR * 0.005 ** 3)


def test_the_smoothing_choice_is_the_same_where_scipy_fits_one_column_at_a_time(monkeypatch):
    """SciPy before 1.16 fits a smoothing spline to one column only (a 2-D ``y`` is a ValueError there): the
    cross-validated smoothing then fits the columns one by one, to the same choice."""
    import scipy.interpolate

    t = np.arange(400) * 0.005
    y = np.sin(3 * t) + np.random.default_rng(0).normal(0.0, 1e-3, len(t))
    both = derivatives.gcv_lambda(t, y)
    original = scipy.interpolate.make_smoothing_spline

    def one_column(x, yy, *args, **kwargs):
        if np.ndim(yy) != 1:
            raise ValueError("``x`` and ``y`` should be one dimensional and the same size")
        return original(x, yy, *args, **kwargs)

    monkeypatch.setattr(scipy.interpolate, "make_smoothing_spline", one_column)
    assert derivatives.gcv_lambda(t, y) == pytest.approx(both, rel=1e-9)
    assert both > derivatives.GCV_FLOOR * 0.005 ** 3  # (noise: more smoothing than the floor)


def test_the_butterworth_estimate_holds_up_to_the_recordings_ends():
    """A smooth motion (two sines, 200 Hz, 10 Hz cutoff, as the shipped configs filter): within the first
    and last 0.1 s the accelerations are within 2 % (measured 2.0 %; 0.05 % inside): the ends are extended
    by a fitted cubic before the zero-phase filter (an odd reflection made the curvature zero at each
    end: 39 % error there)."""
    dt = 0.005
    t = np.arange(0.0, 4.0, dt)
    q = np.stack([0.8 * np.sin(2 * np.pi * 0.7 * t + 0.4), 0.5 * np.sin(2 * np.pi * 1.3 * t + 1.1)], -1)
    qdd = -np.stack([0.8 * (2 * np.pi * 0.7) ** 2 * np.sin(2 * np.pi * 0.7 * t + 0.4),
                     0.5 * (2 * np.pi * 1.3) ** 2 * np.sin(2 * np.pi * 1.3 * t + 1.1)], -1)
    _, est = derivatives.estimate(q, dt, derivatives.settings({"method": "butterworth", "cutoff": 10.0}))
    ends = np.r_[0:20, len(t) - 20:len(t)]
    rel = np.linalg.norm(est[ends] - qdd[ends]) / np.linalg.norm(qdd[ends])
    assert rel < 0.04, rel


# ---------------------------------------------------------------------------- trajectory matching
def test_trajectory_matching_gradient_equals_finite_differences(tmp_path):
    """The multiple-shooting loss differentiates through the rollout: its gradient with respect to a
    weight equals central finite differences (float64, tiny model)."""
    from lnn_torch import LNNModule

    model = LNNModule(scene="actuated_double_pendulum", hidden_dims=[4], loss="trajectory").double()
    rng = np.random.default_rng(0)
    q, qd = (torch.tensor(x) for x in ADP.sample_state(rng, 3))
    params = torch.tensor(ADP.sample_params(rng, 3))
    tau = torch.tensor(rng.uniform(-0.5, 0.5, (3, 2)))
    qdd = ADP.acceleration(q, qd, params, tau)
    model.model.fit_normalizer({"q": q, "qd": qd, "qdd": qdd, "params": params, "params_points": params, "tau": tau})
    model.data_dt = 0.005
    arrays = generate_arrays(DatasetSpec(scene="actuated_double_pendulum", num_trajectories=2, duration=0.05, seed=3))
    batch = {k: torch.from_numpy(arrays[k]) for k in ("q", "qd", "tau")}
    batch["params"] = torch.from_numpy(arrays["params"])[:, None].expand(-1, batch["q"].shape[1], -1)
    weight = model.model.kinetic["mlp"].net.hidden[0].weight
    loss, _ = model.batch_loss(batch)
    (grad,) = torch.autograd.grad(loss, weight)
    h = 1e-6
    for idx in [(0, 0), (1, 2), (3, 5)]:
        with torch.no_grad():
            weight[idx] += h
            up = model.batch_loss(batch)[0]
            weight[idx] -= 2 * h
            down = model.batch_loss(batch)[0]
            weight[idx] += h
        assert abs(grad[idx] - (up - down) / (2 * h)) <= 1e-6 * max(1.0, abs(float(grad[idx]))), idx


def test_shooting_windows_never_cross_a_recording_end(recordings):
    from lnn_torch import TrajectoryDataModule

    root, files, _, spec = recordings
    path = import_recordings(files, root / "windows.h5", spec, overwrite=True)
    dm = TrajectoryDataModule(path=str(path), chunk_len=200, chunks_per_batch=16, steps_per_epoch=20,
                              targets={"method": "savgol", "window": 21, "polyorder": 3})
    dm.setup("fit")
    lengths = dm.source("train").lengths
    assert sorted(lengths.tolist()) == sorted(int(x) for x in read_dataset(path).trajectories("train").lengths)
    for batch in dm.train_dataloader():
        assert torch.isfinite(batch["q"]).all() and torch.isfinite(batch["qd"]).all()
        assert torch.isfinite(batch["qdd"]).all() and torch.isfinite(batch["tau"]).all()


def test_recorded_velocities_are_the_files_point_for_point_with_the_smoothed_ones(recordings):
    """``recorded_velocities``: the velocities as the file holds them (resampled, in rad/s), cut to each
    entry's window like ``trajectories``, whose velocities are the targets' smoothed ones."""
    from lnn_torch import TrajectoryDataModule

    root, files, _, spec = recordings
    windowed = dataclasses.replace(spec, split={"train": ["run0[0.1:2.0]"], "val": ["run1[0.5:1.5]", "run2"],
                                                "test": []})
    path = import_recordings(files, root / "recorded_qd.h5", windowed, overwrite=True)
    f = read_dataset(path)
    dm = TrajectoryDataModule(path=str(path), targets={"method": "butterworth", "cutoff": 10.0})
    recorded, smoothed = dm.recorded_velocities("val"), dm.trajectories("val")
    assert recorded.shape == smoothed.qd.shape and recorded.dtype == torch.float64
    with f.open() as h:
        qd, windows = h["qd"][:], h["windows"][:]
    for j, idx in enumerate(f.splits["val"]):
        a, b = windows[idx]
        n = int(smoothed.lengths[j])
        assert n == b - a
        np.testing.assert_allclose(recorded[j, :n].numpy(), qd[idx, a:b], rtol=0, atol=1e-12)
        assert torch.isnan(recorded[j, n:]).all()
        assert not np.allclose(recorded[j, :n].numpy(), smoothed.qd[j, :n].numpy(), atol=1e-6)
    with pytest.raises(ValueError, match="needs estimated targets"):
        TrajectoryDataModule(path=str(path)).recorded_velocities("val")
    positions_only = dataclasses.replace(windowed, velocities=None)
    path = import_recordings(files, root / "no_recorded_qd.h5", positions_only, overwrite=True)
    without = TrajectoryDataModule(path=str(path), targets={"method": "butterworth", "cutoff": 10.0})
    with pytest.raises(ValueError, match=r"a recording of its 'val' split has no recorded velocities"):
        without.recorded_velocities("val")


def test_feedback_rows_read_the_recorded_torques_whatever_the_inputs_smoothing(recordings):
    """``arm_identification.feedback_rows`` fits its gains to the recorded torques' band above the targets':
    a datamodule that smooths its training inputs (``smooth_inputs``) gives the same rows."""
    from lnn_torch import TrajectoryDataModule
    from lnn_torch.identification.arm_comparison import feedback_rows

    root, files, _, spec = recordings
    path = import_recordings(files, root / "feedback_rows.h5", spec, overwrite=True)
    targets = {"method": "butterworth", "cutoff": 10.0}
    half = lambda q, qd, qdd, p: 0.5 * torch.ones_like(q)  # noqa: E731  (a model that misses everything)
    rows = [feedback_rows(TrajectoryDataModule(path=str(path), targets=targets, smooth_inputs=smooth), {"half": half},
                          ["q1", "q2"], split="val")["half + velocity feedback"] for smooth in (False, True)]
    assert rows[0]["rms_mean"] == rows[1]["rms_mean"] and rows[0]["feedback"] == rows[1]["feedback"]
    assert len(rows[0]["feedback"]["gains"]) == 2 and all(map(math.isfinite, rows[0]["feedback"]["gains"]))


# ---------------------------------------------------------------------------- end to end from the CLI
@pytest.mark.slow
def test_csv_to_trained_evaluated_checkpoint_from_the_cli(recordings, tmp_path):
    """Import, fit (a parameter-free measured system, acceleration targets from Savitzky-Golay, and
    trajectory matching with the grey-box rigid chain), evaluate (the chain's checkpoint) with horizons
    from many start points; all from the command line (``lnn_torch.cli.main`` in this process)."""
    from .helpers import cli_in_process

    root, files, _, _ = recordings
    data = tmp_path / "arm.h5"
    run = lambda *a: cli_in_process(*a, cwd=tmp_path)  # noqa: E731
    out = run("import", *map(str, files), "-o", str(data), "--time", "stamp", "--coordinates", "angle0", "angle1",
              "--velocities", "rate0", "rate1", "--inputs", "motor0", "motor1", "--angle-units", "deg",
              "--angle-combination", "1", "1", "--split-recordings", "train=run0", "val=run1", "test=run2")
    assert out.returncode == 0, out.stderr[-2000:]
    common = ["--data.path", str(data), "--data.chunk_len", "5", "--data.chunks_per_batch", "8",
              "--data.steps_per_epoch", "3", "--model.hidden_dims", "[8,8]", "--model.val_rollout_seconds", "0.2",
              "--trainer.max_epochs", "1", "--trainer.enable_progress_bar", "false", "--trainer.accelerator", "cpu"]
    for extra in (["--data.targets", '{"method": "savgol", "window": 21, "polyorder": 3}'],
                  ["--data.targets", "butterworth", "--model.loss", "trajectory", "--model.model_options",
                   '{"kinetic": "chain", "links": [[1, 0], [1, 1]], "potential": "harmonic"}']):
        out = run("fit", *common, *extra)
        assert out.returncode == 0, out.stderr[-3000:]
    ckpts = sorted(tmp_path.glob("lightning_logs/version_*/checkpoints/last.ckpt"))
    assert len(ckpts) == 2
    from lnn_torch.training.checkpoints import load_model

    assert load_model(str(ckpts[-1])).model.chain is not None  # the options travel with the checkpoint
    out = run("evaluate", str(ckpts[-1]), "--split", "test", "--threads", "1", "-o", str(tmp_path / "eval"))
    assert out.returncode == 0, out.stderr[-3000:]
    metrics = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert "horizons" in metrics and "acc_rel_err" in metrics and "energy_drift" not in metrics
    h = metrics["horizons"]
    assert h["num_starts"] >= 2 and math.isfinite(h["error@0.1s"]["median"])
    # the report says what the errors are against: the checkpoint's estimate of the recordings' accelerations
    assert "Reference accelerations: " in (tmp_path / "eval" / "report.md").read_text()
    assert metrics["reference"] != "the file's accelerations"


def test_smoothed_inputs_reach_the_training_split_only(recordings):
    """``smooth_inputs``: the training split's inputs pass through the targets' filter; validation
    reads the recorded inputs unchanged."""
    from lnn_torch import TrajectoryDataModule

    root, files, _, spec = recordings
    path = import_recordings(files, root / "smooth.h5", spec, overwrite=True)
    targets = {"method": "butterworth", "cutoff": 10.0}
    raw = TrajectoryDataModule(path=str(path), targets=targets)
    smooth = TrajectoryDataModule(path=str(path), targets=targets, smooth_inputs=True)
    for j, n in enumerate(raw.source("train").lengths):
        want = derivatives.smooth_inputs(raw.trajectories("train").tau[j, :n].numpy(), raw.dt,
                                         derivatives.settings(targets))
        np.testing.assert_allclose(smooth.trajectories("train").tau[j, :n].numpy(), want, rtol=1e-12, atol=1e-12)
        assert not np.allclose(want, raw.trajectories("train").tau[j, :n].numpy())
    torch.testing.assert_close(smooth.trajectories("val").tau, raw.trajectories("val").tau, equal_nan=True)
    # asked for explicitly (evaluation in the reference's band): any split, whatever the configuration
    for j, n in enumerate(raw.source("val").lengths):
        want = derivatives.smooth_inputs(raw.trajectories("val").tau[j, :n].numpy(), raw.dt,
                                         derivatives.settings(targets))
        np.testing.assert_allclose(raw.trajectories("val", smooth_inputs=True).tau[j, :n].numpy(), want, rtol=1e-12,
                                   atol=1e-12)
    with pytest.raises(ValueError, match="smooth_inputs needs estimated targets"):
        TrajectoryDataModule(path=str(path)).trajectories("val", smooth_inputs=True)
