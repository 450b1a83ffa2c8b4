"""How much of the torque a model's residuals carry: the contribution that "a residual that never
hurts" reports beside its errors.

A structured model's residuals (``StructuredLagrangian.residual_names``: the force residual ``Q_r``,
the Cholesky MLP beside the rigid-body mass matrix, the potential MLP beside the rigid-body gravity)
each carry the difference they make to the model's inverse dynamics: per input (joint), the RMS over
the data of ``tau_model - tau_model_without_it`` (N m), beside the RMS of the model's torque itself and
of the recorded torque. For the force residual that difference is ``-Q_r`` exactly (the inverse
dynamics are affine in it); for the kinetic and potential residuals it is what their mass-matrix and
potential terms add to ``M qdd + n``. Where a residual's share is small against the model's torque
error, it does not pay and the physics alone is the answer.
"""

from __future__ import annotations

import torch

from .capabilities import INVERSE_DYNAMICS


def _inverse(model, q, qd, qdd, params, batch: int) -> torch.Tensor:
    return torch.cat([model.inverse(q[i:i + batch], qd[i:i + batch], qdd[i:i + batch],
                                                params[i:i + batch]) for i in range(0, len(q), batch)])


def _rms(x: torch.Tensor) -> list[float]:
    return x.double().pow(2).mean(0).sqrt().tolist()


@torch.no_grad()
def torque_shares(model, q, qd, qdd, params, tau=None, batch: int = 4096) -> dict:
    """The torque each of ``model``'s residuals carries on states ``q, qd, qdd (N, dof)`` (SI) with
    parameters ``params (N, P)`` and, optionally, the recorded inputs ``tau (N, n_u)`` (N m).

    Returns a JSON-ready dict (lists per input, N m): ``model_rms`` (the model's torque), ``data_rms``
    (the recorded torque; None without ``tau``), ``physics_rms`` (the model with every residual off),
    ``residuals``: ``{name: {"rms": per input, "share": rms / model_rms per input, "share_mean": the
    mean over inputs}}`` (empty for a model without residuals); ``InputError`` for a model without
    inverse dynamics."""
    model = getattr(model, "model", model)  # an LNNModule or its network
    model._require(INVERSE_DYNAMICS)
    full = _inverse(model, q, qd, qdd, params, batch)
    names = model.residual_names() if hasattr(model, "residual_names") else ()
    residuals = {}
    for name in names:
        with model.residuals_off(name):
            without = _inverse(model, q, qd, qdd, params, batch)
        rms = _rms(full - without)
        share = [r / max(m, 1e-30) for r, m in zip(rms, _rms(full), strict=True)]
        residuals[name] = {"rms": rms, "share": share, "share_mean": sum(share) / len(share)}
    physics = full
    if names:
        with model.residuals_off():
            physics = _inverse(model, q, qd, qdd, params, batch)
    return {"model_rms": _rms(full),
            "data_rms": None if tau is None else _rms(tau), "physics_rms": _rms(physics), "residuals": residuals}
