"""Fixed-step integrators for second-order systems ``qdd = accel_fn(q, qd, params)``.

One entry point, ``rollout``, picks a method by name from ``METHODS``. Each method is a step
function ``step(accel_fn, q, qd, params, dt) -> (q, qd)`` with an ``order`` attribute.

* ``rk4``: classical Runge-Kutta, order 4.
* ``rk8``: the 12-stage, 8th-order Dormand-Prince tableau (the one DOP853 uses) as a fixed step;
  used to generate ground truth.
* ``semi_implicit_euler``: kick then drift (symplectic Euler for velocity-independent forces), order 1.
* ``leapfrog``: kick-drift-kick (velocity Verlet) with the velocity in the second kick taken from an
  explicit half-step estimate; symplectic and order 2 for velocity-independent forces.

Pure tensor functions; shapes ``(*batch, dof)``.
"""

from __future__ import annotations

from typing import Callable

import torch

AccelFn = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


def rk4_step(accel_fn: AccelFn, q, qd, params, dt):
    k1q, k1v = qd, accel_fn(q, qd, params)
    k2q, k2v = qd + 0.5 * dt * k1v, accel_fn(q + 0.5 * dt * k1q, qd + 0.5 * dt * k1v, params)
    k3q, k3v = qd + 0.5 * dt * k2v, accel_fn(q + 0.5 * dt * k2q, qd + 0.5 * dt * k2v, params)
    k4q, k4v = qd + dt * k3v, accel_fn(q + dt * k3q, qd + dt * k3v, params)
    q_new = q + dt / 6 * (k1q + 2 * k2q + 2 * k3q + k4q)
    qd_new = qd + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
    return q_new, qd_new


rk4_step.order = 4


def _dop853_tableau():
    # The coefficients are read from scipy's DOP853 implementation (not re-typed here).
    from scipy.integrate._ivp import dop853_coefficients as dc

    s = dc.N_STAGES
    return dc.A[:s, :s].tolist(), dc.B.tolist(), dc.C[:s].tolist()


_RK8: dict = {}


def _rk8_coefficients(dtype, device):
    key = (dtype, device)
    if key not in _RK8:
        A, B, _ = _dop853_tableau()
        _RK8[key] = (
            [torch.tensor(row[:i], dtype=dtype, device=device) for i, row in enumerate(A)],
            torch.tensor(B, dtype=dtype, device=device),
        )
    return _RK8[key]


def rk8_step(accel_fn: AccelFn, q, qd, params, dt):
    A, B = _rk8_coefficients(q.dtype, q.device)
    dof = q.shape[-1]
    y = torch.cat([q, qd], dim=-1)  # (*batch, 2 dof)
    ks = []
    for i, a in enumerate(A):
        if i == 0:
            yi = y
        else:
            # (i,) x (i, *batch, 2 dof) -> (*batch, 2 dof)
            yi = y + dt * torch.tensordot(a, torch.stack(ks), dims=1)
        qi, vi = yi[..., :dof], yi[..., dof:]
        ks.append(torch.cat([vi, accel_fn(qi, vi, params)], dim=-1))
    y_new = y + dt * torch.tensordot(B, torch.stack(ks), dims=1)
    return y_new[..., :dof], y_new[..., dof:]


rk8_step.order = 8


def semi_implicit_euler_step(accel_fn: AccelFn, q, qd, params, dt):
    qd_new = qd + dt * accel_fn(q, qd, params)
    return q + dt * qd_new, qd_new


semi_implicit_euler_step.order = 1


def leapfrog_step(accel_fn: AccelFn, q, qd, params, dt):
    a0 = accel_fn(q, qd, params)
    qd_half = qd + 0.5 * dt * a0
    q_new = q + dt * qd_half
    # second kick: the acceleration is evaluated at an explicit estimate of the end velocity
    qd_guess = qd_half + 0.5 * dt * a0
    qd_new = qd_half + 0.5 * dt * accel_fn(q_new, qd_guess, params)
    return q_new, qd_new


leapfrog_step.order = 2

METHODS = {
    "rk4": rk4_step,
    "rk8": rk8_step,
    "semi_implicit_euler": semi_implicit_euler_step,
    "leapfrog": leapfrog_step,
}


def rollout(
    accel_fn: AccelFn,
    q0: torch.Tensor,
    qd0: torch.Tensor,
    params: torch.Tensor,
    dt: float,
    num_steps: int,
    method: str = "rk4",
    substeps: int = 1,
    callback: Callable[[int], None] | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Integrate a batch of trajectories with a fixed step.

    Args:
        accel_fn: ``(q, qd, params) -> qdd`` on ``(B, dof)``, ``(B, dof)``, ``(B, P)``, SI units.
        q0, qd0: initial state ``(B, dof)``; params: ``(B, P)``.
        dt: output interval in s; each output step takes ``substeps`` integrator steps of ``dt/substeps``.
        num_steps: number of output steps.
        method: a key of ``METHODS``.
        callback: called with the output step index after each step (progress bars).

    Returns:
        ``(q, qd)`` each of shape ``(B, num_steps + 1, dof)``, starting with the initial state.
    """
    try:
        step = METHODS[method]
    except KeyError:
        raise ValueError(f"unknown integrator '{method}'; known: {', '.join(METHODS)}") from None
    if q0.shape != qd0.shape or q0.ndim != 2:
        raise ValueError(f"q0 and qd0 must both be (batch, dof), got {tuple(q0.shape)} and {tuple(qd0.shape)}")
    if params.ndim != 2 or params.shape[0] != q0.shape[0]:
        raise ValueError(f"params must be (batch, num_params) with batch {q0.shape[0]}, got {tuple(params.shape)}")
    if not dt > 0 or num_steps < 0 or substeps < 1:
        raise ValueError(f"need dt > 0, num_steps >= 0, substeps >= 1; got {dt}, {num_steps}, {substeps}")
    h = dt / substeps
    qs, qds = [q0], [qd0]
    q, qd = q0, qd0
    for i in range(num_steps):
        for _ in range(substeps):
            q, qd = step(accel_fn, q, qd, params, h)
        qs.append(q)
        qds.append(qd)
        if callback is not None:
            callback(i)
    return torch.stack(qs, dim=1), torch.stack(qds, dim=1)
