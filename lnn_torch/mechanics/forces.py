"""Generalised forces: joint inputs (motor torques) and joint friction, as pure tensor functions.

A scene (or a model) with forces obeys ``M qdd = dL/dq - (d2L/dqd dq) qd + Q`` with

    Q = B tau + Q_diss,    Q_diss = -D^T f(D qd),    f_j(r) = b_j r + c_j tanh(r / v)

(the friction law ``f`` is ``lnn_torch.mechanics.friction.friction_torque``)

* ``B`` (dof, n_u): the input matrix, constant (joint torques enter the joint coordinates);
* ``D`` (n_j, dof): the joint map, joint rates ``r = D qd`` (identity for joint coordinates; for
  the double pendulum's absolute angles the second joint turns at ``qd2 - qd1``);
* ``f``: viscous ``b >= 0`` and smooth Coulomb ``c >= 0`` friction per joint, smoothed over the
  velocity ``v`` (a Rayleigh-type dissipation: the power ``qd . Q_diss = -r . f(r) <= 0``, it never
  injects energy).

Power balance: ``dE/dt = qd . B tau + qd . Q_diss``. Shapes ``(*batch, dof)``, SI units.

Static friction (stiction, a Karnopp-type model): a joint turning slower than the stick velocity
``v_s`` is held by whatever torque keeps it at rest, up to its static level ``s`` (the learned models
take the Coulomb level ``c``), and its kinetic friction fades in that window. With
``w_j = exp(-(r_j / v_s)^2)`` the holding torques ``lam`` solve, by projected Gauss-Seidel sweeps (a
fixed number, differentiable),

    lam_j = w_j s_j sat((lam_j - rho_j / A_jj) / s_j),    rho = rho_0 + A lam,

with ``rho_0`` the joint accelerations without them, ``A = D M^-1 D^T`` the joints' response to a
unit joint torque and ``sat`` a smooth clip (``soft_clip``): a joint at rest whose other torques stay below
``s`` keeps still (``rho_j = 0``); beyond, it slips with ``s`` opposing. The holding torque opposes
the tendency to move, not the velocity: its power ``-r . lam`` is bounded by ``sum_j s_j v_s |x|
exp(-x^2) <= 0.43 sum_j s_j v_s`` (``x = r_j / v_s``), not signed.
"""

from __future__ import annotations

import torch

from ..errors import InputError


def stick_weight(rates: torch.Tensor, stick_velocity: float) -> torch.Tensor:
    """The weight ``w = exp(-(r / v_s)^2)`` of the stuck state of each joint, ``(*batch, n_j)``."""
    return torch.exp(-(rates / stick_velocity).square())


def holding_torque(rho0: torch.Tensor, response: torch.Tensor, weight: torch.Tensor, static: torch.Tensor,
                   sweeps: int = 8) -> torch.Tensor:
    """The static-friction torques ``lam (B, n_j)`` that hold the joints at rest up to their static
    levels (module docstring): ``rho0 (B, n_j)`` the joint accelerations without them, ``response
    (B, n_j, n_j)`` the joint accelerations per unit joint torque (``D M^-1 D^T``, positive definite),
    ``weight (B, n_j)`` the stuck weights, ``static`` the levels ``s >= 0`` (broadcasting to
    ``(B, n_j)``, N m). The sweeps start from the exact holds of all joints together, ``-A^-1 rho0``
    (weighted and clipped): an arm held below its levels is held from the start, however strongly its
    joints couple; ``sweeps`` projected Gauss-Seidel sweeps then settle the joints that slip."""
    static = static.expand_as(rho0).clamp_min(1e-12)
    diag = torch.diagonal(response, dim1=-2, dim2=-1)
    start = weight * static * soft_clip(-torch.linalg.solve(response, rho0[..., None])[..., 0] / static)
    lam = list(start.unbind(-1))
    for _ in range(sweeps):
        for j in range(rho0.shape[-1]):
            rho_j = rho0[..., j] + sum(response[..., j, k] * lam[k] for k in range(len(lam)))
            x = (lam[j] - rho_j / diag[..., j]) / static[..., j]
            lam[j] = weight[..., j] * static[..., j] * soft_clip(x)
    return torch.stack(lam, -1)


def soft_clip(x: torch.Tensor) -> torch.Tensor:
    """A smooth clip to [-1, 1] that is nearly the identity inside: ``x / (1 + x^8)^(1/8)`` (0.5 -> 0.4998,
    1 -> 0.917); ``x`` is clamped to [-10, 10] first (the power stays finite in float32)."""
    x = x.clamp(-10.0, 10.0)
    return x * (1 + x.pow(8)).pow(-0.125)


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
    if matrix is not None and matrix.shape[0] == matrix.shape[1] and torch.equal(
            matrix, torch.eye(matrix.shape[0], dtype=matrix.dtype)):
        return None
    return matrix


def power(qd: torch.Tensor, force: torch.Tensor) -> torch.Tensor:
    """The power ``qd . Q`` of a generalised force, ``(*batch,)`` in W."""
    return (qd * force).sum(-1)


def check_inputs(tau, num_inputs: int, batch_shape, name: str = "tau") -> None:
    """Raise ``InputError`` for inputs given to an unactuated system, missing for an actuated one, or
    of the wrong shape (``batch_shape + (num_inputs,)``)."""
    if num_inputs == 0:
        if tau is not None:
            raise InputError(f"{name} given, but the system has no inputs (it is not actuated)")
        return
    if tau is None:
        raise InputError(f"the system is actuated ({num_inputs} inputs): {name} of shape "
                         f"{(*batch_shape, num_inputs)} is missing (pass zeros for free motion)")
    if tuple(tau.shape) != (*batch_shape, num_inputs):
        raise InputError(f"{name} must have shape {(*batch_shape, num_inputs)}, got {tuple(tau.shape)}")
