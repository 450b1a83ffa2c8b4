"""The model registry: a variant name -> its class. Each class declares its own options and defaults
(its ``__init__`` signature); ``build_model`` passes the options given and refuses the ones a
variant does not take. Adding a variant: its own module plus one line in ``MODELS``."""

from __future__ import annotations

import inspect

from ..errors import InputError
from .base import DynamicsModel
from .blackbox import BlackBoxLagrangian
from .direct import DirectMLP
from .hamiltonian import HamiltonianNN
from .structured import DeLaN, FiLMLagrangian

MODELS: dict[str, type[DynamicsModel]] = {
    cls.variant: cls for cls in (FiLMLagrangian, BlackBoxLagrangian, DeLaN, DirectMLP, HamiltonianNN)
}
VARIANTS = tuple(MODELS)


def model_class(variant: str) -> type[DynamicsModel]:
    try:
        return MODELS[variant]
    except KeyError:
        raise InputError(f"unknown model variant '{variant}'; known: {', '.join(VARIANTS)}") from None


def model_options(variant: str) -> dict:
    """The options of a variant with their defaults: ``{name: default}`` (the scene excluded)."""
    params = list(inspect.signature(model_class(variant).__init__).parameters.values())[2:]  # self, scene
    return {p.name: p.default for p in params}


def unknown_options(variant: str, options: dict) -> list[str]:
    """The options given (not None) that ``variant`` does not take, sorted."""
    known = model_options(variant)
    return sorted(k for k, v in options.items() if v is not None and k not in known)


def build_model(variant: str, scene, **options) -> DynamicsModel:
    """Build a model variant for a scene (a ``System``, its ``describe()`` dict or a ``SceneInfo``;
    the canonical ``hnn`` needs a ``System`` for its momentum map).

    ``options``: the variant's own options (``model_options(variant)``); ``None`` means the
    variant's default. An option the variant does not take is an error, not silently ignored.
    """
    options = {k: v for k, v in options.items() if v is not None}
    unknown = unknown_options(variant, options)
    if unknown:
        raise InputError(f"model variant '{variant}' takes no option {', '.join(map(repr, unknown))}; "
                         f"its options: {', '.join(model_options(variant))}")
    if "hidden_dims" in options:
        options["hidden_dims"] = tuple(options["hidden_dims"])
    return model_class(variant)(scene, **options)
