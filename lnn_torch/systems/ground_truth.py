"""The exact reference of a scene's dynamics: float64 ground-truth integration, used by the dataset
generator and by every evaluation that compares a model with the truth (one implementation).

A fast fixed-step pass (8th-order Runge-Kutta by default) for all trajectories, then adaptive DOP853
steps for those whose accuracy check fails (stiff or fast ones). The check is energy conservation
for a conservative scene and POWER BALANCE for a scene with inputs or friction: the work of the
generalised forces is integrated with the state (``y = (q, qd, W_in, W_diss)``, ``dW_in/dt =
qd . B tau``, ``dW_diss/dt = qd . Q_diss``) and ``E(t) - E(0) - W_in(t) - W_diss(t)`` must stay within
the tolerance times the scene's energy scale. Inputs are held over each sample interval.
"""

from __future__ import annotations

import numpy as np
import torch

from ..errors import GenerationError
from ..mechanics.forces import check_inputs, input_force, power
from ..mechanics.integrators import rollout, rollout_adaptive, rollout_first_order


def power_balance_residual(system, q, qd, params, work) -> torch.Tensor:
    """``|E(t) - E(0) - W(t)| / energy scale`` with ``W (N, T)`` the work of the generalised forces
    since ``t = 0``: ``(N, T)`` (the energy drift when ``W = 0``)."""
    E = system.energy(q, qd, params[:, None, :].expand(-1, q.shape[1], -1))
    return relative_residual(E, work, system.energy_scale(params))


def relative_residual(energy: torch.Tensor, work: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """``|E(t) - E(0) - W(t)| / scale`` from the energies ``(N, T)`` and the work ``(N, T)`` since
    ``t = 0`` (J) and the energy scales ``(N,)`` (J): ``(N, T)``."""
    return (energy - energy[:, :1] - work).abs() / scale[:, None]


def _augmented_field(system):
    """``y = (q, qd, W_in, W_diss) -> (qd, qdd, qd . B tau, qd . Q_diss)`` of a scene with forces."""
    dof = system.dof

    def field(y, params, tau=None):
        q, qd = y[:, :dof], y[:, dof:2 * dof]
        q_diss = system.dissipative_force(q, qd, params)
        if tau is None:
            q_in, q_all = torch.zeros_like(q_diss), q_diss
        else:
            q_in = input_force(tau, system._force_maps()[0])
            q_all = q_in + q_diss
        return torch.cat([qd, system.forced_acceleration(q, qd, params, q_all), power(qd, q_in)[:, None],
                          power(qd, q_diss)[:, None]], -1)

    return field


def integrate_ground_truth(system, q0, qd0, params, dt: float, num_steps: int, integrator: str = "rk8",
                           substeps: int = 1, energy_tol: float = 1e-10, adaptive_tol: float = 1e-11,
                           callback=None, indices=None, tau=None, return_work: bool = False):
    """Ground truth in float64: a fast fixed-step pass for all trajectories, then adaptive DOP853
    steps for those whose relative energy drift (or, with forces, power-balance residual) exceeds
    ``energy_tol`` (stiff or fast ones), at ``adaptive_tol``, then ten and a hundred times tighter for
    those that still exceed it.

    ``tau``: inputs ``(N, num_steps, n_u)`` of an actuated scene, held over each interval.

    Returns ``q, qd`` ``(N, num_steps + 1, dof)`` and the integrator steps each trajectory took
    ``(N,)`` (and, with ``return_work``, the work ``(N, num_steps + 1, 2)`` of the inputs and of
    dissipation since t = 0). Raises ``GenerationError`` naming the trajectories (``indices``,
    default 0..N-1) that still fail the check after the tightest adaptive pass.
    """
    check_inputs(tau, system.num_inputs, (len(params), num_steps))
    dof = system.dof
    if system.has_forces:
        field = _augmented_field(system)
        zeros = torch.zeros(len(params), 2, dtype=q0.dtype, device=q0.device)
        y0 = torch.cat([q0, qd0, zeros], -1)
        y = rollout_first_order(field, y0, params, dt, num_steps, integrator, substeps, tau, callback)
    else:
        q, qd = rollout(system.acceleration, q0, qd0, params, dt, num_steps, integrator, substeps, callback=callback)
        y = torch.cat([q, qd, torch.zeros(*q.shape[:2], 2, dtype=q.dtype, device=q.device)], -1)

    def residual(rows):
        yr = y[rows]
        return power_balance_residual(system, yr[..., :dof], yr[..., dof:2 * dof], params[rows],
                                      yr[..., 2 * dof:].sum(-1)).amax(1)

    steps = torch.full((len(params),), num_steps * substeps, dtype=torch.long)
    every = torch.arange(len(params))
    check = residual(every)
    todo = torch.nonzero(~(check <= energy_tol))[:, 0]  # NaN counts as not converged
    # trajectories that fail the check go to adaptive steps; those that still fail are integrated
    # again with a tolerance ten, then a hundred times tighter (a borderline trajectory among thousands
    # should not fail a whole dataset) before the error
    tolerances = (adaptive_tol, adaptive_tol / 10, adaptive_tol / 100)
    for tol in tolerances:
        if not todo.numel():
            break
        y[todo], taken = _adaptive(system, q0[todo], qd0[todo], params[todo], dt, num_steps, tol,
                                   None if tau is None else tau[todo])
        steps[todo] += taken  # every step taken, the passes before included (a refined count tells them apart)
        check[todo] = residual(todo)
        todo = todo[~(check[todo] <= energy_tol)]
    if todo.numel():
        names = np.arange(len(params)) if indices is None else np.asarray(list(indices))
        what = "violate power balance" if system.has_forces else "drift"
        raise GenerationError(
            f"{todo.numel()} trajectories (indices {names[todo.numpy()][:10].tolist()}) {what} by up to "
            f"{check[todo].max().item():.2e} of the energy scale even with adaptive steps at tolerance "
            f"{tolerances[-1]:g} (energy_tol {energy_tol:g}): lower adaptive_tol, raise energy_tol or shorten dt")
    q, qd = y[..., :dof], y[..., dof:2 * dof]
    return (q, qd, steps, y[..., 2 * dof:]) if return_work else (q, qd, steps)


def _adaptive(system, q0, qd0, params, dt: float, num_steps: int, tol: float, tau):
    """Adaptive DOP853 rollouts from ``(q0, qd0)``: the state with the work of the forces (zero
    without forces) ``(B, num_steps + 1, 2 dof + 2)``, and the steps each took."""
    dof = system.dof
    if system.has_forces:
        y0 = torch.cat([q0, qd0, torch.zeros(len(q0), 2, dtype=q0.dtype, device=q0.device)], -1)
        return rollout_adaptive(_augmented_field(system), y0, params, dt, num_steps, rtol=tol, atol=tol, tau=tau)

    def field(z, params_):
        return torch.cat([z[:, dof:], system.acceleration(z[:, :dof], z[:, dof:], params_)], -1)

    y_state, n = rollout_adaptive(field, torch.cat([q0, qd0], -1), params, dt, num_steps, rtol=tol, atol=tol)
    return torch.cat([y_state, torch.zeros(*y_state.shape[:2], 2, dtype=y_state.dtype)], -1), n


def reference_rollout(system, q0, qd0, params, dt: float, num_steps: int, tau=None, energy_tol: float = 1e-10):
    """The exact trajectories of a scene from ``(q0, qd0)`` ``(B, dof)`` (with inputs ``tau (B,
    num_steps, n_u)`` held over each interval): ``(q, qd)`` each ``(B, num_steps + 1, dof)`` in float64,
    to ``energy_tol`` of the energy scale (``integrate_ground_truth``; raises ``GenerationError``
    where that cannot be reached)."""
    f64 = [None if x is None else torch.as_tensor(x, dtype=torch.float64) for x in (q0, qd0, params, tau)]
    with torch.no_grad():
        q, qd, _ = integrate_ground_truth(system, *f64[:3], dt, num_steps, energy_tol=energy_tol, tau=f64[3])
    return q, qd


class ClosedForm:
    """A scene's closed-form dynamics behind the model interface (``acceleration``, ``rollout`` in SI
    units): the ceiling rows of reports and the exact model of identification."""

    variant = "closed form"
    capabilities = frozenset()  # accelerations and rollouts only
    dtype = torch.float64  # (exact to round-off: identification polishes its fit by Gauss-Newton, as a float64 model's)

    def __init__(self, system) -> None:
        self.system = system

    def acceleration(self, q, qd, params, tau=None, check: bool = False):
        return self.system.acceleration(q, qd, params, tau)

    def rollout(self, q0, qd0, params, dt: float, num_steps: int, method: str = "rk4", tau=None):
        return rollout(self.system.acceleration, q0, qd0, params, dt, num_steps, method, tau=tau)
