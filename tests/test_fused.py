"""The fused inference path (``lnn_torch.networks.fused``): the two FiLM networks of the default
``film_lnn`` run as one stacked network where no gradient is recorded. It must give what the
part-by-part path gives (float64), follow the weights when they change, and step aside wherever it
does not apply (gradients, other compositions)."""

import pytest
import torch

from lnn_torch.networks import build_model
from lnn_torch.networks.fused import fusable, fusion_plan
from lnn_torch.systems import get_system

from .conftest import random_batch, random_inputs
from .helpers import perturbed


def plain(model):
    """``model`` with the fused path switched off (the part-by-part path, as under a gradient)."""
    model.fuse_inference = False
    return model


def _model(scene, rng, **kw):
    system = get_system(scene, **kw.pop("scene_config", {}))
    model = perturbed(build_model("film_lnn", system, **kw).double()).eval()
    q, qd, params = random_batch(system, rng, 64)
    tau = random_inputs(system, rng, 64)
    stats = {"q": q, "qd": qd, "qdd": system.acceleration(q, qd, params, tau), "params": params,
             "params_points": params, **({"tau": tau} if tau is not None else {})}
    model.fit_normalizer(stats)
    return model, system


@pytest.mark.parametrize("scene, kw", [
    ("double_pendulum", {}),
    ("double_pendulum", {"hidden_dims": (16, 24, 16)}),
    ("actuated_double_pendulum", {"hidden_dims": (16, 16)}),  # inputs and learned friction
    ("chain_pendulum", {"scene_config": {"num_links": 3}, "hidden_dims": (16, 16)}),
    ("mass_spring", {"hidden_dims": (16, 16)}),  # coordinates that are not angles
    ("pendulum", {"hidden_dims": (16, 16)}),
])
@pytest.mark.parametrize("batch", [1, 32])  # products with few outputs: as they are at 1, transposed at 32
def test_fused_path_equals_the_parts(scene, kw, batch, rng):
    """Accelerations (SI) and a rollout under ``no_grad`` (the fused path) equal the part-by-part path
    to 1e-12 in float64."""
    import copy

    model, system = _model(scene, rng, **kw)
    assert fusable(model)
    reference = plain(copy.deepcopy(model))
    q, qd, params = random_batch(system, rng, batch)
    tau = random_inputs(system, rng, batch)
    with torch.no_grad():
        got = model.acceleration(q, qd, params, tau)
        assert model._fusion_plan is not None  # it ran fused
        want = reference.acceleration(q, qd, params, tau)
        torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)
        steps = None if tau is None else tau[:, None].expand(-1, 4, -1)
        for a, b in zip(model.rollout(q, qd, params, 0.001, 4, tau=steps),
                        reference.rollout(q, qd, params, 0.001, 4, tau=steps), strict=True):
            torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)


def test_fused_path_follows_the_weights(rng):
    """Weights changed in place (an optimiser step, ``load_state_dict``) or a dtype change re-stack the
    plan: the results stay those of the part-by-part path."""
    import copy

    model, system = _model("double_pendulum", rng, hidden_dims=(16, 16))
    q, qd, params = random_batch(system, rng, 8)
    with torch.no_grad():
        before = model.acceleration(q, qd, params)
        plan = model._fusion_plan
        for p in model.parameters():
            p.mul_(1.1)
        after = model.acceleration(q, qd, params)
        assert model._fusion_plan is not plan
        assert not torch.allclose(before, after)
        torch.testing.assert_close(after, plain(copy.deepcopy(model)).acceleration(q, qd, params),
                                   rtol=1e-12, atol=1e-12)
        out = model._kinetic_parts[0].net.out
        out.weight = torch.nn.Parameter(out.weight * 1.5)  # a weight replaced, not changed in place
        replaced = model.acceleration(q, qd, params)
        assert not torch.allclose(replaced, after)
        torch.testing.assert_close(replaced, plain(copy.deepcopy(model)).acceleration(q, qd, params),
                                   rtol=1e-12, atol=1e-12)
        with model.residuals_off():  # the parts swapped (none is a residual here): the same model
            torch.testing.assert_close(model.acceleration(q, qd, params), replaced, rtol=1e-12, atol=1e-12)
        after = replaced
        model.float()
        torch.testing.assert_close(model.acceleration(q, qd, params), after, rtol=1e-4, atol=1e-4)
        assert model._fusion_plan.weights[0].dtype == torch.float32


@pytest.mark.parametrize("fused_kernel", [False, True])
def test_an_optimiser_step_restacks_the_plan(fused_kernel, rng):
    """Training and evaluating in turn (as Lightning validates between steps): every evaluation after an
    optimiser step sees the new weights, also where the step does not bump the weights' version counters
    (the fused AdamW kernel, which the training uses)."""
    import copy

    model, system = _model("double_pendulum", rng, hidden_dims=(16, 16))
    q, qd, params = random_batch(system, rng, 8)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-2, fused=fused_kernel)
    for _ in range(2):
        with torch.no_grad():
            got = model.acceleration(q, qd, params)
            torch.testing.assert_close(got, plain(copy.deepcopy(model)).acceleration(q, qd, params),
                                       rtol=1e-12, atol=1e-12)
        model.acceleration(q, qd, params).square().sum().backward()
        opt.step()
        opt.zero_grad()
    with torch.no_grad():
        assert not torch.allclose(model.acceleration(q, qd, params), got)


def test_a_model_made_under_inference_mode_runs_the_parts(rng):
    """Weights that are inference tensors (a model built or cast under ``torch.inference_mode``) have no version
    counter, so no stacked copy could tell when they change: such a model runs part by part, with the same
    result."""
    import copy

    model, system = _model("double_pendulum", rng, hidden_dims=(16, 16))
    q, qd, params = random_batch(system, rng, 4)
    with torch.no_grad():
        expected = model.acceleration(q, qd, params)
    with torch.inference_mode():
        copied = copy.deepcopy(model)  # every weight and buffer an inference tensor
        assert next(copied.parameters()).is_inference()
        got = copied.acceleration(q, qd, params)
        assert fusion_plan(copied) is None
    torch.testing.assert_close(got, expected, rtol=1e-12, atol=1e-12)


def test_fused_path_steps_aside_under_a_gradient(rng):
    """With a gradient recorded the part-by-part path runs: the weights get their gradients."""
    model, system = _model("double_pendulum", rng, hidden_dims=(16, 16))
    q, qd, params = random_batch(system, rng, 8)
    out = model.acceleration(q, qd, params)
    grads = torch.autograd.grad(out.square().sum(), list(model.parameters()), allow_unused=True)
    assert sum(g is not None and bool(g.abs().sum() > 0) for g in grads) > 10
    assert getattr(model, "_fusion_plan", None) is None


@pytest.mark.parametrize("kw", [{"potential_film": False}, {"shared": True}, {"activation": "softplus"},
                                {"film_hidden": 0}, {"film_mode": "layer"}, {"mass_invariant": [0]},
                                {"potential": ["harmonic"]}])
def test_other_compositions_are_not_fused(kw, rng):
    """Any other composition keeps the part-by-part path (and gives what it gave)."""
    system = get_system("double_pendulum")
    model = build_model("film_lnn", system, hidden_dims=(16, 16), **kw).double().eval()
    assert not fusable(model)
    q, qd, params = random_batch(system, rng, 4)
    with torch.no_grad():
        assert torch.isfinite(model.acceleration(q, qd, params)).all()
    assert not fusable(build_model("delan", system, hidden_dims=(16, 16)))
