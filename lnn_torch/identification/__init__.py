"""Identification, side by side: a learned model's physical parameters (``learned``: ``identify``),
and every classical fit -- least squares on a spatial arm's base parameters, ordinary, weighted and
physically consistent (``classical_arm``), a payload's inertial parameters (``payload``), the two-link
arm's model (``two_link``), a torque
controller's velocity feedback (``velocity_feedback``) -- and the report that sets a learned arm
beside them (``arm_comparison``).

Imported on first use (the learned model's objectives need the training losses)."""

from importlib import import_module

_LAZY = {"identify": ".learned", "identify_batch": ".learned", "Identification": ".learned",
         "least_squares_reference": ".learned", "ArmModel": ".classical_arm", "least_squares": ".classical_arm",
         "consistent_fit": ".classical_arm", "RigidArmModel": ".two_link", "VelocityFeedback": ".velocity_feedback",
         "fit_classical": ".arm_comparison", "compare_on_arm": ".arm_comparison",
         "base_least_squares": ".classical_arm", "payload_least_squares": ".payload",
         "NOISY": ".learned", "BASE": ".two_link", "base_regressor": ".two_link",
         "classical_torque": ".arm_comparison", "description_model": ".arm_comparison",
         "feedback_band": ".arm_comparison", "feedback_rows": ".arm_comparison", "model_torque": ".arm_comparison"}


def __getattr__(name):
    if name in _LAZY:
        return getattr(import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = sorted(_LAZY)
