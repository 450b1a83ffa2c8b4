"""The physically consistent fit's objective (``classical_arm.consistent_fit``) with its gradient and Hessian in
closed form, for a drive model whose friction is linear in its coefficients (every form but ``sigmoid``).

The unknowns ``theta`` are, in order: each link's ten log-Cholesky parameters (``kinematics.log_cholesky``:
``J = U U^T``, ``U``'s diagonal ``exp`` of the first four, its six entries above the diagonal the rest), the
square roots of the armatures, then the friction coefficients ``(K, n)`` in the drive's order
(``DriveModel.coefficient_names``): passive ones squared, the offset ``o`` as it is, and a saturating
friction's ``d`` squared less ``floor`` times the Coulomb level. The physical vector is ``p = (the classical ten
of each link, the armatures, the viscous coefficients, the other linear coefficients joint by joint)`` and the
objective

    E(theta) = p^T A p - 2 b^T p + c + prior * sum_links (tr(J0^-1 J) - log det J + log det J0 - 4),

the mean squared torque error as a quadratic form in ``p`` plus the LogDet divergence from the description
``J0``. Every piece of ``p`` depends on one link's parameters or on one coefficient, and ``log det J`` is twice
the sum of the first four log-Cholesky parameters, so the gradient and the Hessian are small dense algebra:
``H = Jp^T (2 A) Jp + sum_k g_k d2p_k`` with ``g = 2 (A p - b)``, the second term block-diagonal by link (and
diagonal for the coefficients). ``classical_arm.consistent_fit`` evaluates the same objective with autograd
for a sigmoid drive; ``tests/test_classical.py`` checks both against each other.
"""

from __future__ import annotations

import numpy as np
import torch

from ..robots.regressor import classical_of


def _factor_basis() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``E (10, 4, 4)``: where each log-Cholesky parameter sits in ``U`` (``kinematics.log_cholesky_factor``), and
    its row and column ``(10,)`` each."""
    upper = torch.triu_indices(4, 4, 1).numpy()
    rows = np.concatenate([np.arange(4), upper[0]])
    cols = np.concatenate([np.arange(4), upper[1]])
    E = np.zeros((10, 4, 4))
    E[np.arange(10), rows, cols] = 1.0
    return E, rows, cols


def _classical_map() -> np.ndarray:
    """``C (10, 16)``: the classical ten of a pseudo-inertia as a linear map of its 16 entries (``classical_of``)."""
    basis = torch.eye(16, dtype=torch.float64).reshape(16, 4, 4)
    return classical_of(basis).numpy().T.copy()


class ConsistentObjective:
    """``E(theta)`` (module docstring) of the quadratic form ``A (P, P), b (P,), c`` and the description's
    pseudo-inertias ``J0 (n, 4, 4)``; ``names`` the drive's coefficient names, ``linear_names`` those of the
    linear forms beyond viscous (their columns after the regressor's, joint by joint), ``floor`` the saturating
    friction's lower limit as a multiple of the Coulomb level."""

    def __init__(self, A, b, c: float, J0, names, linear_names, floor: float = 0.0) -> None:
        self.A, self.b, self.c = np.asarray(A, np.float64), np.asarray(b, np.float64), float(c)
        J0 = np.asarray(J0, np.float64)
        n = self.n = J0.shape[0]
        names, linear_names = list(names), list(linear_names)
        self.size = 11 * n + len(names) * n
        P = 12 * n + len(linear_names) * n
        if self.A.shape != (P, P) or self.b.shape != (P,):
            raise ValueError(f"the quadratic form has {self.A.shape}, {self.b.shape}; {P} physical values expected")
        self.W0 = np.linalg.inv(J0).transpose(0, 2, 1)  # tr(J0^-1 J) = <J0^-T, J>
        self.logdet0 = float(np.linalg.slogdet(J0)[1].sum())
        self.E, self.rows, self.cols = _factor_basis()
        self.C = _classical_map()
        # the physical values after the links' from the unknowns after theirs: Q @ theta^2 + L @ theta
        Q, L = np.zeros((P - 10 * n, self.size - 10 * n)), np.zeros((P - 10 * n, self.size - 10 * n))
        Q[np.arange(n), np.arange(n)] = 1.0  # armature: the square of its root

        def put(row: int, name: str, j: int) -> None:
            col = n + names.index(name) * n + j
            if name in ("o", "phi3"):
                L[row, col] += 1.0
            else:
                Q[row, col] += 1.0
                if name == "d" and "c" in names:
                    Q[row, n + names.index("c") * n + j] -= floor

        for j in range(n):
            if "b" in names:
                put(n + j, "b", j)
            for i, name in enumerate(linear_names):
                put(2 * n + j * len(linear_names) + i, name, j)
        self.Q, self.L = Q, L

    def _state(self, theta):
        n = self.n
        theta = np.asarray(theta, np.float64)
        raw, rest = theta[: 10 * n].reshape(n, 10), theta[10 * n:]
        u = raw.copy()
        u[:, :4] = np.exp(raw[:, :4])
        U = np.einsum("lk,kab->lab", u, self.E)
        J = U @ U.transpose(0, 2, 1)
        p = np.concatenate([(J.reshape(n, 16) @ self.C.T).reshape(-1), self.Q @ rest ** 2 + self.L @ rest])
        slope = np.where(np.arange(10) < 4, u, 1.0)  # d u / d raw
        return raw, rest, u, slope, U, J, p

    def value_and_gradient(self, theta, prior: float) -> tuple[float, np.ndarray]:
        n = self.n
        raw, rest, u, slope, U, J, p = self._state(theta)
        Ap = self.A @ p
        value = p @ Ap - 2 * self.b @ p + self.c
        value += prior * (float((self.W0 * J).sum()) - 2 * raw[:, :4].sum() + self.logdet0 - 4 * n)
        g = 2 * (Ap - self.b)
        S = self._adjoint(g, prior)
        SU = S @ U
        grad_links = slope * SU[:, self.rows, self.cols]
        grad_links[:, :4] -= 2 * prior
        jac_rest = self.Q * (2 * rest)[None, :] + self.L
        return float(value), np.concatenate([grad_links.reshape(-1), jac_rest.T @ g[10 * n:]])

    def _adjoint(self, g, prior: float) -> np.ndarray:
        """``S = G + G^T (n, 4, 4)``: ``G`` the objective's derivative with respect to each link's ``J`` at fixed
        ``g`` (the quadratic form's through the classical ten, and the divergence's)."""
        G = (g[: 10 * self.n].reshape(self.n, 10) @ self.C).reshape(self.n, 4, 4) + prior * self.W0
        return G + G.transpose(0, 2, 1)

    def hessian(self, theta, prior: float) -> np.ndarray:
        n = self.n
        raw, rest, u, slope, U, J, p = self._state(theta)
        g = 2 * (self.A @ p - self.b)
        S = self._adjoint(g, prior)
        curve = np.where(np.arange(10) < 4, u, 0.0)  # d2 u / d raw2
        # dJ/draw_k = slope_k (E_k U^T + U E_k^T); p's Jacobian, block by block
        D = np.einsum("kab,lcb->lkac", self.E, U)
        D = D + D.transpose(0, 1, 3, 2)
        jac = np.zeros((len(p), self.size))
        links = np.einsum("ef,lkf->lek", self.C, D.reshape(n, 10, 16)) * slope[:, None, :]
        for l in range(n):
            jac[10 * l: 10 * l + 10, 10 * l: 10 * l + 10] = links[l]
        jac[10 * n:, 10 * n:] = self.Q * (2 * rest)[None, :] + self.L
        H = jac.T @ (2 * self.A) @ jac
        # g's second-order part, <G, d2J/draw_k draw_m>:
        #   slope_k slope_m [b_k = b_m] S[a_k, a_m] + [k = m] curve_k (S U)[a_k, b_k]
        same = (self.cols[:, None] == self.cols[None, :]).astype(np.float64)
        SU = S @ U
        for l in range(n):
            block = np.outer(slope[l], slope[l]) * same * S[l][np.ix_(self.rows, self.rows)]
            block[np.diag_indices(10)] += curve[l] * SU[l][self.rows, self.cols]
            H[10 * l: 10 * l + 10, 10 * l: 10 * l + 10] += block
        H[10 * n:, 10 * n:] += np.diag(2 * self.Q.T @ g[10 * n:])
        return H
