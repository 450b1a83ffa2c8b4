"""Angle helpers: angles reduced to one turn, coordinate differences with their angles wrapped."""

from __future__ import annotations

import math

import torch


def wrap_angle(q: torch.Tensor) -> torch.Tensor:
    """Angles ``q`` reduced to [-pi, pi), same dtype. The reduction runs in float64 where the device has
    it: in float32, ``remainder(q + pi, 2 pi)`` loses up to 3e-4 rad at |q| = 1e4 (q + pi is rounded to
    the float32 grid there), while float64 keeps the reduced angle exact to ~1e-12."""
    wide = torch.float64 if q.device.type in ("cpu", "cuda") else q.dtype
    return (torch.remainder(q.to(wide) + math.pi, 2 * math.pi) - math.pi).to(q.dtype)


def wrap_angles(dq: torch.Tensor, angle_mask) -> torch.Tensor:
    """Coordinate differences ``(..., dof)`` with the angle ones (``angle_mask``) wrapped to [-pi, pi)
    (``wrap_angle``)."""
    mask = torch.as_tensor(angle_mask, dtype=torch.bool, device=dq.device)
    return torch.where(mask, wrap_angle(dq), dq)
