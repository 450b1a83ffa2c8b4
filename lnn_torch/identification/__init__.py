"""Identification, side by side: a learned model's physical parameters (``learned``: ``identify``),
and every classical fit -- least squares on a spatial arm's base parameters with their uncertainty,
ordinary, weighted and physically consistent (``classical_arm``), a payload's inertial parameters
(``payload``), the two-link arm's model (``two_link``), a torque controller's velocity feedback
(``velocity_feedback``) -- the report that sets a learned arm beside them (``arm_comparison``), and an arm
grey box started from the consistent fit (``classical_start``)."""

from .arm_comparison import (
    classical_torque,
    compare_on_arm,
    description_model,
    feedback_band,
    feedback_rows,
    fit_classical,
    model_torque,
    torque_errors,
    uncertainty_markdown,
)
from .classical_arm import ArmModel, base_least_squares, consistent_fit, excitation, least_squares
from .classical_start import start_from_classical
from .learned import Identification, identify, identify_batch, least_squares_reference
from .payload import payload_least_squares
from .two_link import BASE, RigidArmModel, base_regressor
from .velocity_feedback import VelocityFeedback

__all__ = ["identify", "identify_batch", "Identification", "least_squares_reference", "ArmModel", "least_squares",
           "consistent_fit", "excitation", "base_least_squares", "payload_least_squares", "RigidArmModel", "BASE",
           "base_regressor", "VelocityFeedback", "fit_classical", "compare_on_arm", "classical_torque",
           "description_model", "feedback_band", "feedback_rows", "model_torque", "torque_errors",
           "uncertainty_markdown", "start_from_classical"]
