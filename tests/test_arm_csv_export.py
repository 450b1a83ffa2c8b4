"""Simulated arm recordings written as a lab logs them (``lnn_torch.data.export_csv``: one CSV per
trajectory and the import configuration naming each recording's payload) and read back by
``lnn-torch import``: the same signals and payloads, the dataset's own split, and models of the
imported (measured) scene conditioned on the payload exactly as on the simulated scene."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from lnn_torch.cli import main
from lnn_torch.commands.config_files import read_config
from lnn_torch.data import DatasetSpec, generate_dataset, read_dataset
from lnn_torch.data.export_csv import export_recordings
from lnn_torch.errors import InputError
from lnn_torch.networks import build_model
from lnn_torch.networks.scene import SceneInfo
from lnn_torch.training.datamodule import TrajectoryDataModule

from .helpers import perturbed

mujoco = pytest.importorskip("mujoco")

TARGETS = {"method": "butterworth", "cutoff": 10.0, "order": 4, "use_measured_velocity": True}


@pytest.fixture(scope="module")
def arm_files(tmp_path_factory):
    """Six simulated arm trajectories of 1 s (payloads 0-3 kg), their CSVs and the imported file."""
    root = tmp_path_factory.mktemp("arm_csv")
    scene = generate_dataset(DatasetSpec(scene="robot_arm", num_trajectories=6, duration=1.0, dt=0.005, seed=3,
                                         split=(0.5, 0.25, 0.25)), root / "scene.h5")
    paths, config = export_recordings(scene, root / "rec", root / "import.yaml")
    imported = root / "imported.h5"
    assert main(["import", *map(str, paths), "--config", str(config), "-o", str(imported)]) == 0
    return scene, imported, config, paths


def test_the_recordings_read_back_as_the_generated_signals_with_their_payloads(arm_files, capsys):
    """Resampled onto the same grid, the imported q, qd, tau and parameters are the generated ones
    exactly (tolerance 0: values written in their shortest round-trip form, the grid's points are the
    time stamps); the split is the dataset's, by recording; no accelerations travel."""
    scene, imported, config, paths = arm_files
    a, b = read_dataset(scene), read_dataset(imported)
    for key in ("t", "q", "qd", "tau", "params"):
        np.testing.assert_array_equal(b.read(key), a.read(key), err_msg=key)
    for part in ("train", "val", "test"):
        np.testing.assert_array_equal(b.splits[part], a.splits[part])
    with b.open() as h5:
        assert b.measured and "qdd" not in h5 and "energy" not in h5
    header = paths[0].read_text().splitlines()[0].split(",")
    assert header == ["time", *[f"q{j}" for j in range(1, 8)], *[f"dq{j}" for j in range(1, 8)],
                      *[f"tau{j}" for j in range(1, 8)]]
    spec = read_config(config)
    assert spec["robot"] == "franka_panda" and spec["coulomb_velocity"] == 0.05
    assert spec["parameters"]["values"][paths[1].stem] == a.read("params")[1].tolist()
    declared = b.scene
    assert declared["name"] == "measured" and declared["config"]["description"] == "franka_panda"
    assert declared["param_names"] == ["payload_mass", "payload_x", "payload_y", "payload_z"]
    assert declared["param_kinds"] == ["nonnegative", "real", "real", "real"]
    # what a model needs to know: the simulated scene's, but for the name
    differ = {k for k, v in vars(SceneInfo.of(a.scene)).items() if getattr(SceneInfo.of(declared), k) != v}
    assert differ == {"name"}
    dm = TrajectoryDataModule(path=str(imported), targets=TARGETS)
    torch.testing.assert_close(dm.trajectories("test").params, torch.as_tensor(a.read("params")[a.splits["test"]]))


def test_the_description_alone_gives_the_recorded_torques_for_the_recorded_payloads(arm_files):
    """The grey box with ``learn: false`` built on the imported scene (its description from the file,
    the payload of each recording from the file) gives the recorded torques from the engine's
    accelerations to 1e-9 of the largest torque (measured 2e-15; M qdd + bias + the description's
    damping); with the payloads zeroed it misses them by 0.35 of it: the payload reaches the model."""
    scene, imported, _, _ = arm_files
    old = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)  # the description's inertia exactly
    try:
        model = build_model("film_lnn", json.loads(read_dataset(imported).attrs["scene_json"]),
                            kinetic={"spatial": {"learn": False}}, potential={"spatial": {}}, eps=0.0).double()
    finally:
        torch.set_default_dtype(old)
    data = read_dataset(imported).trajectories(None)
    qdd = torch.as_tensor(read_dataset(scene).read("qdd"))[:, ::5].reshape(-1, 7)
    q, qd, tau = (x[:, ::5].reshape(-1, 7) for x in (data.q, data.qd, data.tau))
    params = data.params[:, None].expand(-1, data.q[:, ::5].shape[1], -1).reshape(-1, 4)
    model.fit_normalizer({"q": q, "qd": qd, "qdd": qdd, "params": data.params, "tau": tau})
    damping = model.kinetic["spatial"].description_damping()

    def torque(p):
        with torch.no_grad():
            M = model.mass_matrix(q, p)
            return (M @ qdd[..., None])[..., 0] + model.bias(q, qd, p) + damping * qd

    scale = float(tau.abs().max())
    assert float((torque(params) - tau).abs().max()) / scale < 1e-9
    assert float(params[:, 0].max()) > 1.0  # a payload of more than 1 kg among the recordings
    assert float((torque(torch.zeros_like(params)) - tau).abs().max()) / scale > 0.1


@pytest.mark.parametrize("variant", ["film_lnn", "delan"])
def test_film_lnn_and_delan_condition_on_the_imported_payload_as_on_the_scenes(arm_files, variant):
    """Built with the same seed on the simulated scene and on the imported one, with the normaliser fitted
    from each file's training split (the same estimated targets): the same weights, normalisation
    (the payload's kinds nonnegative and real) and accelerations and torques, which depend on the payload."""
    scene, imported, _, _ = arm_files
    models = []
    for path in (scene, imported):
        torch.manual_seed(0)
        model = perturbed(build_model(variant, read_dataset(path).scene, hidden_dims=(16, 16))).double()
        f = read_dataset(path)
        dm = TrajectoryDataModule(path=str(path), spec=None if f.measured else f.spec, targets=TARGETS)
        model.fit_normalizer(dm.normalization_data())
        models.append(model)
    a, b = models
    for (name, x), (_, y) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        torch.testing.assert_close(x, y, rtol=0, atol=0, msg=name)
    test = TrajectoryDataModule(path=str(imported), targets=TARGETS).trajectories("test")
    q, qd, qdd, tau = (x[:, ::10].reshape(-1, 7) for x in (test.q, test.qd, test.qdd, test.tau))
    params = test.params[:, None].expand(-1, test.q[:, ::10].shape[1], -1).reshape(-1, 4)
    with torch.no_grad():
        torch.testing.assert_close(a.acceleration(q, qd, params, tau), b.acceleration(q, qd, params, tau),
                                   rtol=0, atol=0)
        torch.testing.assert_close(a.inverse(q, qd, qdd, params), b.inverse(q, qd, qdd, params),
                                   rtol=0, atol=0)
        heavier = params.clone()
        heavier[:, 0] += 1.0
        moved = (b.acceleration(q, qd, heavier, tau) - b.acceleration(q, qd, params, tau)).abs().max()
    assert float(moved) > 1e-3


def test_jittered_stamps_are_the_motion_at_those_times(arm_files, tmp_path):
    """Stamps moved by up to 1 ms of the 5 ms interval, the values the motion's there; imported (linear
    resampling onto the grid again): q to linear interpolation's error over the longest interval,
    h^2 / 8 max|qdd| with h = dt + 2 jitter (measured 3.0e-5 rad of the bound's 8.5e-5), qd to 5e-3
    rad/s (measured 1.1e-3: qdd jumps with the held torques), and each torque between the held values
    of the samples k-2..k+1 it can be interpolated from. A jitter of half the interval or more is refused
    (stamps would not increase), and so are existing files."""
    scene = arm_files[0]
    jitter = 1e-3
    paths, config = export_recordings(scene, tmp_path / "rec", tmp_path / "import.yaml", jitter=jitter, seed=1)
    t = np.loadtxt(paths[0], delimiter=",", skiprows=1)[:, 0]
    steps = np.diff(t)
    assert steps.min() > 0.005 - 2 * jitter and steps.max() < 0.005 + 2 * jitter and np.ptp(steps) > jitter
    out = tmp_path / "jittered.h5"
    assert main(["import", *map(str, paths), "--config", str(config), "-o", str(out)]) == 0
    a, b = read_dataset(scene), read_dataset(out)
    assert b.num_points == a.num_points
    bound = (0.005 + 2 * jitter) ** 2 / 8 * np.abs(a.read("qdd")).max()
    assert 0 < np.abs(b.read("q") - a.read("q")).max() < bound
    assert np.abs(b.read("qd") - a.read("qd")).max() < 5e-3
    held = np.pad(a.read("tau"), ((0, 0), (2, 1), (0, 0)), mode="edge")
    around = np.stack([held[:, i:i + a.num_points] for i in range(4)])  # samples k-2, k-1, k, k+1
    tau = b.read("tau")
    assert (tau >= around.min(0) - 1e-12).all() and (tau <= around.max(0) + 1e-12).all()
    np.testing.assert_array_equal(b.read("params"), a.read("params"))
    with pytest.raises(InputError, match=r"jitter must be in \[0, dt / 2\)"):
        export_recordings(scene, tmp_path / "bad", None, jitter=0.0025)
    with pytest.raises(InputError, match="exists"):
        export_recordings(scene, tmp_path / "rec", tmp_path / "import.yaml")


def test_a_scene_without_a_robot_exports_its_declaration(tmp_path):
    """The actuated double pendulum (11 parameters, friction, inputs): its declaration in the import
    configuration (no robot), its signals and parameters read back exactly, gzip-compressed."""
    scene = generate_dataset(DatasetSpec(scene="actuated_double_pendulum", num_trajectories=4, duration=0.5,
                                         dt=0.01, seed=1, split=(0.5, 0.25, 0.25)), tmp_path / "adp.h5")
    paths, config = export_recordings(scene, tmp_path / "rec", tmp_path / "import.yaml", compress=True)
    assert all(p.name.endswith(".csv.gz") for p in paths)
    spec = read_config(config)
    assert "robot" not in spec and len(spec["parameters"]["names"]) == 11
    out = tmp_path / "imported.h5"
    assert main(["import", *map(str, paths), "--config", str(config), "-o", str(out)]) == 0
    a, b = read_dataset(scene), read_dataset(out)
    for key in ("q", "qd", "tau", "params"):
        np.testing.assert_array_equal(b.read(key), a.read(key), err_msg=key)
    differ = {k for k, v in vars(SceneInfo.of(a.scene)).items() if getattr(SceneInfo.of(b.scene), k) != v}
    assert differ == {"name"}
