"""The input features of every model: the angles as ``sin``/``cos`` (their own, and the scene's angle
combinations), the other coordinates as they are.

``phi(q) = [sin G q, cos G q, q_lin]`` ``(B, F)`` with ``G`` the feature angles' rows over the
coordinates (each angle coordinate, then the scene's ``angle_combinations``, e.g. the absolute angle
``q1 + q2`` of a link in a chain measured in joint angles) and ``q_lin`` the non-angle coordinates.
``AngleFeatures`` computes them, their tangents ``d phi / d q_k`` (forward mode, for the structured
models' hand-carried tangents) and the pull-back of a feature gradient (reverse mode).
``lnn_torch.networks.reference.features`` is the plain formula the tests compare with.
"""

from __future__ import annotations

import torch
from torch import nn

from ..errors import InputError
from ..mechanics.angles import wrap_angle


class AngleFeatures(nn.Module):
    """The features of a scene's coordinates (normalised: angles stay raw). Holds no state of its own
    that a checkpoint keeps (its buffers are constants of the scene).

    Args:
        dof: the number of coordinates.
        angle_mask: which coordinates are angles.
        angle_combinations: further feature angles, rows of ``dof`` coefficients over the angle
            coordinates (None: none).
    """

    def __init__(self, dof: int, angle_mask, angle_combinations=None) -> None:
        super().__init__()
        angles = [i for i, a in enumerate(angle_mask) if a]
        linear = [i for i, a in enumerate(angle_mask) if not a]
        self.register_buffer("angle_idx", torch.tensor(angles, dtype=torch.long), persistent=False)
        self.register_buffer("linear_idx", torch.tensor(linear, dtype=torch.long), persistent=False)
        # the feature angles G q (rows: each angle coordinate, then the angle combinations) and
        # d(feature)/dq_k selectors: sel_angle = G^T (dof, n_feature_angles), sel_linear (dof, n_linear)
        G = torch.eye(dof)[angles]
        if angle_combinations:
            C = torch.tensor(angle_combinations, dtype=torch.float32)
            if C.shape[1] != dof or (C[:, linear] != 0).any():
                raise InputError(f"angle_combinations must be rows of {dof} coefficients over angle coordinates only")
            G = torch.cat([G, C])
        # a combination of integer coefficients (e.g. q1 - q2) takes its sin/cos from the coordinates' own
        # by angle addition: exact to rounding at any angle, where the sum itself is rounded (in float32
        # at 1e4 rad, by ~1e-3 rad). Each row: (angle column, +1/-1) once per unit of its coefficients.
        self.combo_terms = _integer_terms(G[len(angles):], angles) if angle_combinations else None
        self.register_buffer("sel_angle", G.T.contiguous(), persistent=False)
        self.register_buffer("sel_linear", torch.eye(dof)[:, linear], persistent=False)
        self.num_features = 2 * G.shape[0] + len(linear)
        self.all_angles = not linear
        self.combined_angles = bool(angle_combinations)
        self.plain_angles = self.all_angles and not angle_combinations  # the features read q itself

    def angles(self, q_norm: torch.Tensor) -> torch.Tensor:
        """The feature angles ``G q`` ``(B, n_feature_angles)``."""
        if self.plain_angles:
            return q_norm
        if self.combined_angles:
            return q_norm @ self.sel_angle.to(q_norm.dtype)
        return q_norm[..., self.angle_idx]

    def sin_cos(self, q_norm: torch.Tensor):
        """``sin`` and ``cos`` of the feature angles ``(B, n_feature_angles)`` each: of the angle coordinates,
        then of the combinations, from the coordinates' own by angle addition where the coefficients are
        integers (``combo_terms``), else of the combined angle."""
        if self.combo_terms is None:
            qa = self.angles(q_norm)
        else:
            qa = q_norm if self.all_angles else q_norm[..., self.angle_idx]
        if qa.device.type != "cpu":
            qa = wrap_angle(qa)
        s, c = torch.sin(qa), torch.cos(qa)
        if self.combo_terms is None:
            return s, c

        def unit(i, sign):  # sin and cos of +-(angle column i)
            return (s[..., i:i + 1] if sign > 0 else -s[..., i:i + 1]), c[..., i:i + 1]

        ss, cs = [s], [c]
        for first, *rest in self.combo_terms:
            sr, cr = unit(*first)
            for term in rest:  # sin(a + b) = sa cb + ca sb, cos(a + b) = ca cb - sa sb
                si, ci = unit(*term)
                sr, cr = sr * ci + cr * si, cr * ci - sr * si
            ss.append(sr)
            cs.append(cr)
        return torch.cat(ss, -1), torch.cat(cs, -1)

    def compute(self, q_norm: torch.Tensor, tangents: bool = False):
        """``(phi (B, F), dphi (dof, B, F) or None, (sin, cos))``: the features, their tangents ``d phi /
        d q_k`` if asked, and ``sin``/``cos`` of the feature angles (reused by ``vjp``).

        On the CPU, sin/cos read the raw angles: torch's CPU kernels reduce large arguments exactly
        (``tests/test_stability.py::test_angle_features_are_exact_at_1e4_rad``). On other devices the
        angles are first wrapped to [-pi, pi) in float64 (``lnn_torch.mechanics.angles.wrap_angle``), in case a
        device kernel reduces large arguments inexactly. The dynamics and rollouts never see wrapped
        angles."""
        s, c = self.sin_cos(q_norm)
        phi = torch.cat([s, c] if self.all_angles else [s, c, q_norm[..., self.linear_idx]], -1)
        if not tangents:
            return phi, None, (s, c)
        sa = self.sel_angle.to(q_norm.dtype)[:, None, :]  # (dof, 1, n_angles)
        parts = [sa * c, sa * -s]
        if not self.all_angles:
            parts.append(self.sel_linear.to(q_norm.dtype)[:, None, :].expand(-1, q_norm.shape[0], -1))
        return phi, torch.cat(parts, -1), (s, c)  # dphi: (dof, B, F)

    def vjp(self, q_norm: torch.Tensor, g_phi: torch.Tensor, sin_cos=None) -> torch.Tensor:
        """Pull a feature gradient ``(B, F)`` back to the coordinates ``(B, dof)``."""
        na = self.sel_angle.shape[1]
        if sin_cos is None:
            sin_cos = self.sin_cos(q_norm)
        s, c = sin_cos
        g_angle = g_phi[..., :na] * c - g_phi[..., na : 2 * na] * s
        if self.plain_angles:
            return g_angle
        out = g_angle @ self.sel_angle.to(g_phi.dtype).T
        if not self.all_angles:
            out = out + g_phi[..., 2 * na :] @ self.sel_linear.to(g_phi.dtype).T
        return out


def _integer_terms(rows: torch.Tensor, angles: list[int]):
    """Each combination row's coefficients over the angle coordinates as a list of ``(angle column, +1 or
    -1)``, one per unit of each coefficient (``[1, -1]`` -> ``[(0, 1), (1, -1)]``); None where a
    coefficient is not an integer (those combinations are formed as angles)."""
    out = []
    for row in rows.tolist():
        coeffs = [row[i] for i in angles]
        if any(x != round(x) for x in coeffs) or not any(coeffs):
            return None
        out.append([(j, 1 if x > 0 else -1) for j, x in enumerate(coeffs) for _ in range(abs(round(x)))])
    return out
