"""Generalised forces: joint inputs (motor torques) and joint friction, as pure tensor functions.

A scene (or a model) with forces obeys ``M qdd = dL/dq - (d2L/dqd dq) qd + Q`` with

    Q = B tau + Q_diss,    Q_diss = -D^T f(D qd),    f_j(r) = b_j r + c_j tanh(r / v)

* ``B`` (dof, n_u): the input matrix, constant (joint torques enter the joint coordinates);
* ``D`` (n_j, dof): the joint map, joint rates ``r = D qd`` (identity for joint coordinates; for
  the double pendulum's absolute angles the second joint turns at ``qd2 - qd1``);
* ``f``: viscous ``b >= 0`` and smooth Coulomb ``c >= 0`` friction per joint, smoothed over the
  velocity ``v`` (a Rayleigh-type dissipation: the power ``qd . Q_diss = -r . f(r) <= 0``, it never
  injects energy).

Power balance: ``dE/dt = qd . B tau + qd . Q_diss``. Shapes ``(*batch, dof)``, SI units.
"""

from __future__ import annotations

import torch


def joint_friction(rates: torch.Tensor, viscous: torch.Tensor, coulomb: torch.Tensor,
                   coulomb_velocity: float) -> torch.Tensor:
    """Friction torque per joint ``b r + c tanh(r / v)``: ``rates (*batch, n_j)``, coefficients
    broadcasting to it (N m s/rad and N m), ``v`` in rad/s. Returns ``(*batch, n_j)`` in N m."""
    return viscous * rates + coulomb * torch.tanh(rates / coulomb_velocity)


def dissipative_force(qd: torch.Tensor, joint_map: torch.Tensor | None, friction_fn) -> torch.Tensor:
    """``Q_diss = -D^T f(D qd)`` for ``friction_fn(rates) -> (*batch, n_j)``: ``(*batch, dof)``
    (``joint_map`` None: the identity, joint coordinates)."""
    if joint_map is None:
        return -friction_fn(qd)
    D = joint_map.to(qd.dtype)
    return -friction_fn(qd @ D.mT) @ D


def input_force(tau: torch.Tensor, input_matrix: torch.Tensor | None) -> torch.Tensor:
    """``B tau``: ``tau (*batch, n_u)`` -> ``(*batch, dof)`` (``input_matrix`` None: the identity)."""
    return tau if input_matrix is None else tau @ input_matrix.to(tau.dtype).mT


def identity_or_none(matrix: torch.Tensor | None) -> torch.Tensor | None:
    """None for an identity matrix (the cheap path of ``dissipative_force``/``input_force``), else the matrix."""
    if matrix is not None and matrix.shape[0] == matrix.shape[1] and torch.equal(matrix, torch.eye(matrix.shape[0], dtype=matrix.dtype)):
        return None
    return matrix


def power(qd: torch.Tensor, force: torch.Tensor) -> torch.Tensor:
    """The power ``qd . Q`` of a generalised force, ``(*batch,)`` in W."""
    return (qd * force).sum(-1)


def check_inputs(tau, num_inputs: int, batch_shape, name: str = "tau") -> None:
    """Raise ``InputError`` for inputs given to an unactuated system, missing for an actuated one, or
    of the wrong shape (``batch_shape + (num_inputs,)``)."""
    from .systems.base import InputError

    if num_inputs == 0:
        if tau is not None:
            raise InputError(f"{name} given, but the system has no inputs (it is not actuated)")
        return
    if tau is None:
        raise InputError(f"the system is actuated ({num_inputs} inputs): {name} of shape "
                         f"{(*batch_shape, num_inputs)} is missing (pass zeros for free motion)")
    if tuple(tau.shape) != (*batch_shape, num_inputs):
        raise InputError(f"{name} must have shape {(*batch_shape, num_inputs)}, got {tuple(tau.shape)}")
