"""Ground-truth scenes with closed-form Lagrangians, and the registry that builds them by name."""

from __future__ import annotations

from ..errors import InputError
from .actuated_double_pendulum import ActuatedDoublePendulum
from .base import GRAVITY, Range, System
from .chain_pendulum import ChainPendulum
from .double_pendulum import DoublePendulum
from .ground_truth import ClosedForm, reference_rollout
from .mass_spring import MassSpring
from .measured import MeasuredSystem
from .pendulum import Pendulum
from .relativistic_particle import RelativisticParticle
from .robot_arm import RobotArm

SYSTEMS: dict[str, type[System]] = {
    cls.name: cls for cls in (DoublePendulum, Pendulum, MassSpring, ChainPendulum, RelativisticParticle,
                              ActuatedDoublePendulum, RobotArm, MeasuredSystem)
}


def register_system(cls: type[System], replace: bool = False) -> type[System]:
    """Add a scene of your own (a ``System`` subclass with its ``name``) to ``SYSTEMS``, so that datasets,
    models and checkpoints name it like a shipped one (``docs/own_scene.md``); run it in every process before
    such a file or checkpoint is read. A shipped scene's name is refused unless ``replace``. Returns ``cls``
    (usable as a class decorator)."""
    if not (isinstance(cls, type) and issubclass(cls, System)) or not isinstance(getattr(cls, "name", None), str):
        raise InputError(f"register_system: {cls!r} is not a System subclass with a name")
    if cls.name in SYSTEMS and SYSTEMS[cls.name] is not cls and not replace:
        raise InputError(f"register_system: scene '{cls.name}' exists already ({SYSTEMS[cls.name].__name__}); "
                         "choose another name, or pass replace=True")
    SYSTEMS[cls.name] = cls
    return cls


def get_system(name: str, **config) -> System:
    """Build a scene by name with its sampler configuration (``config`` as in ``System.config()``)."""
    try:
        cls = SYSTEMS[name]
    except KeyError:
        raise InputError(f"unknown scene '{name}'; known scenes: {', '.join(sorted(SYSTEMS))}") from None
    if name == "measured" and "dof" not in config:  # (its coordinates are a recording's: none to generate)
        raise InputError("scene 'measured' is a recorded system: its data come from lnn-torch import (recordings), "
                         "not from a simulation")
    try:
        return cls(**config)
    except TypeError as err:
        raise InputError(f"scene '{name}': bad configuration ({err})") from None


__all__ = ["GRAVITY", "InputError", "Range", "System", "SYSTEMS", "get_system", "register_system",
           "DoublePendulum", "Pendulum", "MassSpring", "ChainPendulum", "RelativisticParticle",
           "ActuatedDoublePendulum", "RobotArm", "MeasuredSystem", "ClosedForm", "reference_rollout"]
