"""Building blocks: MLPs that carry forward-mode tangents by hand, and FiLM conditioning.

``TangentMLP.forward(x, dx)`` returns the output and its directional derivatives along the K
tangents ``dx`` (shape ``(K, B, in_dim)``) in one pass: primal and tangents share each matmul
(``(1 + K) B`` rows), and ``dh' = act'(z) * (W dh)`` needs no autograd. Training then needs only a
first-order backward through this pass (no double backward).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


def _act(name: str):
    """(activation, derivative given (z, act(z)))."""
    if name == "softplus":
        return F.softplus, lambda z, a: torch.sigmoid(z)
    if name == "tanh":
        return torch.tanh, lambda z, a: 1 - a * a
    if name == "sigmoid":
        return torch.sigmoid, lambda z, a: a - a * a
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
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, cond: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
        out = self.net(cond)  # (B, 2 * sum(sizes))
        gammas, betas = out.split(sum(self.sizes), dim=-1)
        return [(1 + g, b) for g, b in zip(gammas.split(self.sizes, -1), betas.split(self.sizes, -1))]


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

    def lnn_init(self) -> None:
        """The LNN paper's initialisation (Cranmer et al., appendix B): sigma = c / sqrt(n), zero biases."""
        n = self.hidden[0].out_features
        for i, layer in enumerate(self.hidden):
            nn.init.normal_(layer.weight, std=(2.2 if i == 0 else 0.58 * i) / math.sqrt(n))
            nn.init.zeros_(layer.bias)
        nn.init.normal_(self.out.weight, std=n / math.sqrt(n))
        if self.out.bias is not None:
            nn.init.zeros_(self.out.bias)

    def forward(self, x: torch.Tensor, dx: torch.Tensor | None = None, film=None):
        """x ``(B, in)``; dx ``(K, B, in)`` or None; film: list of (gamma, beta) per hidden layer.

        Returns ``y (B, out)`` and ``dy (K, B, out)`` (None without tangents).
        """
        if dx is None:
            h = x
            for i, layer in enumerate(self.hidden):
                h = self._act(layer(h))
                if film is not None:
                    g, b = film[i]
                    h = g * h + b
            return self.out(h), None
        K = dx.shape[0]
        h = torch.cat([x[None], dx], 0)  # (1 + K, B, in)
        for i, layer in enumerate(self.hidden):
            zz = h @ layer.weight.T  # (1 + K, B, H)
            z = zz[0] + layer.bias
            a = self._act(z)
            da = self._dact(z, a)
            if film is not None:
                g, b = film[i]
                a = g * a + b
                da = g * da
            dz = zz[1:] * da  # (K, B, H)
            h = torch.cat([a[None], dz], 0)
        yy = h @ self.out.weight.T
        return (yy[0] if self.out.bias is None else yy[0] + self.out.bias), yy[1:]

    def value_and_input_grad(self, x: torch.Tensor, film=None):
        """Scalar-output MLP (``out_dim == 1``): ``y (B,)`` and ``dy/dx (B, in)`` by a hand-written
        reverse pass (one ``B``-row matmul per layer instead of one per input direction)."""
        if self.out.out_features != 1:
            raise ValueError("value_and_input_grad needs a scalar output (out_dim == 1)")
        h, zs, acts, gains = x, [], [], []
        for i, layer in enumerate(self.hidden):
            z = layer(h)
            a = self._act(z)
            zs.append(z)
            acts.append(a)
            if film is not None:
                g, b = film[i]
                h = g * a + b
                gains.append(g)
            else:
                h = a
                gains.append(None)
        y = self.out(h)[..., 0]
        delta = self.out.weight  # (1, H): dy/dh of the last hidden layer
        for i in range(len(self.hidden) - 1, -1, -1):
            d = self._dact(zs[i], acts[i])
            if gains[i] is not None:
                d = d * gains[i]
            delta = (delta * d) @ self.hidden[i].weight  # (B, H_in)
        return y, delta
