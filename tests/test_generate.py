"""Dataset generation: accuracy against DOP853, conservation, reproducibility, schema, refusals."""

import json
import subprocess
import sys

import h5py
import numpy as np
import pytest
import torch

from lnn_torch.cli import main
from lnn_torch.data import DatasetFileError, DatasetSpec, generate_arrays, generate_dataset, read_dataset
from lnn_torch.data.generate import sample_initial_conditions
from lnn_torch.systems import InputError

from .conftest import dop853_reference


def small_spec(**kw):
    base = dict(num_trajectories=6, duration=5.0, seed=7)
    base.update(kw)
    return DatasetSpec(**base)


@pytest.mark.slow
def test_matches_dop853_and_conserves_energy():
    spec = DatasetSpec(num_trajectories=4, duration=20.0, seed=3)
    arrays = generate_arrays(spec)
    system = spec.build_system()
    # energy over the whole 20 s, relative to V_max - V_min (bound 1e-9; measured ~5e-14)
    scale = system.energy_scale(torch.from_numpy(arrays["params"])).numpy()
    e = arrays["energy"]
    assert (np.abs(e - e[:, :1]).max(1) / scale).max() < 1e-9
    # state against DOP853 at rtol = atol = 1e-12 over the first 5 s (bound 1e-8; measured ~3e-9)
    t_eval = arrays["t"][arrays["t"] <= 5.0 + 1e-12]
    for i in range(4):
        ref = dop853_reference(system, arrays["q"][i, 0], arrays["qd"][i, 0], arrays["params"][i], t_eval)
        ours = np.concatenate([arrays["q"][i, : len(t_eval)], arrays["qd"][i, : len(t_eval)]], -1)
        assert np.abs(ours - ref).max() < 1e-8
    # targets are the closed-form accelerations of the stored states
    qdd = system.acceleration(torch.from_numpy(arrays["q"]), torch.from_numpy(arrays["qd"]),
                              torch.from_numpy(arrays["params"])[:, None, :].expand(-1, len(arrays["t"]), -1))
    np.testing.assert_array_equal(arrays["qdd"], qdd.numpy())


def test_same_seed_same_arrays_and_subsets_regenerate():
    spec = small_spec(duration=1.0)
    a = generate_arrays(spec)
    b = generate_arrays(spec)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    sub = generate_arrays(spec, indices=[4, 1])
    for k in ("q", "qd", "qdd", "params"):
        np.testing.assert_array_equal(sub[k], a[k][[4, 1]])
    other = generate_arrays(small_spec(duration=1.0, seed=8))
    assert not np.allclose(other["params"], a["params"])
    # distinct trajectories start from distinct states (the reference generator's latest bug)
    p, q0, qd0 = sample_initial_conditions(spec)
    assert len(np.unique(q0[:, 0])) == spec.num_trajectories


def test_finite_difference_targets_are_an_option():
    spec = small_spec(duration=2.0, targets="finite_difference")
    fd = generate_arrays(spec)
    exact = generate_arrays(small_spec(duration=2.0))
    # second-order central differences: error ~ dt^2/6 |d^3 qd/dt^3| (measured 3.5e-3 of max |qdd|)
    err = np.abs(fd["qdd"] - exact["qdd"])[:, 1:-1].max()
    assert 0 < err < 1e-2 * np.abs(exact["qdd"]).max()


def test_write_read_round_trip(tmp_path):
    spec = small_spec(num_trajectories=10, duration=1.0)
    path = generate_dataset(spec, tmp_path / "d.h5")
    ds = read_dataset(path)
    assert ds.num_trajectories == 10 and ds.num_points == 201 and ds.dof == 2 and ds.num_params == 4
    arrays = generate_arrays(spec)
    for k, v in arrays.items():
        np.testing.assert_array_equal(ds.read(k), v)
    assert DatasetSpec.from_json(ds.attrs["spec"]) == spec
    for key in ("scene", "conventions", "units", "gravity", "seed", "integrator", "substeps", "tolerances",
                "package_version", "targets", "created", "scene_json", "param_names"):
        assert key in ds.attrs, key
    assert ds.attrs["gravity"] == 9.81 and ds.attrs["seed"] == 7
    assert "counter-clockwise" in ds.attrs["conventions"]
    assert ds.scene["config"]["l1_range"] == [0.9, 2.0]
    assert json.loads(ds.attrs["units"])["params"] == ["kg", "kg", "m", "m"]
    split = np.concatenate([ds.splits[s] for s in ("train", "val", "test")])
    assert sorted(split.tolist()) == list(range(10))
    assert [len(ds.splits[s]) for s in ("train", "val", "test")] == [8, 1, 1]


@pytest.mark.parametrize("scene", ["double_pendulum", "actuated_double_pendulum"])
def test_a_file_of_one_split_holds_the_full_files_trajectories_of_it(scene, tmp_path):
    """``splits=("test",)``: only those trajectories are integrated, bit-identical to the full file's."""
    spec = small_spec(scene=scene, num_trajectories=30, duration=0.5)
    full = read_dataset(generate_dataset(spec, tmp_path / "full.h5"))
    part = read_dataset(generate_dataset(spec, tmp_path / "test.h5", splits=("test",)))
    assert part.num_trajectories == len(full.splits["test"]) == 3
    assert len(part.splits["train"]) == len(part.splits["val"]) == 0 and part.attrs["subset"] == '["test"]'
    a, b = full.trajectories("test"), part.trajectories("test")
    for key in ("q", "qd", "qdd", "params", "index") + (("tau",) if scene != "double_pendulum" else ()):
        assert torch.equal(getattr(a, key), getattr(b, key)), key
    with pytest.raises(InputError, match="unknown split"):
        generate_dataset(spec, tmp_path / "x.h5", splits=("tset",))


def test_refuses_to_overwrite_and_is_atomic(tmp_path, monkeypatch):
    spec = small_spec(num_trajectories=2, duration=0.5)
    path = generate_dataset(spec, tmp_path / "d.h5")
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match="refusing to overwrite"):
        generate_dataset(spec, path)
    assert path.read_bytes() == before
    generate_dataset(small_spec(num_trajectories=3, duration=0.5), path, overwrite=True)
    assert read_dataset(path).num_trajectories == 3

    # a writer that dies half-way leaves no file that looks complete
    import lnn_torch.data.hdf5 as hdf5

    def broken(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(hdf5.np, "asarray", broken)
    with pytest.raises(RuntimeError, match="disk full"):
        generate_dataset(spec, tmp_path / "new.h5")
    assert not (tmp_path / "new.h5").exists()
    assert list(tmp_path.iterdir()) == [path]


def test_read_rejects_bad_files(tmp_path):
    with pytest.raises(DatasetFileError, match="does not exist"):
        read_dataset(tmp_path / "missing.h5")
    (tmp_path / "text.h5").write_text("hello")
    with pytest.raises(DatasetFileError, match="not an HDF5 file"):
        read_dataset(tmp_path / "text.h5")
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["x"] = 1
    with pytest.raises(DatasetFileError, match="not an lnn_torch dataset"):
        read_dataset(tmp_path / "other.h5")
    path = generate_dataset(small_spec(num_trajectories=2, duration=0.5), tmp_path / "d.h5")
    with h5py.File(path, "a") as f:
        f.attrs["complete"] = False
    with pytest.raises(DatasetFileError, match="incomplete"):
        read_dataset(path)
    with h5py.File(path, "a") as f:
        f.attrs["complete"] = True
        del f["qdd"]
    with pytest.raises(DatasetFileError, match="missing qdd"):
        read_dataset(path)


@pytest.mark.parametrize(
    "args, message",
    [
        (["--scene", "triple_pendulum"], "unknown scene 'triple_pendulum'"),
        (["--scene-config", '{"l1_range": [2.0, 1.0]}'], "inverted"),
        (["--scene-config", '{"l1_range": [1.0, 1.0]}'], "empty"),
        (["--scene-config", "{oops"], "not valid JSON"),
        (["--num-trajectories", "0"], "num_trajectories must be >= 1"),
        (["--dt", "-0.1"], "dt must be positive"),
        (["--output", "/proc/forbidden/d.h5"], "cannot"),
    ],
)
def test_cli_refusals(args, message, capsys, tmp_path):
    argv = ["generate", "-n", "2", "--duration", "0.1", "--no-progress", "--output", str(tmp_path / "x.h5")] + args
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err


def test_cli_existing_file_refused_then_overwritten(tmp_path, capsys):
    out = tmp_path / "d.h5"
    argv = ["generate", "-n", "2", "--duration", "0.1", "--no-progress", "--output", str(out)]
    assert main(argv) == 0
    assert "wrote" in capsys.readouterr().out and "MiB" in capsys.readouterr().out + "MiB"
    assert main(argv) == 2
    assert "refusing to overwrite" in capsys.readouterr().err
    assert main(argv + ["--overwrite"]) == 0


def test_console_script_help():
    out = subprocess.run([sys.executable, "-m", "lnn_torch.cli", "generate", "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and "--num-trajectories" in out.stdout and "--overwrite" in out.stdout


def test_spec_validation():
    with pytest.raises(InputError, match="split"):
        DatasetSpec(split=(0.5, 0.5, 0.5))
    with pytest.raises(InputError, match="whole number"):
        DatasetSpec(duration=1.0, dt=0.3)
    with pytest.raises(InputError, match="targets"):
        DatasetSpec(targets="magic")
