"""The structured model's parts: the registries, the ways of naming parts, and that a new part is one
class plus one registration (``lnn_torch.networks.parts``)."""

from __future__ import annotations

import warnings

import pytest
import torch

from lnn_torch.networks import build_model
from lnn_torch.networks.parts import KINETIC_PARTS, POTENTIAL_PARTS, PotentialPart, PotentialTerm
from lnn_torch.systems import InputError, get_system
from lnn_torch.systems.measured import MeasuredSystem

from .conftest import random_batch
from .helpers import assert_fast_path_is_the_references

RELATIVE2 = [[1, 0], [1, 1]]


def _outputs(model, batch):
    q, qd, params, tau = batch
    return model.acceleration(q, qd, params, tau), model.energy_norm(*model.normalize(q, qd, params))[0]


@pytest.mark.parametrize("old, new", [
    (dict(kinetic="chain+mlp", links=RELATIVE2, potential="chain+harmonic"),
     dict(kinetic={"chain": {"links": RELATIVE2}, "mlp": {}}, potential={"chain": {}, "harmonic": None})),
    (dict(potential="harmonic+mlp"), dict(potential=["harmonic", "mlp"])),  # any order: the registry's
])
def test_the_old_string_forms_build_the_same_model_with_a_deprecation(old, new, rng):
    system = get_system("actuated_double_pendulum")
    with pytest.warns(FutureWarning, match="deprecated"):
        torch.manual_seed(0)
        a = build_model("film_lnn", system, hidden_dims=(8, 8), **old).double()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the new forms warn about nothing
        torch.manual_seed(0)
        b = build_model("film_lnn", system, hidden_dims=(8, 8), **new).double()
    assert a.state_dict().keys() == b.state_dict().keys()
    assert all(torch.equal(x, b.state_dict()[k]) for k, x in a.state_dict().items())
    batch = (*random_batch(system, rng, 8), torch.randn(8, system.num_inputs, dtype=torch.float64))
    for x, y in zip(_outputs(a, batch), _outputs(b, batch), strict=True):
        assert torch.equal(x, y)


def test_a_parts_own_options_override_the_models_defaults():
    model = build_model("film_lnn", get_system("double_pendulum"), hidden_dims=(16, 16),
                        kinetic={"mlp": {"hidden_dims": [8]}}, potential={"mlp": {"activation": "softplus"}})
    assert [layer.out_features for layer in model.kinetic["mlp"].net.hidden] == [8]
    assert [layer.out_features for layer in model.potential["mlp"].net.hidden] == [16, 16]
    assert model.potential["mlp"].net.activation == "softplus" and model.kinetic["mlp"].net.activation == "tanh"
    assert len(model.kinetic["mlp"].film.sizes) == 1  # the FiLM follows its network's widths


def test_bad_part_specifications_are_refused_in_one_line():
    dp = get_system("double_pendulum")
    with pytest.raises(InputError, match=r"unknown kinetic part 'cholesky'; known: chain, mlp"):
        build_model("film_lnn", dp, kinetic="cholesky")
    with pytest.raises(InputError, match=r"potential part 'mlp' takes no option 'links', 'width'; its options"):
        build_model("film_lnn", dp, potential={"mlp": {"width": 3, "links": [[1]]}})
    with pytest.raises(InputError, match="names no part"):
        build_model("film_lnn", dp, potential={})
    with pytest.raises(InputError, match="takes a dict of options"):
        build_model("film_lnn", dp, potential={"mlp": 3})
    with pytest.raises(InputError, match="residual"):  # set by the model, not an option
        build_model("film_lnn", dp, kinetic={"mlp": {"residual": True}})


def test_options_no_part_takes_are_listed_together():
    """Part-specific options no part uses are refused together; network defaults that no part uses
    are named in one warning (the rule of ``StructuredLagrangian``)."""
    scene = MeasuredSystem(2, input_names=["a", "b"])
    with pytest.raises(InputError, match="takes no option mass_invariant"):
        build_model("film_lnn", scene, mass_invariant=[0], kinetic={"chain": {"links": RELATIVE2}})
    with pytest.raises(InputError, match="cannot be combined with potential 'harmonic', mass_invariant, links"):
        build_model("film_lnn", scene, shared=True, potential="harmonic", links=RELATIVE2, mass_invariant=[0])
    with pytest.raises(InputError, match="takes no option 'film_hidden', 'potential'"):  # another variant
        build_model("hnn", scene, potential="mlp", film_hidden=4)
    chain = {"chain": {"links": RELATIVE2}}
    with pytest.warns(UserWarning, match="ignored activation, hidden_dims"):
        build_model("film_lnn", scene, kinetic=chain, potential="chain", hidden_dims=(8, 8), activation="softplus")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the defaults themselves are not 'given'
        build_model("film_lnn", scene, kinetic=chain, potential="chain", hidden_dims=(64, 64))


def test_delan_is_the_same_composition_with_concatenated_conditioning():
    system = get_system("actuated_double_pendulum")
    film = build_model("film_lnn", system, hidden_dims=(8, 8))
    delan = build_model("delan", system, hidden_dims=(8, 8), kinetic={"chain": {"links": RELATIVE2}, "mlp": {}})
    assert type(delan).__mro__[1] is type(film).__mro__[1]  # one abstract base, neither a subclass of the other
    assert not isinstance(delan, type(film)) and not isinstance(film, type(delan))
    assert film.kinetic["mlp"].film is not None and delan.kinetic["mlp"].film is None
    assert delan.kinetic["mlp"].net.hidden[0].in_features == delan.num_features + system.num_params
    assert list(delan.kinetic) == ["chain", "mlp"]


class _Spring(PotentialPart):
    """A test part: ``V = 1/2 k |q|^2`` with one learned stiffness ``k = exp(log_k)``."""

    name = "spring"

    def __init__(self, ctx, stiffness: float = 2.0) -> None:
        super().__init__()
        self.log_k = torch.nn.Parameter(torch.tensor(float(stiffness)).log())

    def coefficient_parameters(self):
        return [self.log_k]

    def potential(self, inputs, cond, grad):
        k = self.log_k.exp().to(inputs.q_norm.dtype)
        q = inputs.q_norm
        return PotentialTerm(0.5 * k * (q * q).sum(-1), dV_dq=k * q if grad else None)

    def reference_potential(self, q_norm, params_norm, phi, gravity):
        return 0.5 * self.log_k.exp() * (q_norm * q_norm).sum(-1)


def test_a_new_potential_is_one_class_plus_one_registration(monkeypatch, rng):
    """Registered beside the others, a new part is built from its name and options, summed with the
    other parts, solved by the fast path as by the generic Hessian solve of its reference, and its
    coefficient is exempt from weight decay."""
    monkeypatch.setitem(POTENTIAL_PARTS, "spring", _Spring)
    system = get_system("mass_spring")
    model = build_model("film_lnn", system, hidden_dims=(8, 8), potential={"mlp": {}, "spring": {"stiffness": 3.0}})
    model = model.double()
    assert list(model.potential) == ["mlp", "spring"]
    assert any(p is model.potential["spring"].log_k for p in model.coefficient_parameters())
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.3 * torch.randn(p.shape, dtype=p.dtype))
    q, qd, params = random_batch(system, rng, 16)
    assert_fast_path_is_the_references(model, system, *model.normalize(q, qd, params))
    V_mlp = model.potential["mlp"].potential(model._part_inputs(q, model.normalize(q, qd, params)[2], False),
                                             model.films(model.normalize(q, qd, params)[2])[1], False).V
    k = model.potential["spring"].log_k.exp()
    torch.testing.assert_close(model.potential_norm(q, model.normalize(q, qd, params)[2])[0],
                               V_mlp + 0.5 * k * (q * q).sum(-1), rtol=1e-12, atol=1e-12)


# the spatial arm's parts need a robot description: tests/test_spatial_part.py compares them with theirs
PLANAR_POTENTIALS = sorted(n for n in POTENTIAL_PARTS if n != "spatial")
PLANAR_KINETICS = sorted(n for n in KINETIC_PARTS if n != "spatial")


@pytest.mark.parametrize("name", PLANAR_POTENTIALS)
def test_every_registered_potential_part_has_its_reference(name, rng):
    """Every registered potential part, with the kinetic part it needs, solves as its reference."""
    system = get_system("actuated_double_pendulum")
    kinetic = {"chain": {"links": RELATIVE2}} if name == "chain" else "mlp"
    model = build_model("film_lnn", system, hidden_dims=(8, 8), kinetic=kinetic, potential=name).double()
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.3 * torch.randn(p.shape, dtype=p.dtype))
    q, qd, params = random_batch(system, rng, 16)
    assert_fast_path_is_the_references(model, system, *model.normalize(q, qd, params))


@pytest.mark.parametrize("name", PLANAR_KINETICS)
def test_every_registered_kinetic_part_has_its_reference(name, rng):
    system = get_system("actuated_double_pendulum")
    kinetic = {name: {"links": RELATIVE2}} if name == "chain" else name
    model = build_model("delan", system, hidden_dims=(8, 8), kinetic=kinetic).double()
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.3 * torch.randn(p.shape, dtype=p.dtype))
    q, qd, params = random_batch(system, rng, 16)
    assert_fast_path_is_the_references(model, system, *model.normalize(q, qd, params))


def test_a_state_dict_saved_before_parts_loads(rng):
    """Checkpoints written before parts name the networks ``kinetic_net``, ``potential_coef``,
    ``chain``, ``trunk``...: they load into the parts unchanged."""
    old_names = {"kinetic.mlp.net.": "kinetic_net.", "conditioning_nets.kinetic_mlp.": "kinetic_film.",
                 "potential.mlp.net.": "potential_net.", "conditioning_nets.potential_mlp.": "potential_film.",
                 "potential.harmonic.coef": "potential_coef", "kinetic.chain.": "chain."}
    scene = MeasuredSystem(2, input_names=["a", "b"])
    model = build_model("film_lnn", scene, hidden_dims=(8, 8), kinetic={"chain": {"links": RELATIVE2}, "mlp": {}},
                        potential=["mlp", "harmonic"])
    with torch.no_grad():
        for p in model.parameters():
            p.add_(torch.randn(p.shape))
    saved = {}
    for key, value in model.state_dict().items():
        for new, old in old_names.items():
            if key.startswith(new):
                key = old + key[len(new):]
                break
        saved[key] = value
    assert "potential_coef" in saved and "chain.raw" in saved and "kinetic_net.out.bias" in saved
    fresh = build_model("film_lnn", scene, hidden_dims=(8, 8), kinetic={"chain": {"links": RELATIVE2}, "mlp": {}},
                        potential=["mlp", "harmonic"])
    fresh.load_state_dict(saved)  # strict
    assert all(torch.equal(v, fresh.state_dict()[k]) for k, v in model.state_dict().items())
