"""Tools whose parameters recordings leave unknown (``identification.payload.identify_tools``, identified at
import by ``data.import_tools``): the payload regressor against the payload's own inverse dynamics, exact
recovery on noise-free torques (point mass and ten parameters, mass known or not), the tool told from
the arm's last link only with recordings without it, the coverage of the 95 % intervals across seeds,
and simulated arm recordings imported with a tool of unknown centre of mass (and mass)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from lnn_torch.errors import InputError
from lnn_torch.identification.classical_arm import description_parameters
from lnn_torch.identification.payload import ToolsUndetermined, identify_tools
from lnn_torch.robots.regressor import inverse_dynamics, payload_regressor, payload_ten, payload_torque
from lnn_torch.robots.tools import Tool

mujoco = pytest.importorskip("mujoco")

POINT = [1.5, 0.02, -0.03, 0.08]  # kg, m (flange frame)
FULL = POINT + [0.004, 0.005, 0.003, 0.0004, -0.0003, 0.0002]  # and kg m^2 about the centre of mass


@pytest.fixture(scope="module")
def chain():
    from lnn_torch.identification.arm_comparison import arm_chain
    from lnn_torch.systems import get_system

    return arm_chain(get_system("robot_arm"))


def sines(chain, rng, T: int = 600, dt: float = 0.004):
    """Exciting joint motion with exact accelerations: three harmonics of 0.2 Hz per joint."""
    t = np.arange(T) * dt
    q, qd, qdd = (np.zeros((T, chain.dof)) for _ in range(3))
    for j in range(chain.dof):
        for k in range(1, 4):
            w, (a, b) = 2 * np.pi * 0.2 * k, rng.normal(0.0, 0.3 / k, 2)
            q[:, j] += a * np.sin(w * t) + b * np.cos(w * t)
            qd[:, j] += w * (a * np.cos(w * t) - b * np.sin(w * t))
            qdd[:, j] -= w * w * (a * np.sin(w * t) + b * np.cos(w * t))
    return [torch.as_tensor(x) for x in (q, qd, qdd)]


def recordings(chain, truth, seed: int, noise: float = 0.0, loaded: int = 3, free: int = 3, T: int = 600):
    """``free`` recordings without a tool and ``loaded`` carrying ``box`` (the row ``truth``): the
    description's torques, plus white noise of ``noise`` N m."""
    rng = np.random.default_rng(seed)
    gen = torch.Generator().manual_seed(seed)
    pi = description_parameters(chain)
    out = []
    for i in range(free + loaded):
        q, qd, qdd = sines(chain, rng, T)
        tau = inverse_dynamics(chain, q, qd, qdd, pi)
        tool = "box" if i >= free else None
        if tool:
            tau = tau + payload_torque(chain, q, qd, qdd, torch.tensor(truth, dtype=torch.float64)[None].expand(T, -1))
        tau = tau + noise * torch.randn(tau.shape, generator=gen, dtype=torch.float64)
        out.append((f"r{i}", q, qd, qdd, tau, tool))
    return out


def test_the_payload_regressor_is_the_payloads_inverse_dynamics(chain):
    """``payload_regressor(q, qd, qdd) @ payload_ten(row)`` equals the payload's rigid body carried at the
    flange (``payload_torque``, the recursion), ten parameters with an inertia, in float64."""
    rng = np.random.default_rng(0)
    q, qd, qdd = sines(chain, rng, 50)
    row = torch.tensor([FULL], dtype=torch.float64)
    direct = payload_torque(chain, q, qd, qdd, row.expand(50, -1))
    linear = payload_regressor(chain, q, qd, qdd) @ payload_ten(row)[0]
    assert float(direct.abs().max()) > 0.1
    torch.testing.assert_close(linear, direct, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("truth, known", [(POINT, {"mass": 1.5}), (POINT, {}), (FULL, {"mass": 1.5}), (FULL, {}),
                                          (FULL, {"mass": 1.5, "com": POINT[1:]})])
def test_noise_free_torques_give_the_tool_exactly(chain, truth, known):
    """Jointly with the arm's base parameters and damping, the unknown entries come back to 1e-7 (relative
    to the entry's scale) from three recordings with the tool and three without; the known ones are kept."""
    tool = Tool.declared("box", known, len(truth))
    fit = identify_tools(chain, recordings(chain, truth, seed=1), {"box": tool}, drive="viscous")
    got = fit.values["box"]
    scale = np.array([1.0, 0.1, 0.1, 0.1] + [0.01] * 6)[: len(truth)]
    np.testing.assert_allclose(got / scale, np.array(truth) / scale, atol=1e-7)
    assert fit.used["box"] == ["r3", "r4", "r5"] and max(fit.residual_rms) < 1e-9
    assert all(fit.std["box"][k] == 0 for k in tool.known)


def test_a_tool_every_recording_carries_cannot_be_told_from_the_arm(chain):
    """Without recordings free of the tool its parameters and the last link's are one combination: refused
    by name; against a given arm (the description) the same recordings determine it."""
    data = recordings(chain, POINT, seed=2, free=0)
    tool = {"box": Tool.declared("box", {}, 4)}
    with pytest.raises(ToolsUndetermined, match="cannot tell tool.*'box'.*recordings without the tool"):
        identify_tools(chain, data, tool, drive="viscous")
    pi = description_parameters(chain)
    fit = identify_tools(chain, data, tool, arm=lambda q, qd, qdd: inverse_dynamics(chain, q, qd, qdd, pi))
    np.testing.assert_allclose(fit.values["box"], POINT, atol=1e-9)


def test_against_an_arm_without_friction_the_drives_friction_is_fitted_beside_the_tool(chain):
    """Against the description as written (no friction), recordings whose torques hold the drive's viscous,
    Coulomb and offset friction: with ``friction`` those are fitted beside the tool, which comes out exact;
    without, the tool takes up the friction (the check can fail)."""
    from lnn_torch.mechanics.friction import DriveModel

    drive = DriveModel.of({"forms": "viscous+coulomb+offset", "coulomb_velocity": 0.02})
    b, c, o = (torch.linspace(lo, hi, chain.dof, dtype=torch.float64)
               for lo, hi in ((0.5, 2.0), (0.3, 1.5), (-0.4, 0.4)))
    data = [(name, q, qd, qdd, tau + b * qd + c * drive.shape("coulomb", qd) + o, tool)
            for name, q, qd, qdd, tau, tool in recordings(chain, POINT, seed=3, free=0)]
    tool = {"box": Tool.declared("box", {}, 4)}
    pi = description_parameters(chain)

    def arm(q, qd, qdd):
        return inverse_dynamics(chain, q, qd, qdd, pi)

    fitted = identify_tools(chain, data, tool, arm=arm, drive=drive, friction=True)
    np.testing.assert_allclose(fitted.values["box"], POINT, atol=1e-8)
    assert max(fitted.residual_rms) < 1e-8
    alone = identify_tools(chain, data, tool, arm=arm, drive=drive)
    assert np.abs(alone.values["box"] - POINT).max() > 1e-2


def test_declarations_are_checked():
    with pytest.raises(InputError, match="'box': colour is not a payload field"):
        Tool.declared("box", {"colour": 1}, 4)
    with pytest.raises(InputError, match="declares an inertia, but the payloads are point masses"):
        Tool.declared("box", {"inertia": [0.1] * 6}, 4)
    with pytest.raises(InputError, match="mass must be positive"):
        Tool.declared("box", {"mass": 0.0}, 4)
    with pytest.raises(InputError, match="com needs 3 finite value"):
        Tool.declared("box", {"com": [0.1, 0.2]}, 4)
    assert Tool.declared("box", {"mass": 2.0}, 10).unknown == list(range(1, 10))


def test_the_95_percent_intervals_cover_the_truth_across_seeds(chain):
    """Over 9 seeds of white torque noise (0.05 N m), every identifiable base parameter of the arm (its
    pivoted combinations of the description's parameters) and the tool's mass and centre of mass: the
    cluster-robust 95 % intervals contain the truth 90-99 % of the time."""
    pi = description_parameters(chain).numpy()
    hits, total = 0, 0
    for seed in range(9):
        fit = identify_tools(chain, recordings(chain, POINT, seed=100 + seed, noise=0.05, T=400),
                             {"box": Tool.declared("box", {}, 4)}, drive="viscous")
        u = fit.arm.info["uncertainty"]
        beta_true = fit.arm.base["map"] @ pi
        lo, hi = np.array(u["interval95"]).T
        inside = (lo <= beta_true) & (beta_true <= hi)
        box = np.abs(fit.values["box"] - POINT) <= 1.959963984540054 * fit.std["box"]
        hits += int(inside.sum() + box.sum())
        total += len(inside) + len(box)
    coverage = hits / total
    assert total > 450
    print(f"coverage {coverage:.3f} over {total}")
    assert 0.90 <= coverage <= 0.99, coverage


BOTTLE = [0.8, -0.04, 0.03, 0.1]


@pytest.fixture(scope="module")
def arm_logs(tmp_path_factory):
    """Simulated Panda logs as a lab writes them (CSV, ``export_csv``): three of 3 s without a tool, three
    carrying ``box`` (``POINT``), one carrying ``bottle`` (``BOTTLE``); 250 Hz, encoder noise 1e-4 rad."""
    from lnn_torch.data import DatasetSpec, generate_dataset
    from lnn_torch.data.export_csv import export_recordings

    root = tmp_path_factory.mktemp("tools")
    files = []
    for tag, row, count, seed in (("free", [0.0, 0.0, 0.0, 0.0], 3, 1), ("box", POINT, 3, 2), ("bottle", BOTTLE, 1, 3)):
        config = {name: (v, v + 1e-12) for name, v in
                  zip(("payload_mass", "payload_x", "payload_y", "payload_z"), row, strict=True)}
        data = generate_dataset(DatasetSpec(scene="robot_arm", scene_config={**config, "encoder_noise": 1e-4},
                                            num_trajectories=count, duration=3.0, dt=0.004, seed=seed,
                                            split=(1.0, 0.0, 0.0)), root / f"{tag}.h5")
        paths, config_path = export_recordings(data, root / "logs", root / f"{tag}.yaml", prefix=tag)
        files += paths
    return root, files


def import_with(root, files, tools: dict, name: str):
    import yaml

    from lnn_torch.cli import main

    spec = yaml.safe_load((root / "box.yaml").read_text())
    names = [p.name.split(".")[0] for p in files]
    spec["parameters"] = {"values": {n: n.split("_")[0] for n in names if not n.startswith("free")}, "tools": tools}
    spec["split"] = {"train": [n for n in names if n.endswith(("0", "1")) and not n.startswith("bottle")],
                     "val": ["free_0002", "box_0002"], "test": ["bottle_0000"]}
    (root / f"{name}.yaml").write_text(yaml.safe_dump(spec))
    out = root / f"{name}.h5"
    assert main(["import", *map(str, files), "--config", str(root / f"{name}.yaml"), "-o", str(out)]) == 0
    return out


def test_a_tool_of_known_mass_imports_with_its_centre_of_mass_identified(arm_logs, capsys):
    """``lnn-torch import`` with ``box: {mass: 1.5}``: the centre of mass identified within 2 mm (jointly with
    the arm, on the training and validation logs: three of 3 s with the tool) and written where the models
    read the payload, every box entry alike; the bottle, only in the held-out log and declared ``{}``,
    identified from that one log against that arm (mass within 2 %, centre within 1 cm), said so; the report in the
    file and on the screen."""
    from lnn_torch.data import read_dataset

    root, files = arm_logs
    path = import_with(root, files, {"box": {"mass": POINT[0]}, "bottle": {}}, "known_mass")
    printed = capsys.readouterr().out
    f = read_dataset(path)
    names = json.loads(f.attrs["recordings"])
    params = dict(zip(names, f.read("params"), strict=True))
    assert params["box_0000"][0] == POINT[0]
    for n in ("box_0000", "box_0001", "box_0002"):
        np.testing.assert_array_equal(params[n], params["box_0000"])
    assert np.abs(params["box_0000"][1:] - POINT[1:]).max() < 2e-3
    assert abs(params["bottle_0000"][0] / BOTTLE[0] - 1) < 0.02
    assert np.abs(params["bottle_0000"][1:] - BOTTLE[1:]).max() < 1e-2
    np.testing.assert_array_equal(params["free_0000"], 0.0)
    report = json.loads(f.attrs["provenance"])["tools"]
    first, held = report["fits"]
    assert not first["held_out"] and held["held_out"] and "held-out entries used" in held["against"]
    box = first["tools"]["box"]
    assert box["recordings"] == ["box_0000", "box_0001", "box_0002"] and box["parameters"]["mass"]["known"]
    assert box["parameters"]["x"]["std"] > 0
    assert "tool box (known: mass; 3 entries; against the arm, identified with them" in printed
    assert "tool bottle (nothing known; 1 entry;" in printed
    assert printed.count("a point tool's own inertia (to identify it, name ten payload values") == 2  # (four values)
    assert printed.count("friction the drive model lacks (e.g. growing with the load) shift the values by more") == 2


def test_a_tool_nothing_is_known_of_is_identified_within_two_percent_and_five_mm(arm_logs):
    """Declared ``{}``: mass within 2 %, centre of mass within 5 mm, from the same three 3 s logs."""
    from lnn_torch.data import read_dataset

    root, files = arm_logs
    f = read_dataset(import_with(root, files, {"box": {}, "bottle": [*BOTTLE]}, "unknown_mass"))
    params = dict(zip(json.loads(f.attrs["recordings"]), f.read("params"), strict=True))
    assert abs(params["box_0000"][0] / POINT[0] - 1) < 0.02
    assert np.abs(params["box_0000"][1:] - POINT[1:]).max() < 5e-3
    np.testing.assert_array_equal(params["bottle_0000"], BOTTLE)


def test_an_identified_inertia_that_no_rigid_body_has_is_made_the_nearest_one():
    """``payload.physical_inertia``: a rigid body's inertia about its centre of mass has non-negative
    eigenvalues, each at most the sum of the others (its mass's second moment tr(I)/2 - I is positive
    semidefinite); a row that breaks it (an identified inertia the recordings leave loose: MuJoCo refuses it
    on write-back) gets the nearest one, mass and centre of mass kept; a rigid body's row is unchanged."""
    from lnn_torch.identification.payload import physical_inertia

    good = np.array([1.2, 0.01, -0.02, 0.05, 0.004, 0.005, 0.003, 0.0005, -0.0002, 0.0001])
    row, lowest = physical_inertia(good)
    np.testing.assert_array_equal(row, good)
    assert lowest >= 0
    bad = good.copy()
    bad[4:10] = [0.001, 0.001, 0.005, 0.0, 0.0, -0.0006]  # Izz beyond Ixx + Iyy
    row, lowest = physical_inertia(bad)
    assert lowest < 0 and np.array_equal(row[:4], bad[:4])
    I = np.array([[row[4], row[7], row[8]], [row[7], row[5], row[9]], [row[8], row[9], row[6]]])
    eig = np.linalg.eigvalsh(I)
    assert eig.min() >= -1e-15 and eig.max() <= eig.sum() - eig.max() + 1e-15
    assert physical_inertia(row)[1] >= -1e-15  # already a rigid body's: unchanged the second time


def test_long_recordings_are_thinned_for_the_tool_fit(arm_logs, monkeypatch):
    """More samples in all than ``import_tools.TOOL_ROWS``: the tool fit takes every k-th (said in the report),
    and the centre of mass still comes within 2 mm (the targets are filtered far below the sampling rate)."""
    from lnn_torch.data import import_tools, read_dataset

    root, files = arm_logs
    monkeypatch.setattr(import_tools, "TOOL_ROWS", 2000)
    f = read_dataset(import_with(root, files, {"box": {"mass": POINT[0]}, "bottle": [*BOTTLE]}, "thinned"))
    report = json.loads(f.attrs["provenance"])["tools"]
    assert report["stride"] >= 3
    params = dict(zip(json.loads(f.attrs["recordings"]), f.read("params"), strict=True))
    assert np.abs(params["box_0000"][1:] - POINT[1:]).max() < 2e-3
