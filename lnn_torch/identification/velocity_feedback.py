"""A torque-controlled robot's feedback on its own measured velocity, in its measured torques.

A model of the dynamics reads velocities and accelerations smoothed to a band (the targets' low-pass,
``lnn_torch.data.derivatives``): the measured torque's part above that band is error for every model of
the smoothed state. On a robot whose joints run a torque or impedance controller, much of that part is
the controller answering the velocity it measures: it applies ``-D (v_recorded - v_smoothed)`` on top
of what the motion needs, the joint's torque sensor measures it, and the motion it causes is too small
to show in the angles (at 20-60 Hz a torque of 0.2 N m moves a 1 kg m^2 link by microradians). No
model of the state can predict it; the recorded velocity's band above the targets' does, with one gain
per joint.

``band`` is that part of the recorded velocity (``arm_identification.feedback_band`` reads it from a
dataset split); ``fit`` finds the gains ``D`` per joint by least squares
on a model's torque error over training points and keeps a joint's gain only where it lowers the error
on validation points (a gain that does not pay is zero: the correction never hurts on validation);
``VelocityFeedback.torque`` is the correction to add to the model's inverse dynamics. Everything is
per point (N, dof), SI: rad/s, N m, N m s/rad.

On the real Panda (``scripts/real_panda_floor.py``, ``results/real_panda/floor.md``) the gains come out
at 22-31 N m s/rad on joints 1-4 and 5-7 on joints 5-6 (22-41 and 5-7 fitted on each window alone),
the order of the damping of the robot's joint impedance controller; the angles' own derivatives above
the band predict almost none of it.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..errors import InputError


def _check(name: str, x: torch.Tensor, like: torch.Tensor | None = None) -> torch.Tensor:
    x = torch.as_tensor(x, dtype=torch.float64)
    if x.ndim != 2:
        raise InputError(f"{name} must be (points, joints), got shape {tuple(x.shape)}")
    if like is not None and x.shape != like.shape:
        raise InputError(f"{name} has shape {tuple(x.shape)}, expected {tuple(like.shape)}")
    if x.shape[0] == 0:
        raise InputError(f"{name} has no points")
    if not torch.isfinite(x).all():
        raise InputError(f"{name} holds NaN or infinite values")
    return x


def band(recorded: torch.Tensor, smoothed: torch.Tensor) -> torch.Tensor:
    """The recorded velocity's part above the targets' band: ``recorded - smoothed`` ``(N, dof)``, rad/s
    (``TrajectoryDataModule.recorded_velocities`` and ``trajectories(...).qd``, flattened alike)."""
    recorded = _check("recorded velocities", recorded)
    return recorded - _check("smoothed velocities", smoothed, recorded)


@dataclass
class VelocityFeedback:
    """Per joint: the feedback gain ``gains`` (N m s/rad; zero where validation dropped it), whether it
    was ``kept``, and the RMS torque error (N m) on the validation points without and with it."""

    gains: torch.Tensor
    kept: list[bool]
    val_rms_before: list[float]
    val_rms_after: list[float]

    def torque(self, band_: torch.Tensor) -> torch.Tensor:
        """The measured torque's feedback part ``-D band`` ``(N, dof)``, N m: add it to a model's torque."""
        band_ = _check("velocity band", band_)
        if band_.shape[-1] != len(self.gains):
            raise InputError(f"velocity band has {band_.shape[-1]} joints, the feedback {len(self.gains)}")
        return -band_ * self.gains

    def report(self) -> dict:
        return {"gains": self.gains.tolist(), "kept": list(self.kept), "val_rms_before": self.val_rms_before,
                "val_rms_after": self.val_rms_after}


def least_squares(error: torch.Tensor, band_: torch.Tensor) -> torch.Tensor:
    """The least-squares gains ``D (dof,)`` of ``error ≈ -D band`` per joint over the points (zero where the
    band is zero), no validation: ``fit`` is the one that keeps only what pays."""
    power = band_.pow(2).sum(0)
    return torch.where(power > 0, -(band_ * error).sum(0) / power.clamp_min(1e-300), 0.0)


def fit(error_train: torch.Tensor, band_train: torch.Tensor, error_val: torch.Tensor,
        band_val: torch.Tensor) -> VelocityFeedback:
    """The gains of ``error ≈ -D band`` per joint, by least squares on the training points, each kept
    only where it lowers the validation RMS. ``error``: measured torque minus the model's ``(N, dof)``;
    ``band``: ``band(...)`` at the same points."""
    error_train = _check("training torque error", error_train)
    band_train = _check("training velocity band", band_train, error_train)
    error_val = _check("validation torque error", error_val)
    band_val = _check("validation velocity band", band_val, error_val)
    if error_val.shape[1] != error_train.shape[1]:
        raise InputError(f"validation has {error_val.shape[1]} joints, training {error_train.shape[1]}")
    gains = least_squares(error_train, band_train)
    before = error_val.pow(2).mean(0).sqrt()
    after = (error_val + band_val * gains).pow(2).mean(0).sqrt()
    kept = after < before
    gains = torch.where(kept, gains, 0.0)
    return VelocityFeedback(gains, kept.tolist(), before.tolist(), torch.where(kept, after, before).tolist())

