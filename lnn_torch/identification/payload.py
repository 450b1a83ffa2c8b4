"""A payload's inertial parameters from an arm's recordings by classical least squares: per
observation, the payload regressor of the robot-arm scene (``RobotArm.linear_regressor``: the joint
torques less the arm's own, linear in the payload's ten inertial parameters), solved linearly, and as
a point mass (four unknowns, Gauss-Newton from the linear estimate)."""

from __future__ import annotations

import numpy as np
import torch

from ..robots.mujoco_arm import MujocoArm
from ..systems import get_system


def payload_least_squares(q, qd, qdd, tau, edge: int = 0, system=None) -> dict:
    """Per observation, on the engine's payload regressor ``Y`` (``tau - tau_arm = Y pi``,
    ``RobotArm.linear_regressor``): the classical
    linear least squares of the ten inertial parameters (``m = pi_0``, ``c = pi_1:4 / m``), and the
    point-mass fit (the payloads are point masses: ``pi(m, c)``, four unknowns, Gauss-Newton from the
    linear estimate). ``q, qd, qdd, tau``: per observation ``(T, n)`` arrays (SI); ``edge``: points left
    out at each end (a smoothing's least reliable); ``system``: the robot-arm scene (default: the shipped
    arm). Returns ``{"linear": (mass (N,), com (N, 3)), "point mass": (mass, com)}`` in kg and m (flange
    frame)."""
    system = get_system("robot_arm") if system is None else system
    out = {"linear": ([], []), "point mass": ([], [])}
    for i in range(len(q)):
        sl = slice(edge, len(q[i]) - edge)  # the smoothing's ends are least reliable
        Y, b, _ = system.linear_regressor(q[i][sl], qd[i][sl], qdd[i][sl], tau[i][sl])  # the scene's classical form
        pi = torch.linalg.lstsq(Y, b[:, None]).solution[:, 0]
        out["linear"][0].append(float(pi[0]))
        out["linear"][1].append((pi[1:4] / pi[0]).numpy())
        theta = torch.cat([pi[:1], pi[1:4] / pi[0]])

        def residual(th, Y=Y, b=b):
            return Y @ MujocoArm.inertial_parameters(th) - b

        for _ in range(20):
            r = residual(theta)
            Jr = torch.func.jacrev(residual)(theta)
            step = torch.linalg.lstsq(Jr, -r[:, None]).solution[:, 0]
            theta = theta + step
            if step.abs().max() < 1e-12:
                break
        out["point mass"][0].append(float(theta[0]))
        out["point mass"][1].append(theta[1:4].numpy())
    return {k: (np.array(m), np.array(c)) for k, (m, c) in out.items()}
