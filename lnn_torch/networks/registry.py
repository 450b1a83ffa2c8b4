"""The model registry: a variant name -> its class. Each class declares its own options and defaults
(its ``__init__`` signature); ``build_model`` passes the options given and refuses the ones a
variant does not take. Adding a variant: its own module plus one line in ``MODELS``."""

from __future__ import annotations

import inspect

from ..errors import InputError
from .base import DynamicsModel
from .blackbox import BlackBoxLagrangian
from .capabilities import ENERGY, INVERSE_DYNAMICS
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
        dims = options["hidden_dims"]
        dims = [dims] if isinstance(dims, int) and not isinstance(dims, bool) else dims
        if not isinstance(dims, (list, tuple)) or not dims or any(
                isinstance(h, bool) or not isinstance(h, int) or h < 1 for h in dims):
            raise InputError(f"hidden_dims must be one or more positive widths, e.g. [64, 64], got {dims!r}")
        options["hidden_dims"] = tuple(dims)
    return model_class(variant)(scene, **options)


def refuse_conflicts(variant: str, system, options: dict, energy_weight: float = 0.0,
                     torque_weight: float = 0.0, acceleration_weight: float = 1.0) -> None:
    """Every option and loss term that ``variant`` cannot use on ``system``, in ONE ``InputError`` (a user
    switching variants sees the whole list at once, not one refusal per attempt)."""
    cls = model_class(variant)
    problems = [f"option {k!r} (not an option of {variant})" for k in unknown_options(variant, options)]
    if torque_weight > 0 and INVERSE_DYNAMICS not in cls.provides:
        problems.append(f"torque_weight {torque_weight:g} (needs inverse dynamics: film_lnn or delan)")
    elif torque_weight > 0 and not system.num_inputs:
        problems.append(f"torque_weight {torque_weight:g} (fits measured torques, and scene '{system.name}' has no "
                        "inputs: import the recordings' torques (efforts), or set torque_weight 0)")
    if energy_weight > 0 and ENERGY not in cls.provides:
        problems.append(f"energy_weight {energy_weight:g} (variant {variant} has no energy of its own)")
    if acceleration_weight < 0 or (acceleration_weight == 0 and not torque_weight > 0):
        problems.append(f"acceleration_weight {acceleration_weight:g} (>= 0, and 0 only with a torque_weight: "
                        "else nothing is fitted)")
    if (energy_weight > 0 or torque_weight > 0) and options.get("dissipation") == "joint+stiction":
        problems.append("energy_weight/torque_weight with dissipation 'joint+stiction' (static friction's holding "
                        "torque is not a force of the state)")
    if problems:
        listing = f". Its options: {', '.join(model_options(variant))}" if unknown_options(variant, options) else ""
        raise InputError(f"variant '{variant}' cannot use: {'; '.join(problems)}{listing}")
