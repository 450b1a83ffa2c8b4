"""Kinematics and inertia of a spatial serial arm as pure tensor functions (the grey box's geometry).

A serial arm of ``n`` hinge joints is a product of fixed transforms and joint rotations: moving body
``i`` has the pose ``T_i = T_{i-1} X_i Rot(a_i, q_i about the anchor r_i)`` (4 x 4 homogeneous, world
frame; ``X_i`` the fixed transform from the previous moving body, bodies welded between them folded
in). Each joint's world twist ``S_k`` (4 x 4: ``[[w^, r x w], [0, 0]]``, ``w`` the world axis, ``r`` a
point on it) gives the pose derivatives in closed form (product of exponentials):

    dT_i / dq_k = S_k T_i                         (k <= i, else 0)
    d2T_i / dq_m dq_k = S_min(m,k) S_max(m,k) T_i  (m, k <= i)

A rigid body's inertia is its pseudo-inertia ``J = [[Sigma, h], [h^T, m]]`` (4 x 4, in its own frame:
``Sigma = int x x^T dm``, ``h = m c``, ``m`` its mass); its kinetic energy is ``1/2 tr(dT J dT^T)`` and it
is physically consistent (positive mass, inertia satisfying the triangle inequality) exactly when
``J`` is positive definite. With ``J = U U^T`` (``U`` upper triangular: ``reverse_cholesky``) the
arm's mass matrix is ``M = F F^T + diag(armature)``, ``F[k, (i, x, y)] = (S_k T_i U_i)[x, y]`` over
the rows ``x < 3``: a factor with a closed-form derivative, what the structured solve needs.

The chain's constants are read from a robot description by MuJoCo (``read_chain``), never parsed by
hand; the tests compare everything here with MuJoCo's own mass matrix and bias forces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputError
from ..mechanics.euler_lagrange import cholesky


@dataclass
class SerialChain:
    """The fixed geometry and nominal inertia of a serial arm (float64 tensors, SI).

    ``X (n, 4, 4)``: each moving body's frame before its joint, in the previous moving body's frame
    (the first in the world); ``axis (n, 3)``, ``anchor (n, 3)``: joint axis and a point on it in the
    body's frame; ``qpos0 (n,)``: the joint's reference angle; ``J (n, 4, 4)``: pseudo-inertias in the
    body frames, welded bodies folded in; ``flange (4, 4)``: the payload body's frame in the last
    body's; ``armature``, ``damping (n,)``; ``gravity (3,)``; ``joint_names``."""

    X: torch.Tensor
    axis: torch.Tensor
    anchor: torch.Tensor
    qpos0: torch.Tensor
    J: torch.Tensor
    flange: torch.Tensor | None
    armature: torch.Tensor
    damping: torch.Tensor
    gravity: torch.Tensor
    joint_names: tuple[str, ...]

    @property
    def dof(self) -> int:
        return int(self.axis.shape[0])


def _quat_matrix(quat) -> np.ndarray:
    w, x, y, z = np.asarray(quat, dtype=np.float64) / np.linalg.norm(quat)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _transform(pos, quat) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = _quat_matrix(quat), pos
    return out


def pseudo_inertia(mass: float, com, inertia_com) -> np.ndarray:
    """``J (4, 4)`` of a body: mass (kg), centre of mass ``com (3,)`` and inertia about it ``(3, 3)`` in
    its frame."""
    c = np.asarray(com, dtype=np.float64)
    I = np.asarray(inertia_com, dtype=np.float64)
    sigma = 0.5 * np.trace(I) * np.eye(3) - I + mass * np.outer(c, c)
    J = np.zeros((4, 4))
    J[:3, :3], J[:3, 3], J[3, :3], J[3, 3] = sigma, mass * c, mass * c, mass
    return J


def payload_pseudo_inertia(payload: torch.Tensor) -> torch.Tensor:
    """``J (B, 4, 4)`` of payloads ``(B, 4)`` (point masses) or ``(B, 10)`` (with inertia about the centre of
    mass), in the payload's frame; a negative mass is taken as zero."""
    m = payload[:, 0].clamp_min(0)
    c = payload[:, 1:4]
    sigma = m[:, None, None] * c[:, :, None] * c[:, None, :]
    if payload.shape[1] == 10:
        ixx, iyy, izz, ixy, ixz, iyz = payload[:, 4:].unbind(-1)
        I = torch.stack([torch.stack([ixx, ixy, ixz], -1), torch.stack([ixy, iyy, iyz], -1),
                         torch.stack([ixz, iyz, izz], -1)], -2)
        tr = (ixx + iyy + izz)[:, None, None]
        sigma = sigma + 0.5 * tr * torch.eye(3, dtype=payload.dtype, device=payload.device) - I
    top = torch.cat([sigma, (m[:, None] * c)[..., None]], -1)
    bottom = torch.cat([m[:, None] * c, m[:, None]], -1)[:, None]
    return torch.cat([top, bottom], -2)


def payload_at_flange(flange: torch.Tensor, payload: torch.Tensor) -> torch.Tensor:
    """``J (B, 4, 4)``: payloads ``(B, 4 or 10)`` (``payload_pseudo_inertia``) in the last body's frame, the
    flange's pose ``flange (4, 4)`` in it."""
    Xf = flange.to(payload.dtype)
    return Xf @ payload_pseudo_inertia(payload) @ Xf.T


def read_chain(model, payload_body: str | None = "payload") -> SerialChain:
    """The ``SerialChain`` of a compiled MuJoCo model (``mujoco.MjModel``): its hinge joints in tree
    order; bodies without joints welded to their moving ancestor (their inertia folded into it; those
    welded to the world do not move and are left out). ``InputError`` for a branched tree or another
    joint type."""
    import mujoco

    names = lambda kind, i: mujoco.mj_id2name(model, kind, i)  # noqa: E731
    moving, X, axis, anchor, qpos0, J = [], [], [], [], [], []
    frame_of = {0: (-1, np.eye(4))}  # body -> (index of its moving ancestor or -1 for the world, pose in it)
    flange = None
    for b in range(1, model.nbody):
        parent = int(model.body_parentid[b])
        owner, pose = frame_of[parent]
        local = pose @ _transform(model.body_pos[b], model.body_quat[b])
        nj = int(model.body_jntnum[b])
        if nj > 1:
            raise InputError(f"robot description: body '{names(mujoco.mjtObj.mjOBJ_BODY, b)}' has {nj} joints; "
                             "a serial arm has one hinge per moving body")
        if nj == 1:
            j = int(model.body_jntadr[b])
            if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
                raise InputError(f"robot description: joint '{names(mujoco.mjtObj.mjOBJ_JOINT, j)}' is not a hinge "
                                 "(only revolute joints are supported)")
            if owner != len(moving) - 1:
                raise InputError(f"robot description: body '{names(mujoco.mjtObj.mjOBJ_BODY, b)}' branches the "
                                 "kinematic tree (a serial arm is one chain of moving bodies)")
            moving.append(b)
            X.append(local)
            axis.append(np.array(model.jnt_axis[j]))
            anchor.append(np.array(model.jnt_pos[j]))
            qpos0.append(float(model.qpos0[model.jnt_qposadr[j]]))
            J.append(np.zeros((4, 4)))
            owner, local = len(moving) - 1, np.eye(4)
        frame_of[b] = (owner, local)
        name = names(mujoco.mjtObj.mjOBJ_BODY, b)
        if payload_body is not None and name == payload_body:
            flange = local  # the payload's frame in its moving body's; its (run-time) inertia is a parameter
            continue
        if owner >= 0:
            R = _quat_matrix(model.body_iquat[b])
            Jb = pseudo_inertia(float(model.body_mass[b]), model.body_ipos[b], R @ np.diag(model.body_inertia[b]) @ R.T)
            J[owner] = J[owner] + local @ Jb @ local.T
    if not moving:
        raise InputError("robot description: no hinge joint")
    if (flange is not None
            and frame_of[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, payload_body)][0] != len(moving) - 1):
        raise InputError("robot description: the payload body must hang from the last moving body")
    dofs = [int(model.jnt_dofadr[model.body_jntadr[b]]) for b in moving]
    t = lambda a: torch.tensor(np.asarray(a), dtype=torch.float64)  # noqa: E731
    return SerialChain(X=t(X), axis=t(axis), anchor=t(anchor), qpos0=t(qpos0), J=t(J),
                       flange=None if flange is None else t(flange), armature=t(model.dof_armature[dofs]),
                       damping=t(model.dof_damping[dofs]), gravity=t(model.opt.gravity),
                       joint_names=tuple(names(mujoco.mjtObj.mjOBJ_JOINT, int(model.body_jntadr[b])) for b in moving))


def vee(A: torch.Tensor) -> torch.Tensor:
    """``(..., 3, 3) -> (..., 3)``: the vector of a cross-product matrix (inverse of ``_hat``)."""
    return torch.stack([A[..., 2, 1], A[..., 0, 2], A[..., 1, 0]], -1)


def mass_properties(J: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(mass (...), com (..., 3), inertia about the centre of mass (..., 3, 3))`` of pseudo-inertias
    ``J (..., 4, 4)`` (the inverse of ``pseudo_inertia``)."""
    mass = J[..., 3, 3]
    com = J[..., :3, 3] / mass[..., None]
    sigma_c = J[..., :3, :3] - mass[..., None, None] * com[..., :, None] * com[..., None, :]
    eye = torch.eye(3, dtype=J.dtype, device=J.device)
    return mass, com, sigma_c.diagonal(dim1=-2, dim2=-1).sum(-1)[..., None, None] * eye - sigma_c


def _hat(w: torch.Tensor) -> torch.Tensor:
    """``(..., 3) -> (..., 3, 3)``: the cross-product matrix."""
    z = torch.zeros_like(w[..., 0])
    x, y, zz = w.unbind(-1)
    return torch.stack([torch.stack([z, -zz, y], -1), torch.stack([zz, z, -x], -1), torch.stack([-y, x, z], -1)], -2)


def poses_and_twists(chain: SerialChain, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``T (B, n, 4, 4)``: each moving body's pose, and ``S (B, n, 4, 4)``: each joint's world twist, at
    joint angles ``q (B, n)``."""
    dtype, B = q.dtype, q.shape[0]
    X, axis, anchor = (x.to(dtype=dtype, device=q.device) for x in (chain.X, chain.axis, chain.anchor))
    K = _hat(axis)  # (n, 3, 3)
    theta = q - chain.qpos0.to(dtype=dtype, device=q.device)
    s, c = torch.sin(theta)[..., None, None], torch.cos(theta)[..., None, None]
    R = torch.eye(3, dtype=dtype, device=q.device) + s * K + (1 - c) * (K @ K)  # (B, n, 3, 3) Rodrigues
    bottom = torch.zeros(4, dtype=dtype, device=q.device)
    bottom[3] = 1.0
    t = anchor - (R @ anchor[..., None])[..., 0]  # about the anchor: r - R r
    Rj = torch.cat([torch.cat([R, t[..., None]], -1), bottom.expand(*R.shape[:-2], 1, 4)], -2)  # (B, n, 4, 4)
    zero_row = torch.zeros(B, 1, 4, dtype=dtype, device=q.device)
    T, S = [], []
    prev = None
    for i in range(chain.dof):
        pre = X[i].expand(B, 4, 4) if prev is None else prev @ X[i]
        w = pre[:, :3, :3] @ axis[i]  # world axis (B, 3)
        o = pre[:, :3, :3] @ anchor[i] + pre[:, :3, 3]  # world anchor
        S.append(torch.cat([torch.cat([_hat(w), torch.linalg.cross(o, w)[..., None]], -1), zero_row], -2))
        prev = pre @ Rj[:, i]
        T.append(prev)
    return torch.stack(T, 1), torch.stack(S, 1)


def reverse_cholesky(J: torch.Tensor) -> torch.Tensor:
    """``U`` upper triangular with a positive diagonal and ``U U^T = J`` (``J`` positive definite)."""
    flip = lambda a: a.flip(-1).flip(-2)  # noqa: E731
    return flip(torch.linalg.cholesky(flip(J)))


_UPPER = torch.triu_indices(4, 4, 1)  # the six entries above the diagonal of a pseudo-inertia's factor


def log_cholesky(J: torch.Tensor) -> torch.Tensor:
    """``raw (n, 10)`` of pseudo-inertias ``J (n, 4, 4)``: the logs of the diagonal of ``U``
    (``reverse_cholesky``), then its six entries above the diagonal (the log-Cholesky parameters: every
    value is a physically consistent body)."""
    U = reverse_cholesky(J)
    return torch.cat([U.diagonal(dim1=-2, dim2=-1).log(), U[:, _UPPER[0], _UPPER[1]]], -1)


def log_cholesky_factor(raw: torch.Tensor) -> torch.Tensor:
    """``U (n, 4, 4)`` of the log-Cholesky parameters ``raw (n, 10)`` (``log_cholesky``): ``J = U U^T``."""
    rows = torch.arange(raw.shape[0], device=raw.device)[:, None]
    upper = _UPPER.to(raw.device)
    return torch.diag_embed(raw[:, :4].exp()).index_put((rows, upper[0], upper[1]), raw[:, 4:])


def _blocks(n: int, device) -> tuple[torch.Tensor, ...]:
    """Index lists of the nonzero blocks: pairs ``(k, i)`` with ``k <= i`` and triples ``(k, m, i)`` with
    ``k < m <= i``."""
    pk, pi = torch.triu_indices(n, n, device=device)
    trip = [(k, m, i) for i in range(n) for m in range(i + 1) for k in range(m)]
    tk, tm, ti = torch.tensor(trip, device=device, dtype=torch.long).reshape(-1, 3).T
    return pk, pi, tk, tm, ti


def spatial_inertia(J: torch.Tensor) -> torch.Tensor:
    """``G (..., 6, 6)`` about the body origin in (angular, linear) order from pseudo-inertias ``(..., 4, 4)``:
    ``[[I_o, m c^], [-m c^, m 1]]`` (``I_o = tr(Sigma) 1 - Sigma``, ``c^`` the cross-product matrix of the
    centre of mass)."""
    sigma, h, m = J[..., :3, :3], J[..., :3, 3], J[..., 3, 3]
    eye = torch.eye(3, dtype=J.dtype, device=J.device)
    inertia = sigma.diagonal(dim1=-2, dim2=-1).sum(-1)[..., None, None] * eye - sigma
    hh = _hat(h)
    return torch.cat([torch.cat([inertia, hh], -1), torch.cat([-hh, m[..., None, None] * eye], -1)], -2)


def _bracket(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """The Lie bracket of twists ``(w, v)``: ``(w1 x w2, w1 x v2 - w2 x v1)``."""
    w1, v1, w2, v2 = a[..., :3], a[..., 3:], b[..., :3], b[..., 3:]
    cross = torch.linalg.cross
    return torch.cat([cross(w1, w2), cross(w1, v2) - cross(w2, v1)], -1)


def inertia_factor(J: torch.Tensor) -> torch.Tensor:
    """``L (..., 6, 6)``, lower triangular with ``L L^T = G`` the spatial inertia of pseudo-inertias ``J``
    (``mechanics.euler_lagrange.cholesky``: entry by entry where a program is traced for export)."""
    return cholesky(spatial_inertia(J))


def factor(T: torch.Tensor, S: torch.Tensor, L: torch.Tensor, tangents: bool = True):
    """The mass-matrix factor of the bodies, ``F (B, n, 6 n)`` with ``F F^T = sum_i Jb_i^T G_i Jb_i``
    (``Jb_i``: body i's Jacobian in its own frame, columns ``xi_k = Ad(T_i^-1) S_k`` for ``k <= i``; ``G_i =
    L_i L_i^T`` its spatial inertia, ``L (B or 1, n, 6, 6)`` from ``inertia_factor``: ``F[k, i-block] =
    xi_k^T L_i``), and with ``tangents`` ``dF/dq_m (n, B, n, 6 n)`` from ``d xi_k / dq_m = [xi_k, xi_m]``
    (``k < m <= i``, else 0). Only the nonzero blocks are computed and scattered into place."""
    B, n = T.shape[:2]
    pk, pi, tk, tm, ti = _blocks(n, T.device)
    L = L.expand(B, -1, -1, -1)  # (B, n, 6, 6)
    R, p = T[..., :3, :3], T[..., :3, 3]  # (B, n, ...)
    w, v = S[..., :3, :3], S[..., :3, 3]
    w = vee(w)  # the world axes (B, n, 3)
    # xi[:, pair]: joint k's twist in body i's frame (k <= i)
    Rt = R[:, pi].mT
    wk = w[:, pk]
    xi = torch.cat([(Rt @ wk[..., None])[..., 0],
                    (Rt @ (v[:, pk] + torch.linalg.cross(wk, p[:, pi]))[..., None])[..., 0]], -1)  # (B, P, 6)
    F = T.new_zeros(B, n, n, 6)
    F[:, pk, pi] = (xi[..., None, :] @ L[:, pi])[..., 0, :]
    F = F.reshape(B, n, n * 6)
    if not tangents:
        return F, None
    pair = torch.full((n, n), -1, dtype=torch.long, device=T.device)
    pair[pk, pi] = torch.arange(len(pk), device=T.device)
    d = _bracket(xi[:, pair[tk, ti]], xi[:, pair[tm, ti]])  # (B, t, 6)
    dF = T.new_zeros(n, B, n, n, 6)
    dF[tm, :, tk, ti] = (d[..., None, :] @ L[:, ti])[..., 0, :].transpose(0, 1)
    return F, dF.reshape(n, B, n, n * 6)


def gravity_potential(T: torch.Tensor, S: torch.Tensor, J: torch.Tensor, gravity: torch.Tensor, grad: bool = True):
    """``V = -sum_i m_i g . c_i`` ``(B,)`` (``g`` the gravity vector, ``c_i`` body i's centre of mass in the
    world: ``T_i J_i[:, 3]``) and with ``grad`` ``dV/dq (B, n)``."""
    moment = (T @ J[..., :, 3, None])[..., 0]  # (B, n, 4): (m_i c_i in the world, m_i)
    V = -(moment[..., :3] @ gravity.to(T.dtype)).sum(-1)
    if not grad:
        return V, None
    n = T.shape[1]
    mask = torch.ones(n, n, dtype=T.dtype, device=T.device).triu()  # [k, i]: k <= i
    # dV/dq_k = -sum_{i >= k} g . (S_k T_i J_i[:, 3])[:3]
    v = torch.einsum("bkxy,biy->bkix", S[..., :3, :], moment) @ gravity.to(T.dtype)  # (B, k, i)
    return V, -(v * mask).sum(-1)


def mass_matrix(chain: SerialChain, q: torch.Tensor, J: torch.Tensor | None = None,
                armature: torch.Tensor | None = None) -> torch.Tensor:
    """``M (B, n, n)`` at ``q (B, n)`` with pseudo-inertias ``J`` (default the description's) and
    armature (default the description's)."""
    T, S = poses_and_twists(chain, q)
    J = chain.J.to(q.dtype) if J is None else J
    F, _ = factor(T, S, inertia_factor(J), tangents=False)
    a = chain.armature.to(q.dtype) if armature is None else armature
    return F @ F.mT + torch.diag_embed(a.expand(q.shape[0], -1))
