"""Parameter identification: the optimiser against the closed form, the classical least-squares
reference, the learned model on synthetic observations, identifiability, bad input and the command."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from lnn_torch.identification.learned import identify, identify_batch, least_squares_reference
from lnn_torch.systems import get_system
from lnn_torch.systems.base import InputError
from lnn_torch.systems.ground_truth import ClosedForm, reference_rollout

DT = 0.005
TRUE = (1.3, 0.7, 1.15, 0.95)  # m1, m2, l1, l2: inside the training ranges


def observe(params=TRUE, seconds=2.0, q0=(1.2, -0.6), qd0=(0.0, 0.5)):
    system = get_system("double_pendulum")
    p = torch.tensor([params], dtype=torch.float64)
    n = int(round(seconds / DT))
    q, qd = reference_rollout(system, torch.tensor([q0], dtype=torch.float64), torch.tensor([qd0], dtype=torch.float64),
                              p, DT, n)
    q, qd = q[0], qd[0]
    qdd = system.free_acceleration(q, qd, p.expand(len(q), -1))
    return system, np.arange(n + 1) * DT, q.numpy(), qd.numpy(), qdd.numpy()


def true_quantities(params=TRUE):
    m1, m2, l1, l2 = params
    return {"m2/m1": m2 / m1, "l1": l1, "l2": l2}


def test_an_estimate_on_the_edge_of_the_search_box_is_flagged():
    system, t, q, qd, qdd = observe(params=(0.9, 1.1, 0.7, 1.3), seconds=1.0)  # l1 below the sampled range
    result = identify(ClosedForm(system), system, t, q, qd, qdd=qdd, method="acceleration", starts=2, steps=100)
    assert result.at_bound == ["l1"]


def test_closed_form_recovers_the_parameters_to_1e_6_and_reports_the_mass_scale():
    system, t, q, qd, qdd = observe()
    result = identify(ClosedForm(system), system, t, q, qd, qdd=qdd, method="acceleration", starts=4, steps=150)
    for name, value in true_quantities().items():
        assert result.quantities[name]["identifiable"], name
        assert result.quantities[name]["value"] == pytest.approx(value, rel=1e-6), name
    # a common scale of the masses leaves the accelerations unchanged: reported, with no number
    assert not result.quantities["m1"]["identifiable"] and not result.quantities["m2"]["identifiable"]
    assert result.quantities["m1"]["rel_std"] is None
    (direction,) = result.unidentifiable
    assert set(direction["direction"]) == {"m1", "m2"}
    a, b = direction["direction"]["m1"], direction["direction"]["m2"]
    assert a == pytest.approx(b, abs=1e-2) and abs(a) == pytest.approx(math.sqrt(0.5), abs=1e-2)


class _AlmostInvariant(ClosedForm):
    """A scene whose accelerations a trained model reproduces with a slight dependence on the mass scale (a FiLM
    network's imperfect invariance): 1 % of the acceleration per unit of log m."""

    def acceleration(self, q, qd, params, tau=None, check: bool = False):
        return super().acceleration(q, qd, params, tau) * (1 + 0.01 * params[..., :1].log())


def test_the_scale_no_free_motion_shows_is_reported_not_identifiable_and_the_ratio_is():
    """A mass on a spring: only k/m moves the trajectory. A model whose invariance is slightly off gave m and k
    each to 3 % (40 % off) and called them identifiable; the scene's scale invariance now leaves that direction
    out of the information: m and k not identifiable, k/m identified with its uncertainty."""
    system = get_system("mass_spring")
    assert system.scale_invariance() == {"m": 1.0, "k": 1.0}
    assert system.identifiable_quantities() == {"k/m": {"m": -1.0, "k": 1.0}}
    assert get_system("actuated_double_pendulum").scale_invariance() == {}  # torques fix the scale
    assert get_system("pendulum").scale_invariance() == {"m": 1.0}  # one mass: any value
    # a measured system's masses are not all parameters (a learned arm beside a payload): no such direction
    measured = get_system("measured", dof=1, param_names=["k"], param_units=["N/m"])
    assert measured.scale_invariance() == {} and measured.identifiable_quantities() == {}
    p = torch.tensor([[0.8, 2.0]], dtype=torch.float64)
    q, qd = reference_rollout(system, torch.tensor([[0.3]], dtype=torch.float64),
                              torch.tensor([[0.0]], dtype=torch.float64), p, DT, 600)
    q, qd = q[0], qd[0]
    qdd = system.free_acceleration(q, qd, p.expand(len(q), -1))
    t = np.arange(len(q)) * DT
    result = identify(_AlmostInvariant(system), system, t, q.numpy(), qd.numpy(), qdd=qdd.numpy(),
                      method="acceleration", starts=2, steps=150)
    assert not result.quantities["m"]["identifiable"] and not result.quantities["k"]["identifiable"]
    ratio = result.quantities["k/m"]
    assert ratio["identifiable"] and ratio["value"] == pytest.approx(2.5, rel=0.05) and ratio["rel_std"] < 0.05
    (direction,) = result.unidentifiable
    assert direction["scale"] and set(direction["direction"]) == {"m", "k"}
    assert direction["why"] in ("box", "ratio")  # (which rule left it out: the report says which)


@pytest.mark.slow
def test_trajectory_fit_of_the_closed_form_recovers_the_parameters():
    """Rollouts (RK4 at the sampling step) against the exact trajectory: the fit's bias is the
    integrator's error alone."""
    system, t, q, qd, _ = observe(seconds=0.5)
    result = identify(ClosedForm(system), system, t, q, qd, method="trajectory", starts=2, steps=60, window=0.1)
    for name, value in true_quantities().items():
        assert result.quantities[name]["value"] == pytest.approx(value, rel=1e-4), name
    assert result.method == "trajectory" and result.residual_rms["trajectory"] < 1e-3


def test_least_squares_on_the_true_equations_is_exact_and_degrades_gracefully():
    system, t, q, qd, qdd = observe()
    exact = least_squares_reference(system, t, q, qd, qdd=qdd)
    for name, value in true_quantities().items():
        assert exact[name]["value"] == pytest.approx(value, rel=1e-9), name
    estimated = least_squares_reference(system, t, q)  # derivatives estimated from the positions alone
    for name, value in true_quantities().items():
        assert estimated[name]["value"] == pytest.approx(value, rel=1e-3), name
    damped = get_system("double_pendulum", joint_damping=[0.1, 0.1])
    assert least_squares_reference(damped, t, q) is None  # not in its equations: no reference


def test_batched_identification_equals_one_at_a_time():
    system, t, q, qd, qdd = observe(seconds=1.0)
    _, _, q2, qd2, qdd2 = observe(params=(0.9, 1.1, 1.0, 1.3), seconds=1.0, q0=(-0.5, 1.0))
    model = ClosedForm(system)
    both = identify_batch(model, system, t, np.stack([q, q2]), np.stack([qd, qd2]), qdd=np.stack([qdd, qdd2]),
                          method="acceleration", starts=3, steps=100)
    alone = identify(model, system, t, q2, qd2, qdd=qdd2, method="acceleration", starts=3, steps=100)
    for name in ("m2/m1", "l1", "l2"):
        assert both[1].quantities[name]["value"] == pytest.approx(alone.quantities[name]["value"], rel=1e-6)
    assert both[1].quantities["l1"]["value"] == pytest.approx(1.0, rel=1e-6)
    assert not both[1].at_bound


def test_an_observation_the_model_cannot_explain_is_said_not_estimated_silently():
    """Angles logged in degrees, or a pendulum at rest with sensor noise: the fit returned parameters with small
    stated uncertainties and no word. A residual beyond half the accelerations' rms now warns (one warning per
    observation, naming it in a batch); the scene's own noisy trajectory does not."""
    import warnings

    from lnn_torch import PoorFitWarning

    system, t, q, qd, _ = observe(seconds=1.0)
    model = ClosedForm(system)
    noisy = q + np.random.default_rng(0).normal(0, 1e-3, q.shape)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PoorFitWarning)
        fine = identify(model, system, t, noisy, method="acceleration", starts=2, steps=60)
    assert fine.quantities["l1"]["value"] == pytest.approx(TRUE[2], rel=0.05)
    still = np.random.default_rng(1).normal(0, 1e-5, q.shape)
    with pytest.warns(PoorFitWarning) as caught:
        identify_batch(model, system, t, np.stack([q, np.degrees(q), still]), method="acceleration", starts=2,
                       steps=60)
    messages = [str(w.message) for w in caught if issubclass(w.category, PoorFitWarning)]
    assert len(messages) == 2 and "(observation 1)" in messages[0] and "(observation 2)" in messages[1]
    assert "scene 'double_pendulum'" in messages[0] and "other units" in messages[0]


@pytest.mark.slow
def test_learned_model_identifies_noisy_observations_within_the_stated_uncertainty():
    """The shipped model, 1e-3 rad position noise (derivatives from a smoothing spline), the
    acceleration fit: each identifiable quantity within 3 stated standard deviations of the truth
    and within 3 %; the mass scale flagged."""
    from lnn_torch.training.checkpoints import load_model

    module = load_model("pretrained:double_pendulum")
    system, t, q, _, _ = observe(seconds=2.0)
    noisy = q + np.random.default_rng(0).normal(0.0, 1e-3, q.shape)
    result = module.identify(t, noisy)
    for name, value in true_quantities().items():
        est = result.quantities[name]
        assert est["identifiable"], name
        err = abs(est["value"] / value - 1)
        assert err < 0.03 and err < 3 * est["rel_std"] + 1e-3, (name, err, est["rel_std"])
    assert any(set(d["direction"]) == {"m1", "m2"} for d in result.unidentifiable)


@pytest.mark.parametrize("case, message", [
    ("dof", r"q must be \(T, 2\) for scene 'double_pendulum' \(one trajectory"),
    ("short", "too short"),
    ("nan", "q contains NaN"),
    ("uneven", "not uniformly sampled"),
    ("method", "method must be"),
])
def test_bad_observations_are_refused_with_a_clear_error(case, message):
    system, t, q, _, _ = observe(seconds=0.5)
    model = ClosedForm(system)
    kwargs = {}
    if case == "dof":
        q = np.concatenate([q, q[:, :1]], 1)
    elif case == "short":
        t, q = t[:10], q[:10]
    elif case == "nan":
        q = q.copy()
        q[5, 1] = np.nan
    elif case == "uneven":
        t = t.copy()
        t[7] += 0.3 * DT
    else:
        kwargs["method"] = "profile"
    with pytest.raises(InputError, match=message):
        identify(model, system, t, q, **kwargs)


def test_identify_command_on_a_dataset_trajectory_and_a_csv(tmp_path, capsys):
    from lnn_torch.cli import main
    from lnn_torch.data import DatasetSpec, generate_dataset

    data = tmp_path / "d.h5"
    generate_dataset(DatasetSpec(scene="double_pendulum", num_trajectories=10, duration=1.0, seed=5), data)
    out = tmp_path / "id"
    fast = ["--method", "acceleration", "--starts", "2", "--steps", "60"]
    assert main(["identify", "pretrained:double_pendulum", str(data), "--trajectory", "0", "--use", "q+qd+qdd",
                 "-o", str(out), *fast]) == 0
    report = json.loads((out / "identification.json").read_text())
    assert set(report["truth"]) == {"m1", "m2", "l1", "l2"} and report["least_squares"] is not None
    truth = report["truth"]
    assert report["quantities"]["l1"]["value"] == pytest.approx(truth["l1"], rel=0.03)
    assert not report["quantities"]["m1"]["identifiable"]
    text = (out / "report.md").read_text()
    assert "not identifiable" in text and "| l2 |" in text and "least squares" in text
    assert (out / "fit.png").stat().st_size > 5000
    capsys.readouterr()

    # a CSV recording: the closed-form columns written by lnn-torch simulate
    sim = tmp_path / "sim.csv"
    assert main(["simulate", "--params", "1.0", "0.6", "1.2", "1.1", "--q0", "1.0", "-0.5", "--duration", "1",
                 "-o", str(sim)]) == 0
    out2 = tmp_path / "id_csv"
    assert main(["identify", "pretrained:double_pendulum", str(sim), "--coordinates", "theta1_exact", "theta2_exact",
                 "-o", str(out2), *fast]) == 0
    report = json.loads((out2 / "identification.json").read_text())
    assert report["truth"] is None and report["quantities"]["l2"]["value"] == pytest.approx(1.1, rel=0.03)
    # epoch stamps (float64 round-off, 1e-4 of the step) are uniform: they were refused as "not uniformly sampled"
    lines = [ln for ln in sim.read_text().splitlines() if not ln.startswith("#")]
    epoch = tmp_path / "epoch.csv"
    epoch.write_text("\n".join([lines[0]] + [",".join([repr(1.7e9 + float(row.split(",")[0]))] + row.split(",")[1:])
                                             for row in lines[1:]]) + "\n")
    assert main(["identify", "pretrained:double_pendulum", str(epoch), "--coordinates", "theta1_exact",
                 "theta2_exact", "-o", str(tmp_path / "id_epoch"), *fast]) == 0
    again = json.loads((tmp_path / "id_epoch" / "identification.json").read_text())
    assert again["quantities"]["l2"]["value"] == pytest.approx(report["quantities"]["l2"]["value"], rel=1e-3)
    capsys.readouterr()

    # bad input names the problem
    assert main(["identify", "pretrained:double_pendulum", str(sim), "--coordinates", "theta1", "-o", str(out2)]) == 2
    assert "1 coordinate column(s) given, but scene 'double_pendulum' has 2" in capsys.readouterr().err
    assert main(["identify", "pretrained:double_pendulum", str(sim), "--coordinates", "a", "b", "-o", str(out2)]) == 2
    assert "no column 'a', 'b'" in capsys.readouterr().err
    assert main(["identify", "pretrained:double_pendulum", str(data), "--trajectory", "9", "-o", str(out2)]) == 2
    assert "out of range" in capsys.readouterr().err
    assert main(["identify", "pretrained:double_pendulum", str(data), "--feedback", "-o", str(out2)]) == 2
    assert "--feedback is for a model of a measured robot arm" in capsys.readouterr().err


def test_the_search_box_keeps_a_nonnegative_parameter_at_or_above_zero():
    """A friction coefficient's box from a model's training spread (mean +- 3 std) reached below zero: a negative
    friction was returned, and the command's report then refused it. The box starts at 0 for such parameters."""
    from lnn_torch.identification.learned import _Space

    space = _Space(["positive", "nonnegative"], torch.tensor([-1.0, -0.02]), torch.tensor([1.0, 0.07]))
    x = space.x(torch.tensor([[-50.0, -50.0], [50.0, 50.0]], dtype=torch.float64))
    assert float(x[0, 1]) >= 0.0 and float(x[1, 1]) == pytest.approx(0.07)
    assert float(x[0, 0]) == pytest.approx(-1.0)  # (a positive parameter's log may be negative)
