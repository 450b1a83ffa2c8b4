"""``lnn_torch.identification.velocity_feedback``: the gains of a robot's feedback on its measured velocity, recovered
from a torque error that holds it, dropped where validation does not prefer them, and clear errors."""

import pytest
import torch

from lnn_torch.errors import InputError
from lnn_torch.identification import velocity_feedback as vf


def _signals(n: int, gains: torch.Tensor, seed: int, noise: float = 0.05):
    g = torch.Generator().manual_seed(seed)
    band = 0.01 * torch.randn(n, len(gains), generator=g, dtype=torch.float64)
    rest = noise * torch.randn(n, len(gains), generator=g, dtype=torch.float64)
    return rest - gains * band, band  # the error a model of the smoothed state leaves: -D band + the rest


def test_the_gains_are_recovered_and_the_correction_removes_them():
    D = torch.tensor([30.0, 5.0, 12.0], dtype=torch.float64)
    (e_tr, b_tr), (e_va, b_va), (e_te, b_te) = (_signals(20000, D, s) for s in (0, 1, 2))
    fb = vf.fit(e_tr, b_tr, e_va, b_va)
    assert fb.kept == [True, True, True]
    # least squares on 20000 points: the gain's standard error is noise / (0.01 sqrt(20000)) = 0.035
    torch.testing.assert_close(fb.gains, D, atol=0.2, rtol=0)
    after = e_te - fb.torque(b_te)  # what the model with the feedback added still misses
    rest = e_te + D * b_te
    assert (after.pow(2).mean(0).sqrt() <= 1.001 * rest.pow(2).mean(0).sqrt()).all()
    assert (after.pow(2).mean(0) < 0.7 * e_te.pow(2).mean(0)).all()
    assert all(a < b for a, b in zip(fb.val_rms_after, fb.val_rms_before, strict=True))


def test_a_gain_that_validation_does_not_prefer_is_zero():
    """Joint 2's training error holds a gain its validation error does not (zero there): any gain only
    adds error on validation, so the fit drops it; joint 1's is kept."""
    D = torch.tensor([20.0, 20.0], dtype=torch.float64)
    e_tr, b_tr = _signals(5000, D, 0)
    e_va, b_va = _signals(5000, D, 1)
    e_va[:, 1] = 0.0
    fb = vf.fit(e_tr, b_tr, e_va, b_va)
    assert fb.kept == [True, False] and float(fb.gains[1]) == 0.0 and float(fb.gains[0]) > 15.0
    assert fb.val_rms_after[1] == fb.val_rms_before[1] == 0.0
    torch.testing.assert_close(fb.torque(b_va)[:, 1], torch.zeros(5000, dtype=torch.float64))


def test_band_is_the_recorded_velocity_less_the_smoothed_one():
    recorded = torch.tensor([[1.0, 2.0], [3.0, 4.0]])
    smoothed = torch.tensor([[0.5, 2.5], [3.0, 3.0]])
    want = torch.tensor([[0.5, -0.5], [0.0, 1.0]], dtype=torch.float64)
    torch.testing.assert_close(vf.band(recorded, smoothed), want)


@pytest.mark.parametrize(("call", "message"), [
    (lambda: vf.band(torch.zeros(3, 2), torch.zeros(3, 3)),
     r"smoothed velocities has shape \(3, 3\), expected \(3, 2\)"),
    (lambda: vf.band(torch.zeros(3), torch.zeros(3)), r"recorded velocities must be \(points, joints\)"),
    (lambda: vf.band(torch.tensor([[float("nan")]]), torch.zeros(1, 1)), "recorded velocities holds NaN"),
    (lambda: vf.fit(torch.zeros(4, 2), torch.zeros(4, 2), torch.zeros(4, 3), torch.zeros(4, 3)),
     "validation has 3 joints, training 2"),
    (lambda: vf.fit(torch.zeros(4, 2), torch.zeros(5, 2), torch.zeros(4, 2), torch.zeros(4, 2)),
     r"training velocity band has shape \(5, 2\), expected \(4, 2\)"),
    (lambda: vf.VelocityFeedback(torch.zeros(2), [False, False], [0.0, 0.0], [0.0, 0.0]).torque(torch.zeros(3, 3)),
     "velocity band has 3 joints, the feedback 2"),
])
def test_bad_input_is_one_clear_error(call, message):
    with pytest.raises(InputError, match=message):
        call()
