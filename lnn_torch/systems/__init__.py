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


def get_system(name: str, **config) -> System:
    """Build a scene by name with its sampler configuration (``config`` as in ``System.config()``)."""
    try:
        cls = SYSTEMS[name]
    except KeyError:
        raise InputError(f"unknown scene '{name}'; known scenes: {', '.join(sorted(SYSTEMS))}") from None
    try:
        return cls(**config)
    except TypeError as err:
        raise InputError(f"scene '{name}': bad configuration ({err})") from None


__all__ = ["GRAVITY", "InputError", "Range", "System", "SYSTEMS", "get_system",
           "DoublePendulum", "Pendulum", "MassSpring", "ChainPendulum", "RelativisticParticle",
           "ActuatedDoublePendulum", "RobotArm", "MeasuredSystem", "ClosedForm", "reference_rollout"]
