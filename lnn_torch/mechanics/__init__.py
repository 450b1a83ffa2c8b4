"""Mechanics as pure tensor functions (torch only): fixed-step and adaptive integrators
(``integrators``), the Euler-Lagrange solves (``euler_lagrange``), generalised forces (``forces``),
the one joint friction / drive law (``friction``) and angle helpers (``angles``)."""

from .angles import wrap_angle, wrap_angles
from .euler_lagrange import generic_acceleration, spd_solve, structured_acceleration
from .forces import dissipative_force, input_force, power
from .friction import DriveModel, friction_torque
from .integrators import rollout, rollout_adaptive, rollout_first_order

__all__ = ["rollout", "rollout_first_order", "rollout_adaptive", "generic_acceleration", "structured_acceleration",
           "spd_solve", "input_force", "dissipative_force", "power", "DriveModel", "friction_torque", "wrap_angle",
           "wrap_angles"]
