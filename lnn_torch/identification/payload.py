"""A payload's inertial parameters from an arm's recordings by classical least squares.

* ``payload_least_squares``: per observation of the simulated robot-arm scene, on its payload regressor
  (``RobotArm.linear_regressor``: the joint torques less the arm's own, linear in the payload's ten
  inertial parameters), solved linearly, and as a point mass (four unknowns, Gauss-Newton).
* ``identify_tools``: named tools (``Tool``) that recordings carry, with what is known of each (mass,
  centre of mass, inertia, all or nothing), the rest identified jointly across every recording that
  carries the tool: either together with the arm's base parameters and friction (the tool's columns
  beside the arm's; recordings without the tool tell the two apart) or against a given arm model, with
  cluster-robust standard errors and 95 % intervals per identified entry (``ToolFit``).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import InputError
from ..robots.mujoco_arm import MujocoArm
from ..robots.tools import ROW, UNITS, Tool
from ..systems import get_system
from .classical_arm import Z95


def payload_least_squares(q, qd, qdd, tau, edge: int = 0, system=None) -> dict:
    """Per observation, on the engine's payload regressor ``Y`` (``tau - tau_arm = Y pi``,
    ``RobotArm.linear_regressor``): the classical
    linear least squares of the ten inertial parameters (``m = pi_0``, ``c = pi_1:4 / m``), and the
    point-mass fit (the payloads are point masses: ``pi(m, c)``, four unknowns, Gauss-Newton from the
    linear estimate). ``q, qd, qdd, tau``: per observation ``(T, n)`` arrays (SI); ``edge``: points left
    out at each end (a smoothing's least reliable); ``system``: the robot-arm scene (default: the shipped
    arm). Returns ``{"linear": (mass (N,), com (N, 3)), "point mass": (mass, com)}`` in kg and m (flange
    frame)."""
    system = get_system("robot_arm") if system is None else system
    out = {"linear": ([], []), "point mass": ([], [])}
    for i in range(len(q)):
        sl = slice(edge, len(q[i]) - edge)  # the smoothing's ends are least reliable
        Y, b, _ = system.linear_regressor(q[i][sl], qd[i][sl], qdd[i][sl], tau[i][sl])  # the scene's classical form
        pi = torch.linalg.lstsq(Y, b[:, None]).solution[:, 0]
        out["linear"][0].append(float(pi[0]))
        out["linear"][1].append((pi[1:4] / pi[0]).numpy())
        theta = torch.cat([pi[:1], pi[1:4] / pi[0]])

        def residual(th, Y=Y, b=b):
            return Y @ MujocoArm.inertial_parameters(th) - b

        for _ in range(20):
            r = residual(theta)
            Jr = torch.func.jacrev(residual)(theta)
            step = torch.linalg.lstsq(Jr, -r[:, None]).solution[:, 0]
            theta = theta + step
            if step.abs().max() < 1e-12:
                break
        out["point mass"][0].append(float(theta[0]))
        out["point mass"][1].append(theta[1:4].numpy())
    return {k: (np.array(m), np.array(c)) for k, (m, c) in out.items()}


# ---------------------------------------------------------------- tools whose parameters are (partly) unknown
STIFF = 1e-9  # a tool's columns whose scaled singular value falls below this share cannot be told apart


class ToolsUndetermined(InputError):
    """The recordings cannot tell a tool's unknown parameters from the arm's own (e.g. every recording
    carries it and the arm is identified with it)."""


@dataclass
class ToolFit:
    """Identified tools: per tool its row (``values``), the standard errors and 95 % intervals of the
    identified entries (cluster-robust over ``block``-sample blocks), what it was identified against
    (``against``: the arm identified with it by least squares, or a given arm model), the recordings used,
    and the fit's condition number and residual RMS per joint (N m)."""

    tools: dict
    values: dict
    std: dict
    against: str
    used: dict
    condition: float
    residual_rms: list
    block: int
    arm: object = None  # the arm's least-squares model where identified jointly (``classical_arm.ArmModel``)
    notes: list = field(default_factory=list)  # what was changed after the fit (an inertia made physical)

    def report(self) -> dict:
        out = {}
        for name, tool in self.tools.items():
            entries = {}
            for k in range(tool.width):
                value = float(self.values[name][k])
                if k in tool.known:
                    entries[ROW[k]] = {"value": value, "unit": UNITS[k], "known": True}
                else:
                    s = float(self.std[name][k])
                    entries[ROW[k]] = {"value": value, "unit": UNITS[k], "std": s,
                                       "interval95": [value - Z95 * s, value + Z95 * s]}
            out[name] = {"declared": tool.describe(), "parameters": entries, "recordings": self.used[name]}
        return {"tools": out, "against": self.against, "condition_number": self.condition,
                "residual_rms": self.residual_rms, "block_samples": self.block, "notes": list(self.notes)}


def physical_inertia(row: np.ndarray) -> tuple[np.ndarray, float]:
    """A tool's row ``(mass, cx, cy, cz, Ixx, Iyy, Izz, Ixy, Ixz, Iyz)`` with its inertia about the centre of
    mass made that of a rigid body: the second moment of its mass ``S = tr(I)/2 - I`` must be positive
    semidefinite (the inertia's eigenvalues non-negative and each at most the sum of the others); its
    negative eigenvalues are set to zero (the nearest such ``S``), mass and centre of mass kept. Returns the
    row and the most negative eigenvalue of ``S`` before (kg m^2; >= 0: the row unchanged)."""
    row = np.asarray(row, dtype=np.float64).copy()
    xx, yy, zz, xy, xz, yz = row[4:10]
    inertia = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    second = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    w, V = np.linalg.eigh(second)
    if w.min() >= 0:
        return row, float(w.min())
    second = (V * np.clip(w, 0, None)) @ V.T
    inertia = np.trace(second) * np.eye(3) - second
    row[4:10] = [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2]]
    return row, float(w.min())


def _solve(A: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Least squares ``A x = b`` with ``A``'s columns scaled to unit norm first (a tool's inertia columns are
    orders of magnitude below the arm's: unscaled, a rank-revealing solver would drop them)."""
    norms = A.norm(dim=0)
    norms = torch.where(norms > 0, norms, torch.ones_like(norms))
    return torch.linalg.lstsq(A / norms, b[:, None], driver="gelsd").solution[:, 0] / norms


def _start(pi: torch.Tensor, tool: Tool) -> torch.Tensor:
    """The unknown entries from a free linear estimate of the payload's ten at the flange (``payload_ten``'s
    layout), the known ones kept."""
    known = tool.known
    m = known.get(0, float(pi[9]))
    m = m if m > 1e-3 else 1e-3  # a start needs a positive mass
    c = torch.tensor([known.get(1 + k, float(pi[6 + k]) / m) for k in range(3)], dtype=pi.dtype)
    row = [m, *c.tolist()]
    if tool.width == 10:
        I_o = torch.stack([torch.stack([pi[0], pi[3], pi[4]]), torch.stack([pi[3], pi[1], pi[5]]),
                           torch.stack([pi[4], pi[5], pi[2]])])
        I_c = I_o - m * (c.dot(c) * torch.eye(3, dtype=pi.dtype) - torch.outer(c, c))
        free = [I_c[0, 0], I_c[1, 1], I_c[2, 2], I_c[0, 1], I_c[0, 2], I_c[1, 2]]
        row += [known.get(4 + k, float(free[k])) for k in range(6)]
    return torch.tensor([row[k] for k in tool.unknown], dtype=pi.dtype)


def identify_tools(chain, recordings, tools: dict, *, arm=None, drive="viscous+coulomb+offset", block: int = 1,
                   against: str | None = None, max_iterations: int = 50, friction: bool = False) -> ToolFit:
    """The unknown entries of ``tools`` (``{name: Tool}``) from ``recordings``: a list of ``(name, q, qd,
    qdd, tau, payload)`` per recording (``(T, n)`` arrays, SI; ``payload`` the tool's name, or a known row
    ``(4 or 10,)``, or None), by least squares on the joint torques.

    ``arm`` None: jointly with the arm -- its base parameters and ``drive``'s linear friction
    (``classical_arm``) as further columns, so the tools must be told apart from the arm's last link by
    recordings without them (or with others); else the arm's torques ``arm(q, qd, qdd) -> (T, n)``
    (a model's without payload) are taken as known; with ``friction``, less ``drive``'s linear friction per
    joint fitted beside the tools (an arm without friction: the description as written). Each tool's torques
    are its rigid body at the flange, linear in its ten (``robots.regressor.payload_regressor``) and nonlinear
    in the row (mass, centre of mass, inertia about it): Gauss-Newton from the free linear estimate, the linear
    coefficients solved with each step. Raises ``ToolsUndetermined`` where the data cannot determine a tool's
    unknown entries."""
    from ..mechanics.friction import DriveModel
    from ..robots.regressor import base_parameters, parameter_names, payload_regressor, payload_ten, payload_torque
    from .classical_arm import (
        ArmModel,
        _base_names,
        _friction_columns,
        _regressor,
        _viscous_of,
        coefficient_covariance,
        linear_friction,
        linear_friction_names,
    )

    drive = DriveModel.of(drive)
    if "sigmoid" in drive.forms:
        raise InputError("tool identification: the drive model must be linear in its coefficients (no sigmoid)")
    pending = {name: tool for name, tool in tools.items() if tool.unknown}
    carried = {name: [r[0] for r in recordings if isinstance(r[5], str) and r[5] == name] for name in pending}
    for name, used in carried.items():
        if not used:
            raise InputError(f"tool identification: no recording carries tool {name!r}")
    rows_Y, rows_target, rows_F, Yp, groups, ends = [], [], [], {name: [] for name in pending}, [], 0
    n = chain.dof
    extra = [f for f in drive.linear_forms if f != "viscous"]  # the friction columns beside the regressor's
    # the friction columns each recording adds: beside the arm's regressor, or alone beside a given arm's torques
    # (viscous too: no regressor there), or none
    columns = extra if arm is None else list(drive.linear_forms) if friction else []
    for rec, q, qd, qdd, tau, payload in recordings:
        q, qd, qdd, tau = (torch.as_tensor(np.ascontiguousarray(x), dtype=torch.float64) for x in (q, qd, qdd, tau))
        if q.ndim != 2 or q.shape[1] != n or not all(x.shape == q.shape for x in (qd, qdd, tau)):
            raise InputError(f"tool identification: recording {rec!r} needs q, qd, qdd, tau of shape (T, {n})")
        if not all(bool(torch.isfinite(x).all()) for x in (q, qd, qdd, tau)):
            raise InputError(f"tool identification: recording {rec!r} has NaN or Inf")
        T = q.shape[0]
        Y = _regressor(chain, q, qd, qdd, drive)  # (T, n, 12 n)
        target = tau if arm is None else tau - torch.as_tensor(arm(q, qd, qdd), dtype=torch.float64)
        if isinstance(payload, str):
            if payload not in tools:
                raise InputError(f"tool identification: recording {rec!r} carries tool {payload!r}, not declared")
            if payload not in pending:
                target = target - payload_torque(chain, q, qd, qdd, tools[payload].row(q.new_zeros(0))[None]
                                                 .expand(T, -1))
        elif payload is not None and len(payload) and np.any(np.asarray(payload) != 0):
            target = target - payload_torque(chain, q, qd, qdd, torch.as_tensor(payload)[None].expand(T, -1))
        last = payload_regressor(chain, q, qd, qdd, Y=Y)  # (T, n, 10): the payload's ten at the flange
        for name in pending:
            Yp[name].append(last if isinstance(payload, str) and payload == name else torch.zeros_like(last))
        rows_Y.append(Y)
        rows_target.append(target)
        rows_F.append(_friction_columns(qd, drive, columns) if columns else q.new_zeros(T, n, 0))
        groups.append(ends + (torch.arange(T) // max(int(block), 1)).repeat_interleave(n))
        ends = int(groups[-1].max()) + 1
    target = torch.cat(rows_target).reshape(-1)
    rows = target.shape[0]
    if arm is None:
        Yall = torch.cat(rows_Y).reshape(rows, -1)
        base = base_parameters(Yall)
        A_lin = torch.cat([Yall[:, torch.as_tensor(base["independent"])], torch.cat(rows_F).reshape(rows, -1)], 1)
    else:  # a given arm: the drive's friction columns beside its torques where asked (``columns``), else none
        base, A_lin = None, torch.cat(rows_F).reshape(rows, -1)
    Yp = {name: torch.cat(v).reshape(rows, 10) for name, v in Yp.items()}
    names = list(pending)

    # the free linear estimate of every tool's ten, then Gauss-Newton on the unknown entries
    free = _solve(torch.cat([A_lin, *Yp.values()], 1), target)
    theta = {name: _start(free[A_lin.shape[1] + 10 * i: A_lin.shape[1] + 10 * (i + 1)], pending[name])
             for i, name in enumerate(names)}

    def ten(name, th):
        return payload_ten(pending[name].row(th)[None])[0]

    def residual(theta):
        """The torques less every tool's at ``theta`` (the arm's columns still to solve)."""
        return target - sum((Yp[name] @ ten(name, theta[name]) for name in names), torch.zeros_like(target))

    def jacobian(theta):
        """The arm's columns and each tool's ``Y_p d ten / d theta``."""
        return torch.cat([A_lin, *(Yp[name] @ torch.func.jacfwd(lambda th, name=name: ten(name, th))(theta[name])
                                   for name in names)], 1)

    def cost(theta):
        r = residual(theta)
        x = _solve(A_lin, r) if A_lin.shape[1] else r.new_zeros(0)
        return float((r - A_lin @ x).pow(2).sum())

    current = cost(theta)
    for _ in range(max_iterations if names else 0):
        step = _solve(jacobian(theta), residual(theta))[A_lin.shape[1]:]
        size = 1.0
        while True:
            trial, k0 = {}, 0
            for name in names:
                m = len(pending[name].unknown)
                trial[name] = theta[name] + size * step[k0: k0 + m]
                k0 += m
            value = cost(trial)
            if value <= current or size < 1e-4:
                break
            size *= 0.5
        if value > current:  # no step lowers the cost: converged to round-off
            break
        theta, moved, current = trial, float((size * step).abs().max()), value
        if moved < 1e-13:
            break
    r, A = residual(theta), jacobian(theta)
    x = _solve(A_lin, r) if A_lin.shape[1] else r.new_zeros(0)
    r = r - A_lin @ x  # the final residual
    norms = A.norm(dim=0).clamp_min(1e-300)
    s = torch.linalg.svdvals(A / norms)
    condition = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    if names and (s[-1] < STIFF * s[0] or not bool(torch.isfinite(s).all())):
        raise ToolsUndetermined(
            f"tool identification: the recordings cannot tell tool(s) {', '.join(repr(t) for t in names)} from the "
            "arm's own parameters (condition number " + f"{condition:.3g}): "
            + ("add recordings without the tool (or with a known one), or identify it against a trained model "
               "(lnn-torch identify CKPT DATA)" if arm is None else "the recordings do not excite it"))
    groups = torch.cat(groups)
    cov = coefficient_covariance(A, r, groups)
    std_all = cov.diagonal().clamp_min(0).sqrt()
    values, std, k0 = {}, {}, A_lin.shape[1]
    for name, tool in tools.items():
        values[name] = tool.known_row()
        std[name] = np.zeros(tool.width)
        if name in pending:
            m = len(tool.unknown)
            values[name] = pending[name].row(theta[name]).numpy()
            std[name][tool.unknown] = std_all[k0: k0 + m].numpy()
            k0 += m
    notes = []
    for name in pending:  # an inertia the data leave loose can come out of no rigid body: made one, said so
        if tools[name].width == 10 and any(k >= 4 for k in tools[name].unknown):
            values[name], lowest = physical_inertia(values[name])
            if lowest < 0:
                notes.append(f"tool {name!r}: the identified inertia is not a rigid body's (its mass's second moment "
                             f"has the eigenvalue {lowest:.3g} kg m^2): the nearest one is kept (the recordings "
                             "hardly determine it; its intervals stand as fitted)")
                warnings.warn(notes[-1], stacklevel=2)
    rms = r.reshape(-1, n).pow(2).mean(0).sqrt().tolist()
    arm_model = None
    if arm is None:  # the arm identified with the tools: a least-squares ArmModel (base parameters, friction)
        friction = linear_friction(x[base["rank"]:], extra, n)
        if "viscous" in drive.forms:
            friction["b"] = _viscous_of(base, x[: base["rank"]].numpy(), n)
        arm_model = ArmModel(chain, drive, "least squares with the tools", friction, base=base,
                             beta=x[: base["rank"]].numpy())
        labels = _base_names(base, parameter_names(chain))
        labels += linear_friction_names(chain, extra)
        coef_std = std_all[: A_lin.shape[1]]
        arm_model.info["uncertainty"] = {"names": labels, "value": x.tolist(), "std": coef_std.tolist(),
                                         "interval95": torch.stack([x - Z95 * coef_std, x + Z95 * coef_std],
                                                                   -1).tolist(), "block_samples": int(block)}
    label = against or ("the arm, identified with them by least squares" if arm is None else "the given arm")
    return ToolFit(tools={n_: tools[n_] for n_ in tools}, values=values, std=std, against=label,
                   used={name: carried.get(name, []) for name in tools}, condition=condition, residual_rms=rms,
                   block=int(block), arm=arm_model, notes=notes)
