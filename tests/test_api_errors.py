"""Mistakes a new user of the Python API makes, each refused in one line naming the problem (a new-user trial's
list): integer or numpy states (integers truncated the results: a mass matrix of zeros), a non-positive parameter
named by its name, an unknown pretrained model (an ``InputError`` that is also a ``KeyError``), a fractional step
count, and ``evaluate_model`` given what ``load_model`` returns (taken as its network) or a model of another scene."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lnn_torch import load_model
from lnn_torch.errors import InputError
from lnn_torch.evaluation import evaluate_model
from lnn_torch.systems import get_system


@pytest.fixture(scope="module")
def model():
    return load_model("pretrained:double_pendulum")


def test_states_that_are_not_floating_point_tensors_are_refused(model):
    p = torch.tensor([[1.0, 0.6, 1.2, 1.1]])
    for call in (lambda: model.acceleration(torch.tensor([[1, 0]]), torch.zeros(1, 2), p),
                 lambda: model.mass_matrix(torch.tensor([[1, 0]]), p),
                 lambda: model.model.acceleration(torch.tensor([[1, 0]]), torch.zeros(1, 2), p)):
        with pytest.raises(InputError, match=r"^q must be floating point, got torch\.int64 \(e\.g\. torch\.tensor"):
            call()
    with pytest.raises(InputError, match=r"^q must be a torch\.Tensor, got ndarray \(torch\.as_tensor\(q, "):
        model.acceleration(np.zeros((1, 2)), torch.zeros(1, 2), p)
    rest = torch.zeros(1, 2)  # integer parameters are cast (their values are whole numbers already)
    torch.testing.assert_close(model.acceleration(rest, rest, torch.tensor([[1, 1, 1, 1]])),
                               model.acceleration(rest, rest, torch.ones(1, 4)))


def test_a_non_positive_parameter_is_named_and_other_mistakes_are_one_line(model):
    for call in (model.acceleration, model.model.acceleration):
        with pytest.raises(InputError, match=r"non-positive values in \['m1'\]"):
            call(torch.zeros(1, 2), torch.zeros(1, 2), torch.tensor([[-1.0, 0.6, 1.2, 1.1]]))
    with pytest.raises(InputError, match=r"^no pretrained model 'nope'; available: double_pendulum") as err:
        load_model("pretrained:nope")
    assert isinstance(err.value, KeyError) and str(err.value).startswith("no pretrained")  # no KeyError quotes
    with pytest.raises(InputError, match=r"^num_steps must be an integer, got 2\.5$"):
        model.model.rollout(torch.zeros(1, 2), torch.zeros(1, 2), torch.ones(1, 4), 0.01, 2.5)


def test_evaluate_model_takes_what_load_model_returns_and_refuses_another_scene(model, tmp_path):
    from lnn_torch.data import DatasetSpec, generate_dataset, read_dataset

    path = generate_dataset(DatasetSpec(num_trajectories=2, duration=0.5, dt=0.01, seed=0, split=(1.0, 0.0, 0.0)),
                            tmp_path / "dp.h5")
    data = read_dataset(path).trajectories("train")
    whole = evaluate_model(model, model.system, data, sections=("accelerations",))
    network = evaluate_model(model.model, model.system, data, sections=("accelerations",))
    assert whole["acc_rel_err"]["total"] == network["acc_rel_err"]["total"] < 0.01
    with pytest.raises(InputError, match=r"^the model is of scene 'double_pendulum' \(2 coordinates, 4 parameters\); "
                                         r"the data are of 'pendulum' \(1 coordinates, 2 parameters\)$"):
        evaluate_model(model, get_system("pendulum"), data)


def test_a_rollout_that_becomes_non_finite_is_warned_of(model):
    """From a state far beyond any trained (a million rad/s) the learned flow overflows: the rollout says how
    many trajectories and from when; an ordinary one says nothing."""
    import warnings

    p = torch.tensor([[1.0, 0.6, 1.2, 1.1]] * 2)
    with pytest.warns(RuntimeWarning, match=r"rollout: 1 of 2 trajectories became non-finite \(the first at step \d+"):
        model.rollout(torch.zeros(2, 2), torch.tensor([[1e6, 0.0], [0.1, 0.0]]), p, 0.01, 50)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model.rollout(torch.zeros(2, 2), torch.tensor([[1.0, 0.0], [0.1, 0.0]]), p, 0.01, 50)


def test_a_device_this_machine_cannot_load_on_is_named():
    """load_model on a CUDA device without CUDA, on 'meta' or on no device at all: one line saying so (torch's error
    was read as "not an lnn-torch checkpoint")."""
    import torch

    from lnn_torch import load_model
    from lnn_torch.errors import InputError

    cases = [("meta", "a model needs its weights"), ("nodevice", "is not a device")]
    if not torch.cuda.is_available():
        cases.append(("cuda", "this machine has no CUDA device"))
    for device, message in cases:
        with pytest.raises(InputError, match=message) as err:
            load_model("pretrained:double_pendulum", map_location=device)
        assert "\n" not in str(err.value)


def test_identify_names_the_shape_it_was_given(model):
    """One trajectory of the wrong width: the shape given is named (it was the batched (1, T, dof) inside)."""
    from lnn_torch.errors import InputError

    with pytest.raises(InputError, match=r"q must be \(T, 2\) for scene 'double_pendulum' \(one trajectory: its "
                                         r"samples, its coordinates\), got \(11, 3\)"):
        model.identify(torch.arange(11) * 0.01, torch.zeros(11, 3))

