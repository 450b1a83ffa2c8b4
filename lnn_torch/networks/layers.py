"""Building blocks: MLPs that carry forward-mode tangents by hand, and FiLM conditioning.

``TangentMLP.forward(x, dx)`` returns the output and its directional derivatives along the K
tangents ``dx`` (shape ``(K, B, n)``) in one pass: ``dh' = act'(z) * (W dh)`` needs no autograd, so
training needs only a first-order backward through this pass (no double backward). Each layer is a
handful of large ops (a fused ``addmm`` for the primal, one ``mm`` for all tangents, fused
``addcmul`` for the activation derivative and FiLM): on a CPU the cost of this workload is the
number of ops more than their arithmetic.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


_ONE, _MINUS_ONE = torch.tensor(1.0), torch.tensor(-1.0)


def _one(x: torch.Tensor) -> torch.Tensor:
    """A 0-dim one for ``x``'s device (a cached CPU constant on the CPU: no allocation per call)."""
    return _ONE if x.device.type == "cpu" else x.new_ones(())


def _minus_one(x: torch.Tensor) -> torch.Tensor:
    return _MINUS_ONE if x.device.type == "cpu" else -x.new_ones(())


def _affine(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None) -> torch.Tensor:
    """``x @ weight.T + bias`` as ONE fused ``addmm`` (an ``mm`` without bias)."""
    return torch.mm(x, weight.t()) if bias is None else torch.addmm(bias, x, weight.t())


# products with at most this many output columns are computed as ``(W @ x.T).T``
SKINNY = 8


def _mm_t(x: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """``x @ weight.T`` for ``x (B, k)``, ``weight (n, k)``.

    With few outputs (``n <= SKINNY``, ``B > n``) computed as ``(weight @ x.T).T``, whose result is a
    transposed view: MKL's single-thread kernels for a skinny right-hand side are slow (measured
    here, float32: ``(512, 128) @ (128, 4)`` 0.09-0.12 ms against 0.025-0.035 ms transposed;
    ``(1024, 128) @ (4, 128).T`` 0.085 ms against 0.054 ms).
    """
    if weight.shape[0] <= SKINNY < x.shape[0]:
        return torch.mm(weight, x.t()).t()
    return torch.mm(x, weight.t())


def _film_apply(op, *args: torch.Tensor) -> torch.Tensor:
    """``op(*args)`` of ``(B, H)`` activations and FiLM tensors that are per row ``(B, H)`` or per
    chunk ``(C, 1, H)`` (the activations are then viewed as ``(C, B / C, H)``); result ``(B, H)``."""
    film = next((a for a in args if a.dim() == 3), None)
    if film is None:
        return op(*args)
    C = film.shape[0]
    out = op(*(a.view(C, -1, a.shape[-1]) if a.dim() == 2 else a for a in args))
    return out.view(-1, out.shape[-1])


def _sigmoid_backward(grad: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """``grad * s * (1 - s)`` in one op (differentiable; broadcasts)."""
    return torch.ops.aten.sigmoid_backward(grad, s)


def _act(name: str):
    """(activation, derivative given (z, act(z))), each a single fused op where possible."""
    if name == "softplus":
        return F.softplus, lambda z, a: torch.sigmoid(z)
    if name == "tanh":
        # (TangentMLP runs tanh layers in sigmoid form instead: see TangentMLP._layer)
        return torch.tanh, lambda z, a: torch.addcmul(_one(a), a, a, value=-1)  # 1 - a^2
    if name == "sigmoid":
        return torch.sigmoid, lambda z, a: torch.addcmul(a, a, a, value=-1)  # a - a^2
    if name == "isru":  # inverse square-root unit z / sqrt(1 + z^2): smooth, tanh-shaped, no exp
        return lambda z: z * torch.rsqrt(1 + z * z), lambda z, a: torch.rsqrt(1 + z * z).pow(3)
    raise ValueError(f"unknown activation '{name}' (choose one of {', '.join(ACTIVATIONS)})")


ACTIVATIONS = ("softplus", "tanh", "sigmoid", "isru")


class FiLM(nn.Module):
    """Feature-wise linear modulation from a conditioning vector (normalised physical parameters).

    ``mode="neuron"`` gives a (gamma, beta) pair per hidden neuron of each layer; ``mode="layer"``
    one scalar pair per layer (the reference design). Initialised to the identity (gamma=1, beta=0).
    """

    def __init__(self, cond_dim: int, hidden_dims: list[int], mode: str = "neuron", film_hidden: int = 16) -> None:
        super().__init__()
        if mode not in ("neuron", "layer"):
            raise ValueError(f"FiLM mode must be 'neuron' or 'layer', got '{mode}'")
        self.mode = mode
        self.sizes = [h if mode == "neuron" else 1 for h in hidden_dims]
        self.net = nn.Sequential(nn.Linear(cond_dim, film_hidden), nn.SiLU(), nn.Linear(film_hidden, 2 * sum(self.sizes)))
        # identity at initialisation (gamma = 1 + 0, beta = 0); gamma is parametrised around 1 so that
        # weight decay pulls FiLM towards the identity, not towards gamma = 0
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)
        # the constant 1 of gamma = 1 + g, added to the output bias (a vector) instead of to every row
        offset = torch.cat([torch.ones(sum(self.sizes)), torch.zeros(sum(self.sizes))])
        self.register_buffer("gamma_offset", offset, persistent=False)
        self.register_buffer("sigmoid_map", torch.tensor([[2.0, 0.0], [-1.0, 1.0]]), persistent=False)

    def forward(self, cond: torch.Tensor, sigmoid_form: bool = False) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """``cond (B, cond_dim)`` -> ``[(gamma, beta), ...]`` per hidden layer, each ``(B, size)``.

        ``sigmoid_form``: return ``(2 gamma, beta - gamma)`` instead, the pair a tanh layer in sigmoid
        form needs (``gamma tanh(z) + beta = 2 gamma s + beta - gamma`` with ``s = sigmoid(2 z)``);
        the map is applied to the output layer's weights, not to the ``(B, size)`` outputs.
        """
        first, act, last = self.net
        weight, bias = last.weight, last.bias + self.gamma_offset.to(last.bias.dtype)
        if sigmoid_form:  # [2 gamma; beta - gamma] = A [gamma; beta], as (2, 2) @ (2, n F) products
            A = self.sigmoid_map.to(weight.dtype)
            weight = torch.mm(A, weight.view(2, -1)).view(weight.shape)
            bias = torch.mm(A, bias.view(2, -1)).view(bias.shape)
        out = _affine(act(_affine(cond, first.weight, first.bias)), weight, bias)  # (B, 2 sum(sizes)): [gammas | betas]
        parts = out.split(self.sizes + self.sizes, dim=-1)  # ONE split: its backward is one cat
        return list(zip(parts[: len(self.sizes)], parts[len(self.sizes):]))


class TangentMLP(nn.Module):
    """MLP ``in_dim -> hidden_dims -> out_dim`` with optional FiLM after each hidden activation."""

    def __init__(self, in_dim: int, hidden_dims: list[int], out_dim: int, activation: str = "tanh",
                 out_bias: bool = True) -> None:
        super().__init__()
        dims = [in_dim, *hidden_dims]
        self.hidden = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:]))
        # energies are defined up to a constant: their output bias would be a parameter without gradient
        self.out = nn.Linear(dims[-1], out_dim, bias=out_bias)
        self.activation = activation
        self._act, self._dact = _act(activation)
        # tanh layers run in sigmoid form (see ``_layer``); FiLM pairs must then come in that form
        self.sigmoid_form = activation == "tanh"

    def lnn_init(self) -> None:
        """The LNN paper's initialisation (Cranmer et al., appendix B): sigma = c / sqrt(n), zero biases."""
        n = self.hidden[0].out_features
        for i, layer in enumerate(self.hidden):
            nn.init.normal_(layer.weight, std=(2.2 if i == 0 else 0.58 * i) / math.sqrt(n))
            nn.init.zeros_(layer.bias)
        nn.init.normal_(self.out.weight, std=n / math.sqrt(n))
        if self.out.bias is not None:
            nn.init.zeros_(self.out.bias)

    def _layer(self, i: int, h: torch.Tensor, film, grad: bool):
        """Hidden layer ``i``: ``(h_next, g, c)`` with ``d h_next = c * g * dz`` (``z`` its pre-activation,
        ``c`` a Python number; ``g`` is None unless ``grad``).

        Tanh layers run in sigmoid form: ``s = sigmoid(2 z)`` (the 2 folded into the weights),
        ``tanh(z) = 2 s - 1`` and ``tanh'(z) = 4 s (1 - s)``; with FiLM pairs ``(2 gamma, beta - gamma)``
        (``FiLM(..., sigmoid_form=True)``) the layer output is ONE fused ``addcmul``. On CPUs torch's
        tanh kernel is also about twice as slow as its sigmoid kernel (measured here on a (512, 128)
        float32 array: 0.30 ms against 0.09 ms). The rounding differs from ``torch.tanh`` by a few
        ulp of 1; every path of a model (hand tangents, torch.func, autograd) runs this same code.
        """
        layer = self.hidden[i]
        if self.sigmoid_form:
            # the 2 on the (small) weights, not on the output: its backward is then no (B, H) product
            s = torch.sigmoid(_affine(h, layer.weight + layer.weight, layer.bias + layer.bias))
            if film is None:
                ds = torch.addcmul(s, s, s, value=-1) if grad else None  # s (1 - s)
                return torch.add(_minus_one(s), s, alpha=2), ds, 4.0
            gamma2, shift = film[i]
            # gamma2 s (1 - s) as ONE fused op (aten's sigmoid_backward: grad * (1 - s) * s)
            g = _film_apply(_sigmoid_backward, gamma2, s) if grad else None
            return _film_apply(torch.addcmul, shift, gamma2, s), g, 2.0
        z = _affine(h, layer.weight, layer.bias)
        a = self._act(z)
        d = self._dact(z, a) if grad else None
        if film is None:
            return a, d, 1.0
        gamma, beta = film[i]
        return _film_apply(torch.addcmul, beta, gamma, a), (_film_apply(torch.mul, d, gamma) if grad else None), 1.0

    def forward(self, x: torch.Tensor, dx: torch.Tensor | None = None, film=None, out_map: torch.Tensor | None = None):
        """Output and (optionally) its forward-mode tangents.

        Args:
            x: ``(B, in_dim)`` inputs.
            dx: ``(K, B, n)`` tangents of the first ``n <= in_dim`` inputs (the others are held
                fixed, e.g. conditioning parameters), or None.
            film: list of per-hidden-layer pairs, each ``(B, H)`` or ``(B, 1)`` (per row) or
                ``(C, 1, H)`` (per chunk of ``B / C`` consecutive rows), from
                ``FiLM(cond, sigmoid_form=self.sigmoid_form)``.
            out_map: ``(out, m)``: return ``y @ out_map`` instead of ``y`` (a linear map of the
                outputs, folded into the output layer's weights: no extra pass over the batch).

        Returns:
            ``y (B, out)`` and ``dy (K, B, out)`` (None without tangents); ``m`` columns with ``out_map``.
        """
        W_out, b_out = self.out.weight, self.out.bias  # (out, H), (out,)
        if out_map is not None:
            W_out, b_out = out_map.t() @ W_out, (None if b_out is None else b_out @ out_map)
        grad = dx is not None
        h, scale = x, 1.0
        if grad:
            K, B = dx.shape[0], x.shape[0]
            dh = dx.reshape(K * B, dx.shape[-1])  # tangents (K B, n); the true tangent is scale * dh
        for i, layer in enumerate(self.hidden):
            h, g, c = self._layer(i, h, film, grad)
            if grad:
                W = layer.weight
                dz = torch.mm(dh, (W[:, : dh.shape[-1]] if i == 0 else W).t())  # (K B, H)
                dh, scale = (dz.view(K, B, -1) * g).view(K * B, -1), scale * c
        y = _affine(h, W_out, b_out)
        if not grad:
            return y, None
        return y, _mm_t(dh, W_out * scale if scale != 1.0 else W_out).view(K, B, -1)

    def value_and_input_grad(self, x: torch.Tensor, film=None, num_grad_inputs: int | None = None):
        """Scalar-output MLP (``out_dim == 1``): ``y (B,)`` and ``dy/dx`` by a hand-written reverse
        pass (one ``B``-row matmul per layer instead of one per input direction).

        ``film`` as in ``forward``. ``num_grad_inputs``: differentiate only with respect to the first
        ``n`` inputs (``dy/dx[:, :n]``, shape ``(B, n)``); default all.
        """
        if self.out.out_features != 1:
            raise ValueError("value_and_input_grad needs a scalar output (out_dim == 1)")
        h, derivs, scale = x, [], 1.0
        for i in range(len(self.hidden)):
            h, g, c = self._layer(i, h, film, True)
            derivs.append(g)
            scale *= c
        y = _affine(h, self.out.weight, self.out.bias)[:, 0]
        delta = self.out.weight * scale if scale != 1.0 else self.out.weight  # (1, H): dy/dh, times the layers' c
        for i in range(len(self.hidden) - 1, -1, -1):
            W = self.hidden[i].weight
            if i == 0 and num_grad_inputs is not None:
                W = W[:, :num_grad_inputs]
            delta = _mm_t(delta * derivs[i], W.t())  # (B, H_in)
        return y, delta
