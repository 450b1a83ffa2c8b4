"""The exact reference of a scene's dynamics: float64 ground-truth integration, used by the dataset
generator and by every evaluation that compares a model with the truth (one implementation).

A fast fixed-step pass (8th-order Runge-Kutta by default) for all trajectories, then adaptive DOP853
steps for those whose relative energy drift exceeds the tolerance (stiff or fast ones).
"""

from __future__ import annotations

import numpy as np
import torch

from .integrators import rollout, rollout_adaptive
from .metrics import energy_drift


class GenerationError(RuntimeError):
    """Ground truth could not be integrated to the requested accuracy."""


def _relative_drift(system, q, qd, params) -> torch.Tensor:
    """Max over time of |E(t) - E(0)| / energy scale, per trajectory ``(N,)``."""
    return energy_drift(system, q, qd, params).amax(1)


def integrate_ground_truth(system, q0, qd0, params, dt: float, num_steps: int, integrator: str = "rk8",
                           substeps: int = 1, energy_tol: float = 1e-10, adaptive_tol: float = 1e-11,
                           callback=None, indices=None):
    """Ground truth in float64: a fast fixed-step pass for all trajectories, then adaptive DOP853
    steps for those whose relative energy drift exceeds ``energy_tol`` (stiff or fast ones).

    Returns ``q, qd`` ``(N, num_steps + 1, dof)`` and the integrator steps each trajectory took
    ``(N,)``. Raises ``GenerationError`` naming the trajectories (``indices``, default 0..N-1) that
    still drift beyond ``energy_tol`` after the adaptive pass.
    """
    q, qd = rollout(system.acceleration, q0, qd0, params, dt, num_steps, integrator, substeps, callback=callback)
    steps = torch.full((len(params),), num_steps * substeps, dtype=torch.long)
    drift = _relative_drift(system, q, qd, params)
    todo = torch.nonzero(~(drift <= energy_tol))[:, 0]  # NaN counts as not converged
    if todo.numel():
        dof = system.dof

        def field(y, params_):
            return torch.cat([y[:, dof:], system.acceleration(y[:, :dof], y[:, dof:], params_)], -1)

        y, n = rollout_adaptive(field, torch.cat([q0[todo], qd0[todo]], -1), params[todo], dt, num_steps,
                                rtol=adaptive_tol, atol=adaptive_tol)
        q[todo], qd[todo], steps[todo] = y[..., :dof], y[..., dof:], n
        drift[todo] = _relative_drift(system, q[todo], qd[todo], params[todo])
        bad = todo[~(drift[todo] <= energy_tol)]
        if bad.numel():
            names = np.arange(len(params)) if indices is None else np.asarray(list(indices))
            raise GenerationError(
                f"{bad.numel()} trajectories (indices {names[bad.numpy()][:10].tolist()}) drift by up to "
                f"{drift[bad].max().item():.2e} of the energy scale even with adaptive steps at tolerance "
                f"{adaptive_tol:g} (energy_tol {energy_tol:g}): lower adaptive_tol, raise energy_tol or shorten dt")
    return q, qd, steps


def reference_rollout(system, q0, qd0, params, dt: float, num_steps: int, energy_tol: float = 1e-10):
    """The exact trajectories of a scene from ``(q0, qd0)`` ``(B, dof)``: ``(q, qd)`` each
    ``(B, num_steps + 1, dof)`` in float64, to ``energy_tol`` of the energy scale
    (``integrate_ground_truth``; raises ``GenerationError`` where that cannot be reached)."""
    f64 = [torch.as_tensor(x, dtype=torch.float64) for x in (q0, qd0, params)]
    with torch.no_grad():
        q, qd, _ = integrate_ground_truth(system, *f64, dt, num_steps, energy_tol=energy_tol)
    return q, qd
