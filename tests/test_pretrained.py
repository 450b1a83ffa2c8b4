"""The shipped model: it loads with no other argument, is small, is accurate where its card says,
and simulates from the command line; ``lnn-torch evaluate`` writes its report."""

import json
import math

import numpy as np
import pytest
import torch

from lnn_torch import load_pretrained
from lnn_torch.cli import main
from lnn_torch.pretrained import HERE, available, info
from lnn_torch.systems import get_system


def test_shipped_model_is_small_and_has_a_card():
    assert "double_pendulum" in available()
    path = HERE / "double_pendulum.ckpt"
    assert path.stat().st_size < 1_000_000
    card = info("double_pendulum")
    assert card["command"].startswith("lnn-torch fit -c configs/double_pendulum.yaml")
    assert card["test_metrics"]["test/acc_rel_err"] <= 0.005
    with pytest.raises(KeyError, match="no pretrained model 'triple'"):
        load_pretrained("triple")


def test_shipped_model_loads_and_matches_the_closed_form():
    """In distribution its accelerations are within ~1 % of the scene's (card: test error <= 0.5 %)."""
    model = load_pretrained("double_pendulum")
    system = get_system("double_pendulum")
    rng = np.random.default_rng(0)
    params = torch.tensor(system.sample_params(rng, 512))
    q, qd = (torch.tensor(x) for x in system.sample_state(rng, 512))
    with torch.no_grad():
        a = model.acceleration(q, qd, params)
    assert a.dtype == torch.float64 and a.shape == (512, 2)
    true = system.acceleration(q, qd, params)
    assert ((a - true).norm() / true.norm()) < 0.01  # measured ~0.2 % on these initial states


def test_a_loaded_model_works_under_torch_func_transforms():
    """``torch.func.vmap`` and ``jacrev`` through a loaded model's (and a scene's) checked ``acceleration``: the
    checks of values, which read a tensor's value, step aside there (they refused with vmap's .item() error), the
    results are the plain calls', the Jacobian near the exact one; outside a transform NaN is refused as before,
    and a gradient through the checks warns of nothing."""
    import warnings

    from torch.func import jacrev, vmap

    from lnn_torch import load_model
    from lnn_torch.errors import InputError

    model, system = load_model("pretrained:double_pendulum").double(), get_system("double_pendulum")
    gen = torch.Generator().manual_seed(3)
    q, qd = torch.randn(6, 2, generator=gen, dtype=torch.float64), torch.randn(6, 2, generator=gen, dtype=torch.float64)
    p = torch.tensor([1.0, 0.6, 1.2, 1.1], dtype=torch.float64).expand(6, 4)
    one = lambda face: lambda q, qd, p: face.acceleration(q[None], qd[None], p[None])[0]  # noqa: E731
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        torch.testing.assert_close(vmap(one(model))(q, qd, p), model.acceleration(q, qd, p), rtol=1e-12, atol=1e-12)
        J, exact = vmap(jacrev(one(model)))(q, qd, p), vmap(jacrev(one(system)))(q, qd, p)
        x = q.clone().requires_grad_()
        model.acceleration(x, qd, p).sum().backward()
    assert J.shape == (6, 2, 2) and float((J - exact).abs().max() / exact.abs().max()) < 0.02
    by_hand = torch.autograd.functional.jacobian(one(model), (q[2], qd[2], p[2]))[0]
    torch.testing.assert_close(J[2], by_hand, rtol=1e-9, atol=1e-9)
    bad = q.clone()
    bad[1, 0] = float("nan")
    with pytest.raises(InputError, match="q contains NaN"):
        model.acceleration(bad, qd, p)
    # the rigid-body terms and a rollout (whose check of non-finite states stopped vmap) run through vmap too
    rolled = vmap(lambda q, qd, p: model.rollout(q[None], qd[None], p[None], 0.01, 5)[0][0])(q, qd, p)
    torch.testing.assert_close(rolled, model.rollout(q, qd, p, 0.01, 5)[0], rtol=1e-12, atol=1e-12)
    for name in ("mass_matrix", "energy", "bias", "gravity"):
        args = (q, p) if name in ("mass_matrix", "gravity") else (q, qd, p)
        torch.testing.assert_close(vmap(lambda *a, n=name: getattr(model, n)(*(x[None] for x in a))[0])(*args),
                                   getattr(model, name)(*args), rtol=1e-12, atol=1e-12)
    with pytest.raises(InputError, match="has no inputs"):  # (was an AttributeError on None)
        model.inverse(q, qd, qd, p)


def test_simulate_writes_csv_and_plot_and_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "sim.csv"
    argv = ["simulate", "--params", "1.0", "0.6", "1.2", "1.1", "--q0", "0.8", "-0.4", "--qd0", "0", "0",
            "--duration", "2", "--dt", "0.01", "-o", str(out)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "wrote" in text and "true-energy drift" in text
    lines = out.read_text().splitlines()
    row = next(i for i, line in enumerate(lines) if not line.startswith("#"))  # comments, then a header row
    data = np.loadtxt(lines[row + 1:], delimiter=",")
    assert lines[row].split(",")[:3] == ["t", "theta1", "theta2"]
    assert data.shape == (201, 1 + 2 + 2 + 2 + 2)
    np.testing.assert_allclose(data[0, 1:3], [0.8, -0.4])
    assert np.abs(data[:, 1:3] - data[:, 5:7]).max() < 0.05  # model vs exact over 2 s
    assert (tmp_path / "sim.png").exists()
    assert main(argv) == 2
    assert "refusing to overwrite" in capsys.readouterr().err
    assert main(argv[:2] + ["1.0", "0.6"] + argv[6:] + ["--overwrite"]) == 2
    assert "params needs 4 values (m1, m2, l1, l2)" in capsys.readouterr().err


def test_simulate_hdf5(tmp_path):
    import h5py

    out = tmp_path / "sim.h5"
    assert main(["simulate", "--params", "1.0", "0.6", "1.2", "1.1", "--q0", "0.5", "0.5", "--duration", "1",
                 "-o", str(out), "--no-exact"]) == 0
    with h5py.File(out) as f:
        assert f["q"].shape == (201, 2) and "q_exact" not in f
        assert json.loads(f.attrs["meta"])["variant"] == "film_lnn"


@pytest.mark.slow
def test_evaluate_report_of_the_shipped_model(tmp_path):
    """``lnn-torch evaluate`` on a small dataset: JSON, Markdown and plots with every section."""
    from lnn_torch.data import DatasetSpec, generate_dataset

    data = generate_dataset(DatasetSpec(num_trajectories=20, duration=4.0, seed=9), tmp_path / "d.h5")
    out = tmp_path / "eval"
    assert main(["evaluate", "pretrained:double_pendulum", "--data", str(data), "--horizon", "3", "--threads", "1",
                 "--stability-seconds", "0.5", "--long-horizon-steps", "200", "-o", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("acc_rel_err", "divergence_time@0.1", "divergence_time@0.5", "energy_drift", "mass_matrix", "ood",
                "stability"):
        assert key in metrics, key
    assert metrics["acc_rel_err"]["total"] < 0.02
    assert len(metrics["ood"]) == 4
    assert any(r["case"].startswith("long horizon") for r in metrics["stability"])
    # every hard case stays finite but m2/m1 = 1e3, a thousand times beyond the training range, where the exact
    # equations themselves leave the finite numbers at this step (scripts/benchmark.py: 88 % of its rollouts)
    assert all(r["non_finite_fraction"] == 0 for r in metrics["stability"] if not r["case"].startswith("m2/m1 = 1e3"))
    assert sum(r["case"].startswith("m2/m1 = 1e3") for r in metrics["stability"]) == 1
    assert math.isfinite(metrics["mass_matrix"]["cond_max"])
    report = (out / "report.md").read_text()
    assert "Out-of-distribution" in report and "Stability" in report
    # the README's units, capped times marked, no inputs mentioned for a scene without them
    assert f"| acceleration rel. L2 error (total) | {100 * metrics['acc_rel_err']['total']:.3g} % |" in report
    assert "(never exceeded)" in report and "inputs" not in report.split("Skipped sections")[0]
    for png in ("trajectory.png", "energy_drift.png", "error_growth.png", "frames_ood_case1.png"):
        assert (out / png).stat().st_size > 1000, png


@pytest.mark.slow
def test_evaluate_a_shipped_model_generates_its_test_split_alone_into_the_cache(tmp_path, monkeypatch, capsys):
    """No dataset file in the working directory: the 300 test trajectories of the specification the
    checkpoint records, generated once into the cache folder, the same as in the full file."""
    from lnn_torch.data import DatasetSpec, read_dataset, split_indices
    from lnn_torch.data.cache import split_path
    from lnn_torch.training.checkpoint_format import data_hparams

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("LNN_TORCH_CACHE", str(tmp_path / "cache"))
    args = ["evaluate", "pretrained:double_pendulum", "--max-trajectories", "2", "--horizon", "0.2",
            "--stability-seconds", "0", "--threads", "1"]
    assert main(args) == 0
    spec = DatasetSpec(**data_hparams("pretrained:double_pendulum")["spec"])
    cached = split_path(spec, "test")
    out = capsys.readouterr().out
    assert f"into the cache: {cached}" in out and "evaluation/double_pendulum/report.md" in out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache", "evaluation"]
    f = read_dataset(cached)
    assert f.num_trajectories == len(split_indices(spec)["test"]) == 300 and len(f.splits["train"]) == 0
    assert (f.read("trajectory_index") == split_indices(spec)["test"]).all()
    assert main(args) == 0 and "into the cache" not in capsys.readouterr().out  # read from there afterwards


def _arm_errors(name: str, num_trajectories: int, duration: float, stride: int = 1) -> tuple[float, float]:
    """``(torque nMSE mean over joints, acceleration rel. L2)`` of ``pretrained:NAME`` (float64) on
    ``num_trajectories`` arm trajectories of ``duration`` s recorded with seed 123 (no shipped model saw
    it), every ``stride``-th point but the last."""
    from lnn_torch.data import DatasetSpec, generate_arrays

    model = load_pretrained(name).model.double()
    arrays = generate_arrays(DatasetSpec(scene="robot_arm", num_trajectories=num_trajectories, duration=duration,
                                         dt=0.005, seed=123))
    q, qd, qdd, tau = (torch.from_numpy(arrays[k][:, :-1:stride]).reshape(-1, 7) for k in ("q", "qd", "qdd", "tau"))
    params = torch.from_numpy(arrays["params"]).repeat_interleave(len(q) // num_trajectories, 0)
    with torch.no_grad():
        torques = model.inverse(q, qd, qdd, params)
        accelerations = model.forward(q, qd, params, tau)
    torque_nmse = ((torques - tau).pow(2).mean(0) / tau.var(0)).mean()
    return float(torque_nmse), float((accelerations - qdd).norm() / qdd.norm())


def test_the_shipped_arm_grey_box_explains_trajectories_of_another_seed():
    """``pretrained:robot_arm_grey_box`` (the Panda's description learned with a payload at the flange):
    on arm trajectories recorded with a seed it never saw, its inverse dynamics gives the recorded torques
    to a normalised MSE below 1e-8 (measured 1.9e-9) and its forward dynamics the engine's accelerations
    within 0.1 % (measured 0.02 %)."""
    pytest.importorskip("mujoco")
    torque_nmse, acceleration_error = _arm_errors("robot_arm_grey_box", 3, 0.5)
    assert torque_nmse < 1e-8, torque_nmse
    assert acceleration_error < 1e-3, acceleration_error


def test_the_shipped_arm_film_lnn_explains_trajectories_of_another_seed():
    """``pretrained:robot_arm_film_lnn`` (one FiLM network for every payload, learned from 12000 simulated
    trajectories, 128 x 128, 220,000 steps): on 30 arm trajectories of 1 s recorded with a seed it never
    saw, its acceleration error is below 12 % (measured 9.97 %; 9.54 % on the 100 trajectories of 3 s of
    ``results/robot_arm/film_lnn``) and its inverse dynamics' torque nMSE below 0.035 % (measured
    0.025 %; there 0.029 %). The model before (100,000 steps) measured 11.9 % and 0.042 % here; an
    untrained model's acceleration error is about 100 %."""
    pytest.importorskip("mujoco")
    torque_nmse, acceleration_error = _arm_errors("robot_arm_film_lnn", 30, 1.0, stride=2)
    print(f"film_lnn on seed 123: torque nMSE {torque_nmse:.3g}, acc. error {acceleration_error:.3g}")
    assert torque_nmse < 3.5e-4, torque_nmse
    assert acceleration_error < 0.12, acceleration_error
