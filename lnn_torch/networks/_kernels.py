"""Private CPU-oriented kernels of the fast network paths (``TangentMLP``, ``FiLM``).

Everything here computes exactly what the plain formulas of ``lnn_torch.networks.reference`` compute
(tests compare them in float64); it only chooses cheaper forms for small-network workloads on a CPU,
where the number of ops and temporaries costs more than the arithmetic:

* tanh layers in sigmoid form: ``tanh(z) = 2 sigmoid(2z) - 1`` with the 2 folded into the weights,
  and FiLM's ``(gamma, beta)`` given as ``(2 gamma, beta - gamma)`` so that a FiLM'd layer output is
  ONE fused ``addcmul``; its derivative ``2 gamma s (1 - s)`` is one ``sigmoid_backward``;
* products with few output columns computed as ``(W @ x.T).T`` (``mm_t``);
* cached 0-dim constants instead of a new tensor per call.

The measurements behind these choices are in ``results/`` (``benchmark_dynamics.md``,
``compare_compile.md``).
"""

from __future__ import annotations

import torch

_ONE, _MINUS_ONE = torch.tensor(1.0), torch.tensor(-1.0)

# products with at most this many output columns are computed as ``(W @ x.T).T``
SKINNY = 8


def one(x: torch.Tensor) -> torch.Tensor:
    """A 0-dim one for ``x``'s device (a cached CPU constant on the CPU: no allocation per call)."""
    return _ONE if x.device.type == "cpu" else x.new_ones(())


def minus_one(x: torch.Tensor) -> torch.Tensor:
    return _MINUS_ONE if x.device.type == "cpu" else -x.new_ones(())


def affine(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None) -> torch.Tensor:
    """``x @ weight.T + bias`` as ONE fused ``addmm`` (an ``mm`` without bias)."""
    return torch.mm(x, weight.t()) if bias is None else torch.addmm(bias, x, weight.t())


def transposed(outputs: int, rows: int) -> bool:
    """Whether a product with ``outputs`` output columns over ``rows`` rows is computed as ``(W @ x.T).T``
    (``mm_t``; the fused path's stacked output layers): few outputs (``<= SKINNY``) and more rows than
    that, or any rows under ``torch.export`` (a program for every batch size: no branch on the batch)."""
    return outputs <= SKINNY and (torch.compiler.is_exporting() or SKINNY < rows)


def mm_t(x: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """``x @ weight.T`` for ``x (B, k)``, ``weight (n, k)``; with few outputs (``n <= SKINNY < B``)
    computed as ``(weight @ x.T).T`` (a transposed view): single-thread BLAS kernels for a skinny
    right-hand side are slow on the CPUs measured. Under ``torch.export`` (a program for every batch
    size: no branch on the batch) the transposed form whenever ``n <= SKINNY``."""
    if transposed(weight.shape[0], x.shape[0]):
        return torch.mm(weight, x.t()).t()
    return torch.mm(x, weight.t())


def film_apply(op, *args: torch.Tensor) -> torch.Tensor:
    """``op(*args)`` of ``(B, H)`` activations and FiLM tensors that are per row ``(B, H)`` or per
    chunk ``(C, 1, H)`` (the activations are then viewed as ``(C, B / C, H)``); result ``(B, H)``."""
    film = next((a for a in args if a.dim() == 3), None)
    if film is None:
        return op(*args)
    C = film.shape[0]
    out = op(*(a.view(C, -1, a.shape[-1]) if a.dim() == 2 else a for a in args))
    return out.view(-1, out.shape[-1])


def sigmoid_backward(grad: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """``grad * s * (1 - s)`` in one op (differentiable; broadcasts)."""
    return torch.ops.aten.sigmoid_backward(grad, s)


def sigmoid_form_tanh_layer(h, weight, bias, film, grad: bool):
    """A tanh layer ``gamma tanh(W h + b) + beta`` in sigmoid form: ``(h_next, g, c)`` with the layer's
    derivative ``d h_next = c * g * (W dh)`` (``g`` None unless ``grad``).

    ``s = sigmoid(2 (W h + b))`` (the 2 as the product's scalar factors, not on the ``(B, H)``
    output, so that its backward is no ``(B, H)`` product); ``tanh = 2 s - 1``,
    ``tanh' = 4 s (1 - s)``. ``film`` is the layer's pair in sigmoid form ``(2 gamma, beta - gamma)``
    or None.
    """
    s = torch.sigmoid(torch.addmm(bias, h, weight.t(), beta=2, alpha=2))
    if film is None:
        g = torch.addcmul(s, s, s, value=-1) if grad else None  # s (1 - s)
        return torch.add(minus_one(s), s, alpha=2), g, 4.0
    gamma2, shift = film
    g = film_apply(sigmoid_backward, gamma2, s) if grad else None  # 2 gamma s (1 - s), one fused op
    return film_apply(torch.addcmul, shift, gamma2, s), g, 2.0


def sigmoid_form_film(weight: torch.Tensor, bias: torch.Tensor, sigmoid_map: torch.Tensor):
    """The FiLM output layer's ``(weight, bias)`` mapped so that it outputs ``(2 gamma, beta - gamma)``
    instead of ``(gamma, beta)``: ``[2 gamma; beta - gamma] = A [gamma; beta]`` as (2, 2) products on
    the (small) weights rather than on the ``(B, n)`` outputs."""
    A = sigmoid_map.to(weight.dtype)
    return torch.mm(A, weight.view(2, -1)).view(weight.shape), torch.mm(A, bias.view(2, -1)).view(bias.shape)
