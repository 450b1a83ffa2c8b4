"""The model registry (``lnn_torch.networks.registry``): every variant is registered, each class declares
its options and defaults, options a variant does not take are refused, and they travel with the
module's hyper-parameters."""

import pytest

from lnn_torch.networks import MODELS, VARIANTS, build_model, model_options
from lnn_torch.systems import InputError, get_system


def test_registry_maps_every_variant_and_each_class_declares_its_defaults():
    assert set(VARIANTS) == set(MODELS) == {"film_lnn", "delan", "lnn", "mlp", "hnn"}
    for name, cls in MODELS.items():
        assert cls.variant == name
        assert "hidden_dims" in model_options(name) and "activation" in model_options(name)
    assert model_options("lnn")["activation"] == "softplus" and model_options("film_lnn")["activation"] == "tanh"
    system = get_system("pendulum")
    assert build_model("film_lnn", system, film_mode="layer").kinetic["mlp"].film.mode == "layer"
    with pytest.raises(InputError, match="model variant 'mlp' takes no option 'film_mode'"):
        build_model("mlp", system, film_mode="layer")
    with pytest.raises(InputError, match="unknown model variant 'hnnn'"):
        build_model("hnnn", system)


def test_module_refuses_an_option_its_variant_does_not_take_but_loads_old_checkpoints():
    from lnn_torch import LNNModule

    with pytest.raises(InputError, match=r"cannot use: option 'hnn_coordinates' \(not an option of mlp\)"):
        LNNModule(variant="mlp", hnn_coordinates="velocity", hidden_dims=[8])
    # older checkpoints record every option with its old default for every variant: still loads
    old = dict(variant="mlp", hidden_dims=[8], film_mode="neuron", potential_film=True, eps=1e-4, lnn_init=False,
               hnn_coordinates="canonical")
    assert LNNModule(**old).model.variant == "mlp"


def test_shared_network_option_travels_with_the_module_hyperparameters():
    from lnn_torch import LNNModule

    module = LNNModule(hidden_dims=[8, 8], model_options={"shared": True})
    assert module.model.shared and list(module.model.kinetic) == ["shared"] and module.model.kinetic["shared"].film
    rebuilt = LNNModule(**module.hparams)
    rebuilt.load_state_dict(module.state_dict())  # same parameters, same names
    assert rebuilt.model.shared
    assert not LNNModule(hidden_dims=[8, 8]).model.shared  # off by default
