"""The regimes of motion a scene names (``System.regimes``) and the evaluation that reports a model in
each apart (``lnn_torch.evaluation.regimes``): the double pendulum's samplers give what they declare
(parameters outside the box, energies over the stated range of the potential's span, angles over the
whole circle), an exact model scores zero in every regime and a wrong one is caught, and the report
carries the section."""

from __future__ import annotations

import numpy as np
import torch

from lnn_torch.evaluation.regimes import regime_errors
from lnn_torch.systems import get_system


class Scene(torch.nn.Module):
    """The scene itself as a model (its exact accelerations), optionally with one parameter off."""

    def __init__(self, system, scale: float = 1.0) -> None:
        super().__init__()
        self.system, self.scale = system, scale

    def acceleration(self, q, qd, params, tau=None, check=True):
        params = params.clone()
        params[:, 0] = params[:, 0] * self.scale  # m1 only: the dynamics change unless m2 is zero
        return self.system.acceleration(q, qd, params, tau)


def test_the_double_pendulums_regimes_are_what_they_declare():
    system = get_system("double_pendulum")
    regimes = system.regimes()
    assert list(regimes) == ["in distribution", "out of the parameter range", "high energy, whole circle"]
    rng = np.random.default_rng(0)
    q, qd, p = (torch.as_tensor(x) for x in regimes["out of the parameter range"](rng, 4000))
    m1, m2, l1, l2 = p.unbind(-1)
    ratio, r = m2 / m1, system.m2_ratio
    assert bool(((ratio < r.low * 0.951) | (ratio > r.high * 1.049)).all())
    assert bool(((l1 < 0.9 * 0.951) | (l1 > 2.0 * 1.049)).all()) and bool((l1 < 2.0 * 1.31).all())
    assert bool(((l2 / l1 < 0.9 * 0.951) | (l2 / l1 > 1.1 * 1.049)).all())
    q, qd, p = (torch.as_tensor(x) for x in regimes["high energy, whole circle"](rng, 4000))
    top = 9.81 * ((p[:, 0] + p[:, 1]) * p[:, 2] + p[:, 1] * p[:, 3])
    f = (system.energy(q, qd, p) + top) / (2 * top)
    assert float(f.min()) >= 0.25 - 1e-9 and float(f.max()) <= 1.5 + 1e-9 and float(f.max()) > 1.4
    assert float(q.abs().max()) > 3.1 and float((q.abs() > np.pi / 2).double().mean()) > 0.4


def test_an_exact_model_scores_zero_in_every_regime_and_a_wrong_one_is_caught():
    system = get_system("double_pendulum")
    exact = regime_errors(Scene(system), system, num=500)
    assert set(exact) == set(system.regimes())
    assert all(r["acc_rel_err"] < 1e-12 and r["non_finite"] == 0 for r in exact.values())
    wrong = regime_errors(Scene(system, 1.2), system, num=500)
    assert all(r["acc_rel_err"] > 1e-3 for r in wrong.values())
    # seeded: the same states for every model
    again = regime_errors(Scene(system, 1.2), system, num=500)
    assert again == wrong


def test_the_wider_training_distributions_cover_the_regimes_and_leave_the_default_alone():
    """``param_margin`` and ``whole_circle`` widen what the scene samples (and are recorded in its
    configuration); off, the sampler draws exactly what it drew before (the same generator calls), and the
    regimes stay those of the default box."""
    default = get_system("double_pendulum")
    wide = get_system("double_pendulum", param_margin=0.3, whole_circle={"fraction": 0.3, "omega": 6.0})
    assert "param_margin" not in default.config() and wide.config()["whole_circle"] == {"fraction": 0.3, "omega": 6.0}
    rng = np.random.default_rng(1)
    m1 = np.exp(0.3 * rng.standard_normal(1000))
    expected = np.stack([m1, m1 * rng.uniform(0.2, 1.0, 1000)], -1)
    np.testing.assert_array_equal(default.sample_params(np.random.default_rng(1), 1000)[:, :2], expected)
    p = wide.sample_params(np.random.default_rng(2), 20000)
    ratio = p[:, 1] / p[:, 0]
    assert ratio.min() < 0.2 / 1.25 and ratio.max() > 1.25 and ratio.min() >= 0.2 / 1.3 and ratio.max() <= 1.3
    q, qd = wide.sample_state(np.random.default_rng(3), 20000)
    circle = np.abs(q).max(-1) > np.pi / 2
    assert 0.20 < circle.mean() < 0.25  # three quarters of the 30 % drawn over the circle land beyond +-90 degrees
    assert np.abs(qd).max() > 5.9 and np.abs(q).max() > 3.1
    assert list(wide.regimes()) == list(default.regimes())
    for name, draw in wide.regimes().items():  # the same states: judged in the default box's regimes
        for got, want in zip(draw(np.random.default_rng(4), 50), default.regimes()[name](np.random.default_rng(4), 50),
                             strict=True):
            np.testing.assert_array_equal(got, want)
    import pytest

    from lnn_torch.errors import InputError

    with pytest.raises(InputError, match="whole_circle takes fraction and omega"):
        get_system("double_pendulum", whole_circle={"share": 0.3})
    with pytest.raises(InputError, match="param_margin must be in"):
        get_system("double_pendulum", param_margin=-0.1)
