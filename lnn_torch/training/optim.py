"""The optimiser and its schedule: AdamW (the fused kernel where torch has one) with the physical
coefficients exempt from weight decay, and a cosine learning rate from ``lr`` to ``lr_min`` that ends
with the run: at its step budget or, under a ``max_time`` (Lightning's ``Timer``), its time budget,
whichever comes first. And ``train_only``: which of a model's parameters train at all."""

from __future__ import annotations

import math

import torch

from ..errors import InputError
from ..perf import adamw
from .checkpoint_format import RESIDUAL


def training_progress(trainer, step: int) -> float:
    """Fraction of a run's training budget used at optimiser step ``step``: of its steps or, under a
    ``max_time``, of its time, whichever is further (0 outside a trainer)."""
    if trainer is None:
        return 0.0
    from lightning.pytorch.callbacks import Timer  # Lightning only where a trainer runs

    total = trainer.estimated_stepping_batches
    progress = step / total if total and math.isfinite(total) else 0.0
    for cb in trainer.callbacks:
        if isinstance(cb, Timer) and cb.time_remaining("train") is not None:
            elapsed = cb.time_elapsed("train")
            duration = elapsed + cb.time_remaining("train")
            progress = max(progress, elapsed / duration if duration > 0 else 1.0)
    return min(progress, 1.0)


# train_only: the names of a model's parameters it trains (in the model, not in the LNNModule around it)
TRAINABLE_PARTS = {"residual_force": RESIDUAL.removeprefix("model.")}


def freeze_all_but(model, part: str | None, init_from: str | None) -> None:
    """``train_only``: with ``part`` (a name of ``TRAINABLE_PARTS``) every parameter of ``model`` outside that
    part stops training (``requires_grad`` False); None leaves all. A model without the part, or a run
    without ``init_from`` (whose frozen weights would stay as initialised), is refused."""
    if part is None:
        return
    if not init_from:
        raise InputError(f"train_only {part} needs init_from: the fitted model whose other weights stay as they are")
    if part not in TRAINABLE_PARTS:
        raise InputError(f"train_only must be one of {', '.join(TRAINABLE_PARTS)} or null, got {part!r}")
    names = [n for n, _ in model.named_parameters() if n.startswith(TRAINABLE_PARTS[part])]
    if not names:
        raise InputError(f"train_only {part}: the model has no {part} (set model_options.{part})")
    for name, p in model.named_parameters():
        p.requires_grad_(name.startswith(TRAINABLE_PARTS[part]))


def configure_optimizer(parameters, coefficients, *, lr: float, lr_min: float, weight_decay: float,
                        progress, fused: bool = True) -> dict:
    """Lightning's ``configure_optimizers`` answer: AdamW over ``parameters`` with ``weight_decay`` on
    all but ``coefficients`` (physical coefficients: a decay would pull a mass or a length towards
    zero), and a per-step cosine from ``lr`` to ``lr_min`` over ``progress(step)`` in [0, 1]; ``fused``:
    ``perf.adamw``'s."""
    params = list(parameters)
    if weight_decay:
        exempt = {id(p) for p in coefficients}
        groups = [{"params": [p for p in params if id(p) not in exempt]},
                  {"params": [p for p in params if id(p) in exempt], "weight_decay": 0.0}]
        params = [g for g in groups if g["params"]]
    opt = adamw(params, fused=fused, lr=lr, weight_decay=weight_decay)
    floor = lr_min / lr
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda step: floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * progress(step))))
    return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}
