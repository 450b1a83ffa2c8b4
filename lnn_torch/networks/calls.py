"""Calls of any model for evaluation and training: batched, without an autograd graph, and counting
undefined accelerations as NaN instead of raising (``NAN_ON_SINGULAR`` models).

Models are anything with ``acceleration(q, qd, params, tau=None, check=False)`` and ``rollout(q0, qd0,
params, dt, num_steps, method, tau=None)`` in SI units (every ``DynamicsModel``; a scene's closed
form, ``lnn_torch.systems.ground_truth.ClosedForm``).
"""

from __future__ import annotations

import contextlib

import torch

from .capabilities import NAN_ON_SINGULAR, capabilities_of


@contextlib.contextmanager
def counting_failures(model):
    """Within the block, a model whose accelerations can be undefined (``NAN_ON_SINGULAR``: the
    black-box LNN's singular Hessians) returns NaN there instead of raising, so that batched
    evaluations count them."""
    if NAN_ON_SINGULAR in capabilities_of(model):
        with model.nan_on_singular():
            yield model
    else:
        yield model


def model_accelerations(model, q, qd, params, tau=None, max_batch: int = 16384) -> torch.Tensor:
    """A model's accelerations at states ``(B, T, dof)`` of trajectories with parameters ``(B, P)``
    (and inputs ``tau (B, T, n_u)``): ``(B, T, dof)`` in ``q``'s dtype; NaN where undefined. No
    autograd graph."""
    B, T, dof = q.shape
    flat_q, flat_qd = q.reshape(-1, dof), qd.reshape(-1, dof)
    flat_p = params[:, None, :].expand(-1, T, -1).flatten(0, 1)
    flat_tau = None if tau is None else tau.reshape(B * T, -1)
    out = []
    with torch.no_grad(), counting_failures(model):
        for i in range(0, B * T, max_batch):
            sl = slice(i, i + max_batch)
            out.append(model.acceleration(flat_q[sl], flat_qd[sl], flat_p[sl],
                                          None if flat_tau is None else flat_tau[sl], check=False))
    return torch.cat(out).reshape(B, T, dof)


def model_rollout(model, q0, qd0, params, dt: float, num_steps: int, method: str = "rk4", tau=None):
    """A model's rollout (inputs ``tau (B, num_steps, n_u)`` held over each step) without an autograd
    graph; trajectories through undefined accelerations become NaN (counted by the metrics)."""
    with torch.no_grad(), counting_failures(model):
        q, qd = model.rollout(q0, qd0, params, dt, num_steps, method, tau=tau)
    return q.detach(), qd.detach()
