"""Using a learned model: the plant view (``plant``), controllers (``controllers``) and closed-loop
simulation on a true plant (``closed_loop``)."""

from .closed_loop import closed_loop
from .controllers import LQR, MPPI, ComputedTorque, SwingUp, equilibrium_input, lqr_gain, min_jerk, wrap
from .plant import Plant, calibrate_on, calibrate_torque_scale, plant_of

__all__ = ["Plant", "plant_of", "calibrate_torque_scale", "calibrate_on", "LQR", "MPPI", "ComputedTorque", "SwingUp",
           "min_jerk", "lqr_gain", "equilibrium_input", "wrap", "closed_loop"]
