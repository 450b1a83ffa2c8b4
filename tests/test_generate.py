"""Dataset generation: accuracy against DOP853, conservation, reproducibility, schema, refusals."""

import copy
import dataclasses
import json
import pickle
import subprocess
import sys

import h5py
import numpy as np
import pytest
import torch

from lnn_torch.cli import main
from lnn_torch.data import DatasetFileError, DatasetSpec, generate_arrays, generate_dataset, read_dataset
from lnn_torch.data.generate import sample_initial_conditions
from lnn_torch.systems import InputError, get_system

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
        (["--scene-config", '{"l1_range": [1.0]}'], "expected a pair"),
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


# ---------------------------------------------------------------------------- one recorder, one scene
# trajectory 2 of DatasetSpec(scene, scene_config, num_trajectories=3, duration=0.1, seed=3): its parameters
# and its last sample, as the generator before the recorder refactor wrote them (commit 7b003fd). The
# parameters are seeded draws (exact on every platform); the states are float64 integrations, equal here
# to the last bit, within 1e-10 wherever libm or the engine rounds differently. A change of the seeding or
# of the order of the draws moves them by O(1).
FINGERPRINTS = {
    ("double_pendulum", ""): {
        "params": [0.897008362769448, 0.24727169655774434, 1.925769876575321, 2.07561095542777],
        "q": [-0.14602672430007427, -1.147425835486757], "qd": [-0.28840973045918933, 0.6521656773508495],
        "qdd": [0.11584375686342117, 4.316083186036731], "energy": -23.153135988002564},
    ("actuated_double_pendulum", ""): {
        "params": [0.42224593794740944, 0.43783132176957135, 0.2932518069613928, 0.27698249224255045,
                   0.13803674628309345, 0.036979492699336966, 0.010718798686421734, 0.04661918921755773,
                   0.0023721386706823944, 0.005131741185733579, 0.11569261935514089],
        "q": [0.9035495596037314, -0.266114677984923], "qd": [0.22099007302547097, -2.3209727433683764],
        "qdd": [-34.267545248005014, 84.22845404255668], "tau": [0.5257072676546769, 0.18098966229006927],
        "energy": -1.9483741752339698},
    ("chain_pendulum", '{"num_links": 3}'): {
        "params": [0.897008362769448, 0.7906169511014272, 0.8586991860988125, 0.9445210077734176,
                   0.7314418152825397, 0.5604680000712116],
        "q": [-0.38661446732444904, 0.1595476610041093, 0.677713776393485],
        "qd": [0.34014631619442093, -1.5724318009944291, -0.43291776516263963],
        "qdd": [9.488791535268762, -9.120642748769598, -10.16006458042471], "energy": -36.31188667384734},
    ("pendulum", ""): {
        "params": [0.5834222673027853, 0.6418674566358925], "q": [1.3616889414916664], "qd": [-0.7203657046783283],
        "qdd": [-14.950601937064539], "energy": -0.700234297720389},
    ("mass_spring", ""): {
        "params": [0.5834222673027853, 0.8310240654837492], "q": [0.9365064985972382], "qd": [0.6496260523633711],
        "qdd": [-1.3339556637325358], "energy": 0.487528695218731},
    ("relativistic_particle", ""): {
        "params": [0.06112296897370471], "q": [-0.7588508699955363], "qd": [0.5208260738453114],
        "qdd": [0.017964104412396483], "energy": 0.31100053010622586},
    ("robot_arm", ""): {
        "params": [0.16684453460557058, -0.04054216955760717, 0.04325180696139283, 0.08890420155468354],
        "q": [-0.06790929267219714, -0.6451411720930407, -0.5938832595036136, -1.31565917885153, 0.9672403222436765,
              0.8130541055445445, -1.2822161326997958],
        "qd": [-0.28573923877773544, 0.3852739548893259, -0.4803030534594353, 0.13676602742763466,
               0.3328346575456984, 0.09075654739453394, -0.3028138133049816],
        "qdd": [1.2147683376564786, 2.3137268219681624, 0.08897704016601171, -0.22548150419174817,
                -2.3095713437415, 3.1133467632901652, -1.1233712457003124],
        "tau": [1.8766316777708627, 14.62428153851713, 8.011367735626472, 7.410897001707067, 1.870238500517893,
                2.8147650111329097, -0.48539955044583055],
        "energy": 101.79999731636},
    ("robot_arm", '{"encoder_noise": 0.001, "perturbation": 2}'): {
        "params": [0.16684453460557058, -0.04054216955760717, 0.04325180696139283, 0.08890420155468354],
        "q": [-0.06662540460708472, -0.6441818623517724, -0.5925464259188162, -1.312915527961046, 0.970312869494836,
              0.8164503726624899, -1.2818170833325637],
        "qd": [-0.28067352428896175, 0.38490274194657204, -0.4674649818272953, 0.1568986477919968,
               0.35289527692031736, 0.1108366589450026, -0.2953174595959421],
        "qdd": [0.6223545019021558, 2.378046529291059, -0.018861870412060888, -0.8420517326484047,
                -3.212065014759708, 2.528032199528475, -1.2760549269462578],
        "tau": [1.7158654589686326, 14.847773314289064, 6.3799933711982915, 6.042638208137348, 1.3541431290691834,
                2.536091094479163, -0.5031476255526459],
        "energy": 96.25320072954047},
}


@pytest.mark.parametrize("scene, config", list(FINGERPRINTS), ids=lambda x: x or "default")
def test_every_scene_records_the_trajectories_it_always_recorded(scene, config):
    """The shipped models and the README's figures were trained and measured on these datasets."""
    if scene == "robot_arm":
        pytest.importorskip("mujoco")
    spec = DatasetSpec(scene=scene, scene_config=json.loads(config or "{}"), num_trajectories=3, duration=0.1, seed=3)
    arrays = generate_arrays(spec, indices=[2])
    expected = FINGERPRINTS[scene, config]
    np.testing.assert_array_equal(arrays["params"][0], expected["params"])
    for key in ("q", "qd", "qdd", "tau", "energy"):
        if key in expected:
            np.testing.assert_allclose(arrays[key][0, -1], expected[key], rtol=1e-10, atol=1e-12, err_msg=key)
    assert ("tau" in arrays) == ("tau" in expected)


def test_the_closed_form_recorder_is_the_seeded_draws_integrated():
    """Against the recipe written out here: trajectory i's generator is the seed sequence (seed, i);
    it draws the parameters, the state, then the inputs; the closed form is integrated with them; the
    targets and the energy are the scene's at the integrated states. Equal to the last bit."""
    from lnn_torch.systems.excitation import sample
    from lnn_torch.systems.ground_truth import integrate_ground_truth

    spec = small_spec(scene="actuated_double_pendulum", num_trajectories=4, duration=0.2)
    system = spec.system
    t = np.arange(spec.num_points) * spec.dt
    drawn = []
    for i in (3, 1):
        rng = np.random.default_rng(np.random.SeedSequence(spec.seed, spawn_key=(i,)))
        params = system.sample_params(rng, 1)[0]
        q0, qd0 = system.sample_state(rng, 1)
        drawn.append((params, q0[0], qd0[0], sample(spec.input_signal(), rng, t, system.num_inputs)))
    params, q0, qd0, tau = (torch.from_numpy(np.array(x)) for x in zip(*drawn, strict=True))
    q, qd, steps, work = integrate_ground_truth(system, q0, qd0, params, spec.dt, spec.num_points - 1, spec.integrator,
                                                spec.substeps, spec.energy_tol, spec.adaptive_tol, tau=tau[:, :-1],
                                                return_work=True)
    p_b = params[:, None].expand(-1, len(t), -1)
    arrays = generate_arrays(spec, indices=[3, 1])
    expected = {"t": t, "q": q, "qd": qd, "params": params, "tau": tau, "work": work, "integrator_steps": steps,
                "qdd": system.acceleration(q, qd, p_b, tau), "energy": system.energy(q, qd, p_b)}
    assert sorted(arrays) == sorted(expected)
    for key, value in expected.items():
        np.testing.assert_array_equal(arrays[key], np.asarray(value), err_msg=key)


def test_a_dataset_builds_its_scene_once(tmp_path, monkeypatch):
    import lnn_torch.data.spec as spec_module

    built = []
    monkeypatch.setattr(spec_module, "get_system", lambda *a, **k: built.append(a) or get_system(*a, **k))
    spec = small_spec(scene="actuated_double_pendulum", num_trajectories=3, duration=0.1)
    generate_dataset(spec, tmp_path / "d.h5", splits=("train",))
    assert built == [("actuated_double_pendulum",)]


def test_the_spec_keeps_its_scene_out_of_its_fields():
    """Equality, asdict/JSON, pickles and copies (Lightning's saved hyper-parameters) see the fields
    only; a changed scene configuration builds the scene again."""
    spec = small_spec(duration=0.5)
    scene = spec.system
    assert spec.system is scene and spec == small_spec(duration=0.5)
    assert sorted(json.loads(spec.to_json())) == sorted(f.name for f in dataclasses.fields(DatasetSpec))
    copies = (pickle.loads(pickle.dumps(spec)), copy.deepcopy(spec), copy.copy(spec))
    assert all("_scene" not in vars(other) for other in copies)  # built again when asked for
    for other in (*copies, DatasetSpec.from_json(spec.to_json())):
        assert other == spec and other.system is not scene and other.system.config() == scene.config()
    assert len(pickle.dumps(spec)) < 1000
    spec.scene_config = {"l1_range": [1.0, 1.5]}
    assert spec.system is not scene and spec.system.config()["l1_range"] == [1.0, 1.5]


@pytest.mark.parametrize("scene", ["double_pendulum", "robot_arm"])
def test_one_progress_bar_counts_every_sample_interval(scene, monkeypatch):
    if scene == "robot_arm":
        pytest.importorskip("mujoco")
    import lnn_torch.data.generate as generate

    bars = []

    class Bar:
        def __init__(self, total, **kw):
            self.total, self.done, self.closed = total, 0, False
            bars.append(self)

        def update(self, n=1):
            self.done += n

        def close(self):
            self.closed = True

    monkeypatch.setattr(generate, "tqdm", Bar)
    spec = small_spec(scene=scene, num_trajectories=3, duration=0.1)
    generate_arrays(spec, indices=[0, 2], progress=True)
    assert len(bars) == 1 and bars[0].total == bars[0].done == 2 * 20 and bars[0].closed


def test_cli_substeps_default_to_the_scenes(tmp_path):
    """``lnn-torch generate`` without ``--substeps`` takes the scene's (8 for the actuated pendulum, as a
    configuration's ``DatasetSpec`` does); given, its own."""
    for extra, expected in (([], 8), (["--substeps", "2"], 2)):
        out = tmp_path / f"d{expected}.h5"
        argv = ["generate", "--scene", "actuated_double_pendulum", "-n", "2", "--duration", "0.05", "--no-progress",
                "-o", str(out)]
        assert main(argv + extra) == 0
        ds = read_dataset(out)
        assert ds.attrs["substeps"] == expected and DatasetSpec.from_json(ds.attrs["spec"]).substeps == expected


def test_the_physics_layers_do_not_import_the_data_layer():
    """Scenes, robots and recorders (layer 1) never import ``lnn_torch.data`` (layer 3)."""
    code = ("import sys, lnn_torch.systems, lnn_torch.robots.recording, lnn_torch.systems.recording; "
            "print(sorted(m for m in sys.modules if m.startswith('lnn_torch.data')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stderr


def test_read_rows_equals_hdf5_point_selection(tmp_path):
    """Rows read as one slice per run of consecutive rows equal h5py's own selection of the same rows."""
    from lnn_torch.data.hdf5 import read_rows

    values = np.arange(40 * 3 * 2, dtype=np.float64).reshape(40, 3, 2)
    with h5py.File(tmp_path / "a.h5", "w") as f:
        f["x"] = values
    with h5py.File(tmp_path / "a.h5", "r") as f:
        for rows in ([0], [39], [0, 1, 2, 7, 8, 20, 39], list(range(40)), [], [3, 5, 7]):
            np.testing.assert_array_equal(read_rows(f["x"], rows), values[rows])


def test_a_parameter_can_be_held_fixed_and_a_split_must_leave_training_trajectories(tmp_path):
    """A range [a, a] is one value (a fixed system, a frictionless actuated one: it was refused as empty); a split
    whose validation and test shares round up to every trajectory is refused (it wrote an empty training split)."""
    from lnn_torch.systems.base import Range

    assert Range(1.0, 1.0).sample(np.random.default_rng(0), 3).tolist() == [1.0, 1.0, 1.0]
    path = generate_dataset(DatasetSpec(scene="pendulum", num_trajectories=3, duration=0.5, seed=1,
                                        scene_config={"l_range": [1.0, 1.0], "m_range": [0.5, 0.5]}), tmp_path / "p.h5")
    np.testing.assert_array_equal(np.asarray(read_dataset(path).read("params")), [[0.5, 1.0]] * 3)
    with pytest.raises(InputError, match=r"split \[0\.1, 0\.45, 0\.45\] of 2 trajectories leaves none for training"):
        DatasetSpec(num_trajectories=2, duration=1.0, split=[0.1, 0.45, 0.45])


def test_trajectories_redone_with_adaptive_steps_are_counted_and_said(tmp_path, capsys):
    """A first pass that fails the accuracy check (semi-implicit Euler) is integrated again with adaptive DOP853: the
    steps each took count both passes, the refined trajectories are counted, and generate says the data are the
    adaptive pass's (one adaptive step per interval looked like the fixed pass: 0 refined, the method's name only)."""
    out = tmp_path / "sie.h5"
    assert main(["generate", "-n", "3", "--duration", "1", "--integrator", "semi_implicit_euler", "--no-progress",
                 "-o", str(out)]) == 0
    assert "note: 3 of 3 trajectories failed the semi_implicit_euler pass's accuracy check and were integrated " \
           "again with adaptive DOP853 steps" in capsys.readouterr().out
    f = read_dataset(out)
    assert json.loads(f.attrs["tolerances"])["refined_trajectories"] == 3
    assert (np.asarray(f.read("integrator_steps")) > 200).all()  # 200 fixed steps, then the adaptive ones
    assert main(["generate", "-n", "3", "--duration", "1", "--no-progress", "-o", str(tmp_path / "rk8.h5")]) == 0
    assert "note:" not in capsys.readouterr().out


def test_a_dataset_too_large_for_the_memory_and_bad_seeds_are_refused_before_any_work(tmp_path, capsys):
    """20 million trajectories of the default length (4.5 TB of arrays, 4.5 times that while generated) are refused
    with the estimate (it started, or failed with NumPy's memory error); a negative seed or thread count is named."""
    for args, message in ((["-n", "20000000"], "20000000 trajectories of 4001 points need about"),
                          (["--seed", "-3"], "--seed must be >= 0, got -3"),
                          (["--threads", "0"], "--threads must be a positive number of threads, got 0")):
        assert main(["generate", *args, "-o", str(tmp_path / "x.h5")]) == 2
        assert message in capsys.readouterr().err
        assert not (tmp_path / "x.h5").exists()


def test_a_file_whose_splits_overlap_is_refused_naming_the_trajectory(tmp_path):
    """A trajectory in two splits (a test on training data) or twice in one is a malformed file: refused in one line
    naming it and the splits (it was read as it was)."""
    path = generate_dataset(DatasetSpec(num_trajectories=6, duration=0.5, seed=1), tmp_path / "d.h5")
    read_dataset(path)
    train = np.asarray(read_dataset(path).splits["train"])
    with h5py.File(path, "r+") as f:
        del f["splits/test"]
        f["splits/test"] = np.asarray([train[0]], dtype=np.int64)
    with pytest.raises(DatasetFileError, match=rf"trajectory {train[0]} is in the splits more than once \(train, "
                                               r"test\)") as err:
        read_dataset(path)
    assert "\n" not in str(err.value)
