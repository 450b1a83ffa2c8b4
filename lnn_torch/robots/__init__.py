"""Robot descriptions shipped with the package (each with its licence) and their dynamics through an
established rigid-body engine (MuJoCo, ``lnn_torch.robots.mujoco_arm``; the optional dependency
``pip install 'lnn-torch[robots]'``)."""

from .description import ArmDescription
from .mujoco_arm import MujocoArm
from .shipped import DESCRIPTIONS, HERE, LIMITS, description_path

__all__ = ["ArmDescription", "DESCRIPTIONS", "HERE", "LIMITS", "description_path", "MujocoArm"]
