"""The fused inference path of ``film_lnn``'s default composition: the Cholesky MLP and the potential MLP,
each FiLM-conditioned, run as ONE stacked network.

The two networks have the same widths and activation, and read the same features (the potential the
parameters too), so each of their layers is one batched product over a leading axis of two
(``baddbmm``) instead of two products, and likewise their FiLM networks: about half the operators of
the part-by-part path (``structured.StructuredLagrangian._solve``) for the same arithmetic. On a CPU
an eager call of a small network costs more in operators than in arithmetic (``results/speed``).

It computes exactly what the parts compute (tests compare the two in float64), from the model's
weights stacked once and cached until a weight changes (``fusion_plan`` says what it sees): inference only, so the
model uses it where no gradient is recorded (``torch.no_grad``, ``torch.inference_mode``). Compiled
(``compile_dynamics``), such a call compiles this path with the stacked weights as the program's inputs
(``compiled_view``) up to ``COMPILED_MAX_ROWS`` rows a call, where it is the faster of the two: on the CPU
as an AOTInductor program called without dynamo (``fused_aot``), elsewhere through ``torch.compile``.

    plan = fusion_plan(model)            # None where the model's composition is another
    qdd = fused_solve(model, plan, q_norm, qd_norm, params_norm)
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch.optim.optimizer import register_optimizer_step_post_hook

from ._kernels import mm_t, sigmoid_backward, sigmoid_form_film, transposed
from .normalization import trusted

# Optimiser steps taken in this process, by any ``torch.optim`` optimiser: a step may change the weights
# without bumping their version counters (the fused AdamW kernel does not), so a plan stacked before the
# last step is stacked again. A global post-step hook only counts; it changes nothing else.
_optimizer_steps = 0


def _count_step(optimizer, args, kwargs) -> None:
    global _optimizer_steps
    _optimizer_steps += 1


register_optimizer_step_post_hook(_count_step)


@dataclass(frozen=True)
class FusionPlan:
    """The stacked weights of one model (index 0 the Cholesky MLP, 1 the potential MLP), in the model's
    dtype and device; ``key``: the identities, storages and versions of the tensors they were stacked from
    (``sources``: where they live; a weight replaced, moved, cast or changed in place gives another key),
    ``parts``: the model's part tuples they were stacked for, ``steps``: the process's optimiser steps then.

    Hidden layer ``i``: ``weights[i] (2, n_in, H)`` and ``biases[i] (2, 1, H)``, both times 2 (the tanh
    layers' sigmoid form: ``s = sigmoid(2 z)``); layer 0's kinetic rows for the parameters are zero (that
    network reads the features alone). ``kinetic_first (F, H)``: layer 0's kinetic weights on the
    features (the tangents' first product). ``out (2, H, m)``, ``out_bias (2, 1, m)``: the Cholesky
    entries scattered into the ``dof^2`` matrix (``m = dof^2``) and the potential in column 0;
    ``out_t (2, m, H)``, ``out_bias_t (2, m, 1)``: the same transposed (a product with few output
    columns is computed as ``(W @ h.T).T``, as ``_kernels.mm_t`` does).
    FiLM: ``film_in (2, P, h)``, ``film_in_bias (2, 1, h)``, ``film_out (2, h, 2 S)``, ``film_out_bias
    (2, 1, 2 S)`` in sigmoid form (``[2 gamma | beta - gamma]``, ``S`` the hidden widths' sum)."""

    key: tuple
    steps: int
    sources: tuple
    parts: tuple
    widths: tuple[int, ...]
    weights: tuple[torch.Tensor, ...]
    biases: tuple[torch.Tensor, ...]
    kinetic_first: torch.Tensor
    out: torch.Tensor
    out_bias: torch.Tensor
    out_t: torch.Tensor
    out_bias_t: torch.Tensor
    film_in: torch.Tensor
    film_in_bias: torch.Tensor
    film_out: torch.Tensor
    film_out_bias: torch.Tensor


def fusable(model) -> bool:
    """Whether ``model`` has the composition this path computes: a FiLM-conditioned structured model
    (not shared) with the Cholesky MLP alone as its kinetic part and the potential MLP alone as its
    potential, both tanh networks of the same widths, each with a per-neuron FiLM network with one
    hidden layer of the same width; the kinetic network reads every feature."""
    from .parts.cholesky import CholeskyMLP
    from .parts.potential_mlp import PotentialMLP

    if getattr(model, "conditioning", None) != "film" or getattr(model, "shared", True):
        return False
    kinetic, potential = getattr(model, "_kinetic_parts", ()), getattr(model, "_potential_parts", ())
    if len(kinetic) != 1 or len(potential) != 1:
        return False
    kin, pot = kinetic[0], potential[0]
    if type(kin) is not CholeskyMLP or type(pot) is not PotentialMLP or kin.index is not None or kin.residual:
        return False
    films = (kin.film, pot.film)
    if any(f is None or f.mode != "neuron" or len(f.net) != 3 for f in films):
        return False
    if films[0].net[0].out_features != films[1].net[0].out_features:
        return False
    nets = (kin.net, pot.net)
    return (all(n.activation == "tanh" for n in nets) and kin.hidden_dims == pot.hidden_dims
            and len(kin.net.hidden) == len(pot.net.hidden))


def plan_sources(model) -> tuple[tuple[dict, str], ...]:
    """Where the tensors the plan is stacked from live: ``(module._parameters, name)`` of both networks'
    layers and both FiLM networks (read through those dicts: a weight replaced there is seen)."""
    kin, pot = model._kinetic_parts[0], model._potential_parts[0]
    layers = [*kin.net.hidden, kin.net.out, *pot.net.hidden, kin.film.net[0], kin.film.net[2], pot.film.net[0],
              pot.film.net[2]]
    return (*((layer._parameters, name) for layer in layers for name in ("weight", "bias")),
            (pot.net.out._parameters, "weight"))


def _state(sources) -> tuple | None:
    """Each source tensor's identity, storage and version; None where one is an inference tensor (made under
    ``torch.inference_mode``: no version counter, so no plan can tell when it changes)."""
    try:
        return tuple((id(t), t.data_ptr(), t._version) for t in (d[name] for d, name in sources))
    except RuntimeError:
        return None


def fusion_plan(model) -> FusionPlan | None:
    """The model's stacked weights (cached on the model until a weight is replaced, cast, moved or
    changed in place, any optimiser takes a step, or the model's parts are swapped, e.g. by
    ``residuals_off``), or None where the model is not ``fusable``. A write that bypasses the version
    counters outside an optimiser (``param.data.add_(...)``) is not seen: set ``model.fuse_inference =
    False`` around such code, or delete ``model._fusion_plan`` after it."""
    plan = model.__dict__.get("_fusion_plan")
    if (plan is not None and plan.steps == _optimizer_steps and model._kinetic_parts is plan.parts[0]
            and model._potential_parts is plan.parts[1] and _state(plan.sources) == plan.key):
        return plan
    if not fusable(model):
        return None
    sources = plan_sources(model)
    state = _state(sources)
    if state is None:  # inference-tensor weights: the parts' path
        return None
    with torch.no_grad():
        plan = _stack(model, sources, state)
    object.__setattr__(model, "_fusion_plan", plan)  # a plain attribute: not a module, buffer or state
    return plan


def _stack(model, sources, state: tuple) -> FusionPlan:
    kin, pot = model._kinetic_parts[0], model._potential_parts[0]
    kn, pn = kin.net, pot.net
    first = sources[0][0][sources[0][1]]
    cast = dict(dtype=first.dtype, device=first.device)  # the networks' own (the constant buffers follow)
    num_features = kn.hidden[0].in_features
    weights, biases = [], []
    for i, (lk, lp) in enumerate(zip(kn.hidden, pn.hidden, strict=True)):
        wk, wp = lk.weight.to(**cast), lp.weight.to(**cast)
        if i == 0:  # the kinetic network reads the features alone: zero rows for the parameters
            wk = torch.cat([wk, wk.new_zeros(wk.shape[0], wp.shape[1] - wk.shape[1])], 1)
        weights.append(2 * torch.stack([wk.t(), wp.t()]).contiguous())
        biases.append(2 * torch.stack([lk.bias.to(**cast), lp.bias.to(**cast)])[:, None, :].contiguous())
    scatter = kin.scatter.to(**cast)
    w_kin = scatter.t() @ kn.out.weight.to(**cast)  # (dof^2, H)
    b_kin = kn.out.bias.to(**cast) @ scatter
    w_pot = torch.zeros_like(w_kin)
    w_pot[0] = pn.out.weight.to(**cast)[0]
    out = torch.stack([w_kin.t(), w_pot.t()]).contiguous()  # (2, H, dof^2)
    out_bias = torch.stack([b_kin, torch.zeros_like(b_kin)])[:, None, :].contiguous()
    film_in, film_in_bias, film_out, film_out_bias = [], [], [], []
    for film in (kin.film, pot.film):
        first, _, last = film.net
        w, b = sigmoid_form_film(last.weight.to(**cast), last.bias.to(**cast) + film.gamma_offset.to(**cast),
                                 film.sigmoid_map)
        film_in.append(first.weight.to(**cast).t())
        film_in_bias.append(first.bias.to(**cast)[None])
        film_out.append(w.t())
        film_out_bias.append(b[None])
    return FusionPlan(state, _optimizer_steps, sources, (model._kinetic_parts, model._potential_parts),
                      tuple(kin.hidden_dims), tuple(weights), tuple(biases),
                      2 * kn.hidden[0].weight.to(**cast)[:, :num_features].t().contiguous(), out, out_bias,
                      out.transpose(1, 2).contiguous(), out_bias.transpose(1, 2).contiguous(),
                      torch.stack(film_in).contiguous(), torch.stack(film_in_bias).contiguous(),
                      torch.stack(film_out).contiguous(), torch.stack(film_out_bias).contiguous())


# compiled, the fused path is the faster one up to this many rows a call; above it the compiler's own program
# of the part-by-part path is (one thread, benchmarks/speed_vs_original.py, results/speed/batches*: 0.055
# against 0.134 ms at batch 1, 0.68 against 0.82 ms at 512, 1.30 against 1.49 ms at 1024; 2.78 against 2.94
# ms at 2048, 6.34 against 6.07 ms at 4096)
COMPILED_MAX_ROWS = 1024


def compiled_view(model, plan: FusionPlan) -> FusionPlan:
    """``plan`` as compiled code takes it: its stacked weights without the bookkeeping of ``fusion_plan``
    (identities, versions, the parts), so that the compiler guards on the weights' shapes and dtypes alone
    and a change of weights needs no recompilation (cached on the model with the plan it views)."""
    cached = model.__dict__.get("_fusion_view")
    if cached is not None and cached[0] is plan:
        return cached[1]
    view = dataclasses.replace(plan, key=(), steps=0, sources=(), parts=())
    object.__setattr__(model, "_fusion_view", (plan, view))
    return view


def fused_films(plan: FusionPlan, params_norm: torch.Tensor) -> torch.Tensor:
    """Both networks' FiLM outputs in sigmoid form ``(2, B, 2 S)``: ``[2 gamma_1 .. 2 gamma_L | beta_1 -
    gamma_1 ..]`` per network (index 0 the Cholesky MLP's)."""
    cond = trusted(params_norm)
    hidden = F.silu(torch.baddbmm(plan.film_in_bias, cond.expand(2, *cond.shape), plan.film_in))
    return torch.baddbmm(plan.film_out_bias, hidden, plan.film_out)


def _stacked_out(plan: FusionPlan, h: torch.Tensor) -> torch.Tensor:
    """Both networks' output layers on their last hidden activations ``h (2, B, H)``: ``(2, B, m)``; with
    few outputs as ``(W @ h.T).T`` (a transposed view), as ``_kernels.mm_t`` (``_kernels.transposed``)."""
    if transposed(plan.out.shape[-1], h.shape[1]):
        return torch.baddbmm(plan.out_bias_t, plan.out_t, h.transpose(1, 2)).transpose(1, 2)
    return torch.baddbmm(plan.out_bias, h, plan.out)


def fused_solve(model, plan: FusionPlan, q_norm, qd_norm, params_norm, films: torch.Tensor | None = None,
                force: torch.Tensor | None = None) -> torch.Tensor:
    """Normalised accelerations of the model (as ``StructuredLagrangian.solve_norm``) under the
    normalised generalised force ``force`` (None: none); ``films``: ``fused_films`` of these parameters
    (None: computed here)."""
    from ..mechanics.euler_lagrange import structured_acceleration_from_factor
    from .parts.cholesky import chol_from

    films = fused_films(plan, params_norm) if films is None else films
    phi, dphi, sin_cos = model._features(q_norm, True)  # (B, F), (dof, B, F)
    x = torch.cat([phi, trusted(params_norm)], -1)
    h = x.expand(2, *x.shape)
    total = sum(plan.widths)
    gains, offset = [], 0
    for weight, bias, width in zip(plan.weights, plan.biases, plan.widths, strict=True):
        gamma2, shift = films[..., offset:offset + width], films[..., total + offset:total + offset + width]
        s = torch.sigmoid(torch.baddbmm(bias, h, weight))
        gains.append(sigmoid_backward(gamma2, s))  # d h_next / d z (with the 2 of z in the weights)
        h = torch.addcmul(shift, gamma2, s)
        offset += width
    out = _stacked_out(plan, h)  # (2, B, dof^2)
    # the Cholesky MLP's tangents along each coordinate (forward), the potential's gradient (reverse)
    dof, B = dphi.shape[0], x.shape[0]
    dh = (torch.mm(dphi.reshape(dof * B, -1), plan.kinetic_first).view(dof, B, -1) * gains[0][0])
    for weight, gain in zip(plan.weights[1:], gains[1:], strict=True):
        dh = torch.mm(dh.view(dof * B, -1), weight[0]).view(dof, B, -1) * gain[0]
    draw = mm_t(dh.view(dof * B, -1), plan.out_t[0]).view(dof, B, -1)
    delta = plan.out[1, :, 0]  # (H,): dV/dh_L
    for i in range(len(plan.weights) - 1, -1, -1):
        weight = plan.weights[i][1] if i else plan.weights[0][1, : phi.shape[-1]]  # (n_in, H)
        delta = mm_t(delta * gains[i][1], weight)
    dV = model.features_vjp(q_norm, delta, sin_cos)
    chol, dchol = chol_from(out[0], draw, model._kinetic_parts[0].diag, model._kinetic_parts[0].diag_shift, dof)
    return structured_acceleration_from_factor(chol, dchol, qd_norm, dV, model.eps, force=force)
