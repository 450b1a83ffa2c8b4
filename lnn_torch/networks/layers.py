"""Building blocks: MLPs that carry forward-mode tangents by hand, and FiLM conditioning.

``TangentMLP.forward(x, dx)`` returns the output and its directional derivatives along the K
tangents ``dx`` (shape ``(K, B, n)``) in one pass: ``dh' = act'(z) * (W dh)`` needs no autograd, so
training needs only a first-order backward through this pass (no double backward). Each layer is a
handful of large ops (the cheaper forms are in the private ``_kernels`` module); the plain formulas
they compute are ``lnn_torch.networks.reference``, which the tests compare against.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from ._kernels import affine, film_apply, mm_t, one, sigmoid_form_film, sigmoid_form_tanh_layer


def _d_softplus(z, a):
    return torch.sigmoid(z)


def _d_tanh(z, a):
    return torch.addcmul(one(a), a, a, value=-1)  # 1 - a^2


def _d_sigmoid(z, a):
    return torch.addcmul(a, a, a, value=-1)  # a - a^2


def _isru(z):  # inverse square-root unit z / sqrt(1 + z^2): smooth, tanh-shaped, no exp
    return z * torch.rsqrt(1 + z * z)


def _d_isru(z, a):
    return torch.rsqrt(1 + z * z).pow(3)


# name -> (activation, its derivative given (z, act(z))); module-level functions, so that models pickle
_ACTS = {"softplus": (F.softplus, _d_softplus), "tanh": (torch.tanh, _d_tanh),
         "sigmoid": (torch.sigmoid, _d_sigmoid), "isru": (_isru, _d_isru)}


def _act(name: str):
    """(activation, derivative given (z, act(z))). Tanh layers of ``TangentMLP`` run in sigmoid form instead."""
    try:
        return _ACTS[name]
    except KeyError:
        raise ValueError(f"unknown activation '{name}' (choose one of {', '.join(ACTIVATIONS)})") from None


ACTIVATIONS = ("softplus", "tanh", "sigmoid", "isru")


def quadratic_features(cond: torch.Tensor, rows: torch.Tensor, cols: torch.Tensor) -> torch.Tensor:
    """``[c, c_i c_j for (i, j) in zip(rows, cols)]`` of ``cond (B, n)``: ``(B, n + len(rows))``."""
    return torch.cat([cond, cond[..., rows] * cond[..., cols]], -1)


class QuadraticFeatures(nn.Module):
    """``c -> [c, c_i c_j for i <= j]`` (``(B, n) -> (B, size)``): a linear layer after it is a quadratic
    polynomial of ``c``."""

    def __init__(self, n: int) -> None:
        super().__init__()
        self.size = n + n * (n + 1) // 2
        rows, cols = torch.triu_indices(n, n)
        self.register_buffer("rows", rows, persistent=False)
        self.register_buffer("cols", cols, persistent=False)

    def forward(self, cond: torch.Tensor) -> torch.Tensor:
        return quadratic_features(cond, self.rows, self.cols)


class FiLM(nn.Module):
    """Feature-wise linear modulation from a conditioning vector (normalised physical parameters).

    ``mode="neuron"`` gives a (gamma, beta) pair per hidden neuron of each layer; ``mode="layer"``
    one scalar pair per layer (the reference design). Initialised to the identity (gamma=1, beta=0).

    ``film_hidden``: the width of the one hidden (SiLU) layer of the network from the parameters to the
    pairs; 0: no hidden layer, each gamma and beta a quadratic polynomial of the parameters (a linear
    map of ``[c, c_i c_j for i <= j]``, ``quadratic_features``). A network of the parameters can tell
    every training system from the next (each trajectory's parameters are its own) and so fit each
    one's samples on its own; a polynomial cannot, and it is the form physics takes where parameters
    enter linearly (a payload's mass and first moment enter ``T`` and ``V`` linearly).
    """

    def __init__(self, cond_dim: int, hidden_dims: list[int], mode: str = "neuron", film_hidden: int = 16) -> None:
        super().__init__()
        if mode not in ("neuron", "layer"):
            raise ValueError(f"FiLM mode must be 'neuron' or 'layer', got '{mode}'")
        if film_hidden < 0:
            raise ValueError(f"film_hidden must be >= 0 (0: quadratic in the parameters), got {film_hidden}")
        self.mode = mode
        self.sizes = [h if mode == "neuron" else 1 for h in hidden_dims]
        if film_hidden:
            self.net = nn.Sequential(nn.Linear(cond_dim, film_hidden), nn.SiLU(),
                                     nn.Linear(film_hidden, 2 * sum(self.sizes)))
        else:
            self.net = nn.Sequential(nn.Linear(cond_dim + cond_dim * (cond_dim + 1) // 2, 2 * sum(self.sizes)))
            rows, cols = torch.triu_indices(cond_dim, cond_dim)
            self.register_buffer("pair_rows", rows, persistent=False)
            self.register_buffer("pair_cols", cols, persistent=False)
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
        last = self.net[-1]
        weight, bias = last.weight, last.bias + self.gamma_offset.to(last.bias.dtype)
        if sigmoid_form:
            weight, bias = sigmoid_form_film(weight, bias, self.sigmoid_map)
        if len(self.net) == 1:
            hidden = quadratic_features(cond, self.pair_rows, self.pair_cols)
        else:
            first, act, _ = self.net
            hidden = act(affine(cond, first.weight, first.bias))
        out = affine(hidden, weight, bias)  # (B, 2 sum(sizes)): [gammas | betas]
        parts = out.split(self.sizes + self.sizes, dim=-1)  # ONE split: its backward is one cat
        return list(zip(parts[: len(self.sizes)], parts[len(self.sizes):], strict=True))


class TangentMLP(nn.Module):
    """MLP ``in_dim -> hidden_dims -> out_dim`` with optional FiLM after each hidden activation."""

    def __init__(self, in_dim: int, hidden_dims: list[int], out_dim: int, activation: str = "tanh",
                 out_bias: bool = True) -> None:
        super().__init__()
        dims = [in_dim, *hidden_dims]
        self.hidden = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:], strict=True))
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
        ``c`` a Python number; ``g`` is None unless ``grad``). Tanh layers run in sigmoid form
        (``_kernels.sigmoid_form_tanh_layer``; FiLM pairs must then come from
        ``FiLM(..., sigmoid_form=True)``); every path of a model (hand tangents, torch.func, autograd)
        runs this same code."""
        layer = self.hidden[i]
        if self.sigmoid_form:
            return sigmoid_form_tanh_layer(h, layer.weight, layer.bias, None if film is None else film[i], grad)
        z = affine(h, layer.weight, layer.bias)
        a = self._act(z)
        d = self._dact(z, a) if grad else None
        if film is None:
            return a, d, 1.0
        gamma, beta = film[i]
        return film_apply(torch.addcmul, beta, gamma, a), (film_apply(torch.mul, d, gamma) if grad else None), 1.0

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
        y = affine(h, W_out, b_out)
        if not grad:
            return y, None
        return y, mm_t(dh, W_out * scale if scale != 1.0 else W_out).view(K, B, -1)

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
        y = affine(h, self.out.weight, self.out.bias)[:, 0]
        delta = self.out.weight * scale if scale != 1.0 else self.out.weight  # (1, H): dy/dh, times the layers' c
        for i in range(len(self.hidden) - 1, -1, -1):
            W = self.hidden[i].weight
            if i == 0 and num_grad_inputs is not None:
                W = W[:, :num_grad_inputs]
            delta = mm_t(delta * derivs[i], W.t())  # (B, H_in)
        return y, delta


class GroupedMLP(nn.Module):
    """``groups`` independent MLPs ``in_dim -> hidden_dims -> 1`` run as one batched pass: ``(B, groups,
    in_dim) -> (B, groups)``, group ``g``'s output from its own inputs ``x[:, g]`` alone (a network per
    joint, e.g. the local force residual). Default PyTorch initialisation per group (uniform in
    ``+-1/sqrt(fan_in)``)."""

    def __init__(self, groups: int, in_dim: int, hidden_dims: list[int], activation: str = "tanh") -> None:
        super().__init__()
        dims = [in_dim, *hidden_dims, 1]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for a, b in zip(dims[:-1], dims[1:], strict=True):
            bound = 1 / math.sqrt(a)
            self.weights.append(nn.Parameter(torch.empty(groups, a, b).uniform_(-bound, bound)))
            self.biases.append(nn.Parameter(torch.empty(groups, 1, b).uniform_(-bound, bound)))
        self._act, _ = _act(activation)

    @property
    def out_layer(self) -> tuple[nn.Parameter, nn.Parameter]:
        """The output layer's ``(weight (groups, h, 1), bias (groups, 1, 1))``."""
        return self.weights[-1], self.biases[-1]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = x.transpose(0, 1)  # (groups, B, in)
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            h = torch.baddbmm(b.to(h.dtype), h, w.to(h.dtype))
            if i < last:
                h = self._act(h)
        return h[..., 0].transpose(0, 1)
