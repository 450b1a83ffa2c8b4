"""Classical identification of a robot arm, as robotics labs do it, beside every learned model: the
inverse dynamics of the description's kinematic chain, linear in the inertial parameters
(``lnn_torch.robots.regressor``), plus a drive model per joint (``lnn_torch.mechanics.friction``), fitted to
measured joint torques.

* ``least_squares``: the base parameters (the combinations the trajectory excites; pivoted QR,
  ``regressor.base_parameters``) and the linear friction coefficients by ordinary least squares or,
  ``weighted=True``, by weighted least squares (each joint's rows divided by the standard deviation of
  its ordinary residual, Gautier's two-step estimate); the sigmoid friction's ``phi2, phi3`` by
  variable projection (an outer nonlinear least squares over them, the linear ones solved inside).
* ``consistent_fit``: a physically consistent model: every link's pseudo-inertia ``J = U U^T``
  (log-Cholesky: positive mass, inertia within the triangle inequality, for every value), armature and
  the passive friction coefficients non-negative (squares), fitted by Newton's method with a trust
  region on the same (weighted) squared torque error plus ``prior`` times the LogDet divergence of each
  ``J`` from the description's (the geometry-aware pull towards the description when the data cannot
  tell; 0: none).

Both give an ``ArmModel`` (the rigid-body face ``mass_matrix``, ``bias``, ``gravity``, ``friction``,
``inverse``, ``forward`` in SI) and a report of its parameters.

Uncertainty and identifiability (least squares): before fitting, the excitation check
(``excitation``: the condition number of the column-scaled regressor of the base parameters and the
friction columns; above ``COND_WARN`` a warning says the recordings cannot determine the model), and
after it the covariance of every estimated coefficient, cluster-robust over blocks of ``block``
consecutive samples (each block's rows together: residuals correlated across the joints of a sample,
or along a trajectory for ``block > 1``; the sandwich ``(A^T A)^-1 (sum_b s_b s_b^T) (A^T A)^-1`` with
``s_b = A_b^T r_b``, times ``B / (B - 1)``), its standard errors and 95 % intervals per base parameter
(``ArmModel.info["uncertainty"]``, named after the parameter each base combination is pivoted on), and
the parameters the data determine only in combination with others or not at all, named.
Shapes: ``q, qd, qdd, tau (N, n)``, float64.
"""

from __future__ import annotations

import hashlib
import math
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import InputError, values_readable
from ..mechanics.friction import COEFFICIENTS, SLOPE_LIMIT, DriveModel
from ..robots.kinematics import SerialChain, log_cholesky, log_cholesky_factor
from ..robots.regressor import (
    NEGLIGIBLE,
    base_parameters,
    classical_of,
    inverse_dynamics,
    parameter_names,
    parameter_vector,
    payload_torque,
    pseudo_inertia_of,
    regressor,
)
from .consistent_objective import ConsistentObjective

# the condition number of the column-scaled regressor above which the recordings are said not to determine
# the model (the exciting trajectories of identification papers reach 10-300; a stationary arm, infinity)
COND_WARN = 1e3
# the priors a consistent fit chooses among on validation data (consistent_fit; LogDet divergence per link,
# in units of the mean squared torque error per sample, N^2 m^2)
PRIORS = (1e-4, 1e-3, 1e-2, 3e-2, 0.1, 0.3, 1.0, 3.0, 10.0)
# where validation prefers the strongest or the weakest of the priors given, up to EXTEND more beyond it, each
# EXTEND_STEP times stronger (weaker) than the last, while the validation error falls (consistent_fit)
EXTEND, EXTEND_STEP = 4, 10 ** 0.5
Z95 = 1.959963984540054  # the two-sided 95 % quantile of the normal distribution


@dataclass
class ArmModel:
    """An identified arm: ``tau = Y(q, qd, qdd) pi + f(qd)`` (module docstring). ``pi``: the full
    parameter vector (consistent fit) or None with ``base``/``beta`` (least squares: only the
    identifiable combinations have values); ``friction_coefficients``: the drive model's coefficients per
    joint."""

    chain: SerialChain
    drive: DriveModel
    method: str
    friction_coefficients: dict[str, np.ndarray]
    pi: np.ndarray | None = None
    base: dict | None = None
    beta: np.ndarray | None = None
    weights: np.ndarray | None = None  # the per-joint row weights of a weighted fit
    info: dict = field(default_factory=dict)

    def rigid_torque(self, q, qd, qdd, payload=None, viscous: bool = True) -> torch.Tensor:
        """The rigid body's and the armature's torques ``(N, n)`` (viscous friction included where the
        drive has it and ``viscous``: it is the regressor's damping column); with ``payload (N, 4 or 10)``
        (per row, at the flange; None: none) its torques too (``regressor.payload_torque``)."""
        if payload is not None:
            return self.rigid_torque(q, qd, qdd, viscous=viscous) + payload_torque(self.chain, q, qd, qdd, payload)
        if self.pi is not None:  # the recursion with the parameters, not the regressor (a tenth of the time)
            pi = torch.as_tensor(self.pi, dtype=torch.float64).clone()
            if "viscous" not in self.drive.forms or not viscous:
                pi[11 * self.chain.dof:] = 0.0
            q, qd, qdd = (torch.as_tensor(x, dtype=torch.float64) for x in (q, qd, qdd))
            return inverse_dynamics(self.chain, q, qd, qdd, pi)
        Y = _regressor(self.chain, q, qd, qdd, self.drive, viscous)
        return Y[..., torch.as_tensor(self.base["independent"])] @ torch.as_tensor(self.beta)  # Y_B beta

    # ------------------------------------------------------------------ the rigid-body face (SI, float64)
    # ``params`` is the payload at the flange, ``(N, 4 or 10)`` per row (None: none), as on every face
    def mass_matrix(self, q, params=None) -> torch.Tensor:
        """``M (N, n, n)``: column ``i`` the rigid torques of ``qdd = e_i`` at rest less gravity's. A
        least-squares fit's ``M`` need not be positive definite."""
        q = torch.as_tensor(q, dtype=torch.float64)
        n, dof = q.shape
        rest = torch.zeros_like(q)
        rows = None if params is None else torch.as_tensor(params, dtype=torch.float64)
        still = self.rigid_torque(q, rest, rest, rows)
        unit = self.rigid_torque(q.repeat_interleave(dof, 0), rest.repeat_interleave(dof, 0),
                                 torch.eye(dof, dtype=q.dtype).repeat(n, 1),
                                 None if rows is None else rows.repeat_interleave(dof, 0))
        M = (unit.view(n, dof, dof) - still[:, None]).mT
        return 0.5 * (M + M.mT)

    def bias(self, q, qd, params=None) -> torch.Tensor:
        """``n (N, n)``: Coriolis, centrifugal and gravity torques, no friction."""
        rest = torch.zeros_like(torch.as_tensor(qd, dtype=torch.float64))
        return self.rigid_torque(q, qd, rest, params, viscous=False)

    def gravity(self, q, params=None) -> torch.Tensor:
        """``g = n(q, 0) (N, n)``: the torques that hold the arm still at ``q``."""
        rest = torch.zeros_like(torch.as_tensor(q, dtype=torch.float64))
        return self.rigid_torque(q, rest, rest, params, viscous=False)

    def friction(self, q, qd, params=None) -> torch.Tensor:
        """``Q_f = -f(qd) (N, n)``: the drive model's friction as a generalised force (it opposes the
        motion), viscous included."""
        qd = torch.as_tensor(qd, dtype=torch.float64)
        rest = torch.zeros_like(qd)
        viscous = self.rigid_torque(rest, qd, rest) - self.rigid_torque(rest, qd, rest, viscous=False)
        coefficients = {k: torch.as_tensor(v) for k, v in self.friction_coefficients.items()}
        return -(viscous + self.drive.torque(qd, {**coefficients, "b": torch.zeros(1)}))

    def inverse(self, q, qd, qdd, params=None) -> torch.Tensor:
        """The joint torques ``(N, n)`` (N m) that give ``qdd`` at ``(q, qd)`` carrying the payload
        ``params``: ``M qdd + n - Q_f``."""
        qd = torch.as_tensor(qd, dtype=torch.float64)
        coefficients = {k: torch.as_tensor(v) for k, v in self.friction_coefficients.items()}
        return (self.rigid_torque(q, qd, qdd, params)
                + self.drive.torque(qd, {**coefficients, "b": torch.zeros(1)}))

    def forward(self, q, qd, tau, payload=None) -> torch.Tensor:
        """The accelerations ``(N, n)`` under the joint torques ``tau`` (N m): ``M(q) qdd = tau - h(q, qd)``
        with ``h`` the torque at zero acceleration (friction included) and ``M``'s columns the rigid
        torques of unit accelerations at rest less those at zero acceleration (the friction and gravity
        cancel); ``payload`` as in ``inverse``. A least-squares fit's ``M`` need not be positive definite:
        a singular one gives NaN."""
        q, qd, tau = (torch.as_tensor(x, dtype=torch.float64) for x in (q, qd, tau))
        rows = None if payload is None else torch.as_tensor(payload, dtype=torch.float64)
        h = self.inverse(q, qd, torch.zeros_like(qd), rows)
        solution, info = torch.linalg.solve_ex(self.mass_matrix(q, rows), (tau - h)[..., None])
        return torch.where((info == 0)[:, None], solution[..., 0], torch.nan)

    def report(self) -> dict:
        """The model in SI: its method, the drive model, the friction coefficients per joint, and the
        links' masses (a consistent fit) or the number of base parameters (least squares)."""
        out = {"method": self.method, "drive": self.drive.name, "joints": list(self.chain.joint_names),
               "friction": {k: np.asarray(v).tolist() for k, v in self.friction_coefficients.items()},
               **self.info}
        if self.pi is not None:
            n = self.chain.dof
            out["mass"] = self.pi[9: 10 * n: 10].tolist()
            out["armature"] = self.pi[10 * n: 11 * n].tolist()
        else:
            out["base_parameters"] = int(self.base["rank"])
        return out


def description_parameters(chain: SerialChain) -> torch.Tensor:
    """The description's own parameter vector ``pi`` (its links' classical ten, armature, damping)."""
    return parameter_vector(chain.J, chain.armature, chain.damping)


# the regressors of the last few state sets of CACHE_ROWS rows or more (a classical start fits a dozen candidates to the
# same training and validation states; identify its fits and the held-out states), by the content of the states and of
# the chain's kinematics: a third of a start's time was spent computing the same regressor again. Never changed in
# place (``_regressor`` copies before zeroing a column)
_CACHE: OrderedDict = OrderedDict()
CACHED, CACHE_ROWS = 3, 256


def clear_regressor_cache() -> None:
    """Let go of the cached regressors (``_regressor``; a classical start does when it ends)."""
    _CACHE.clear()


def _content(chain: SerialChain, args) -> str:
    digest = hashlib.blake2b(digest_size=16)
    digest.update(str(args[0].device).encode())
    for t in (chain.X, chain.axis, chain.anchor, chain.qpos0, chain.gravity, *args):
        a = np.ascontiguousarray(t.detach().cpu().numpy())
        digest.update(f"{a.dtype}{a.shape}".encode())
        digest.update(a)
    return digest.hexdigest()


def _regressor(chain: SerialChain, q, qd, qdd, drive: DriveModel, viscous: bool = True) -> torch.Tensor:
    """``Y (N, n, 12 n)`` with the damping columns zeroed where the drive has no viscous friction (or
    ``viscous`` is False: the rigid body alone)."""
    args = [torch.as_tensor(x, dtype=torch.float64) for x in (q, qd, qdd)]
    if args[0].shape[0] < CACHE_ROWS or any(a.requires_grad for a in args) or not values_readable():
        Y = regressor(chain, *args)  # (a gradient or a torch.func transform through it: computed afresh)
    else:
        key = _content(chain, args)
        Y = _CACHE.get(key)
        if Y is None:
            Y = _CACHE[key] = regressor(chain, *args)
            while len(_CACHE) > CACHED:
                _CACHE.popitem(last=False)
        _CACHE.move_to_end(key)
    if "viscous" not in drive.forms or not viscous:
        Y = Y.clone()
        Y[..., 11 * chain.dof:] = 0.0
    return Y


def _friction_columns(qd: torch.Tensor, drive: DriveModel, forms) -> torch.Tensor:
    """``(N, n, n k)``: the shapes of ``forms`` per joint, each joint's in its own columns."""
    n = qd.shape[-1]
    shapes = torch.stack([drive.shape(f, qd) for f in forms], -1)  # (N, n, k)
    eye = torch.eye(n, dtype=qd.dtype)
    return (eye[None, :, :, None] * shapes[:, :, None, :]).reshape(qd.shape[0], n, n * len(forms))


def _check(q, qd, qdd, tau, chain: SerialChain):
    arrays = [torch.as_tensor(x, dtype=torch.float64) for x in (q, qd, qdd, tau)]
    n = chain.dof
    for name, x in zip(("q", "qd", "qdd", "tau"), arrays, strict=True):
        if x.ndim != 2 or x.shape[1] != n or x.shape[0] != arrays[0].shape[0]:
            raise InputError(f"classical identification: {name} must be (N, {n}), got {tuple(x.shape)}")
        if not torch.isfinite(x).all():
            raise InputError(f"classical identification: {name} has NaN or Inf")
    return arrays


def excitation(A: torch.Tensor) -> float:
    """The condition number of ``A (rows, p)`` with its columns scaled to unit norm (the excitation of a
    regressor: how well the data separate its columns; ``inf`` where a column is zero or dependent)."""
    norms = A.norm(dim=0)
    if bool((norms == 0).any()):
        return float("inf")
    s = torch.linalg.svdvals(A / norms)
    return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


def coefficient_covariance(A: torch.Tensor, r: torch.Tensor, groups: torch.Tensor) -> torch.Tensor:
    """The cluster-robust covariance ``(p, p)`` of least-squares coefficients of ``A (rows, p)`` with
    residuals ``r (rows,)``, rows clustered by ``groups (rows,)`` (consecutive integers from 0)."""
    inverse = torch.linalg.pinv(A.T @ A)
    count = int(groups.max()) + 1
    scores = torch.zeros(count, A.shape[1], dtype=A.dtype).index_add_(0, groups, A * r[:, None])
    return inverse @ (scores.T @ scores) @ inverse * (count / max(count - 1, 1))


def _base_names(base: dict, names: list[str]) -> list[str]:
    """Each base parameter named after the parameter its combination is pivoted on, ``+ k more`` where
    dependent parameters enter it."""
    out = []
    for k, j in enumerate(base["independent"]):
        more = int(np.count_nonzero(np.abs(base["K"][k]) > 1e-12)) if base["K"].size else 0
        out.append(names[j] + (f" (+ {more} more)" if more else ""))
    return out


def _moving(Y: torch.Tensor) -> set:
    """The parameters whose columns of ``Y (rows, p)`` move a torque: beyond ``NEGLIGIBLE`` of the largest column's
    norm, as ``base_parameters`` counts them (round-off, 1e-17 of it on one machine and 0 on another, is none)."""
    norms = Y.norm(dim=0)
    return set(np.flatnonzero((norms > NEGLIGIBLE * norms.max()).numpy()).tolist())


def least_squares(chain: SerialChain, q, qd, qdd, tau, drive=None, weighted: bool = False,
                  rtol: float = 1e-6, block: int = 1) -> ArmModel:
    """Base parameters and friction by (weighted) least squares, with their uncertainty (module
    docstring); ``block``: the samples per cluster of the covariance (1: each sample's joints together;
    the number of samples in the residuals' correlation time for filtered recordings)."""
    import warnings

    from ..errors import UntrustedParameterWarning

    drive = DriveModel.of(drive)
    q, qd, qdd, tau = _check(q, qd, qdd, tau, chain)
    N, n = q.shape
    Y = _regressor(chain, q, qd, qdd, drive)
    base = base_parameters(Y.reshape(N * n, -1), rtol)
    extra = [f for f in drive.linear_forms if f != "viscous"]
    YB = Y.reshape(N * n, -1)[:, torch.as_tensor(base["independent"])]
    F = _friction_columns(qd, drive, extra).reshape(N * n, -1) if extra else torch.zeros(N * n, 0, dtype=q.dtype)
    target = tau.reshape(-1)

    def solve(phi, w):
        cols = [YB, F]
        if phi is not None:
            cols.append(_sigmoid_columns(qd, drive, *phi).reshape(N * n, -1))
        A = torch.cat(cols, 1) * w[:, None]
        x = torch.linalg.lstsq(A, target * w).solution
        return x, target * w - A @ x

    condition = excitation(torch.cat([YB, F], 1))
    if condition > COND_WARN:
        warnings.warn(f"classical identification: the recordings excite the model poorly (condition number "
                      f"{condition:.3g} of the scaled regressor, above {COND_WARN:g}): the base parameters are "
                      "uncertain; record a more exciting trajectory", UntrustedParameterWarning, stacklevel=2)
    ones = torch.ones(N * n, dtype=q.dtype)
    phi = None
    if "sigmoid" in drive.forms:
        phi = _variable_projection(lambda p: solve(p, ones)[1], n, coulomb_velocity=drive.coulomb_velocity)
    x, r = solve(phi, ones)
    w = ones
    weights = None
    if weighted:
        sigma = (r.reshape(N, n).pow(2).mean(0).sqrt()).clamp_min(1e-12)
        weights = (1.0 / sigma).numpy()
        w = (1.0 / sigma).repeat(N)
        if phi is not None:
            phi = _variable_projection(lambda p: solve(p, w)[1], n, start=phi,
                                       coulomb_velocity=drive.coulomb_velocity)
        x, r = solve(phi, w)
    r_B = base["rank"]
    beta, coefs = x[:r_B], x[r_B:]
    # the friction columns are per joint, each joint's forms together: column j k + i is joint j, form i
    friction = linear_friction(coefs, extra, n)
    if phi is not None:
        friction["phi1"] = coefs.reshape(-1)[len(extra) * n:].numpy()
        friction["phi2"], friction["phi3"] = phi[0].numpy(), phi[1].numpy()
    if "viscous" in drive.forms:  # the damping column's combination: its own base parameter where identifiable
        friction["b"] = _viscous_of(base, beta.numpy(), n)
    cols = [YB, F] + ([_sigmoid_columns(qd, drive, *phi).reshape(N * n, -1)] if phi is not None else [])
    A = torch.cat(cols, 1) * w[:, None]
    groups = torch.arange(N).repeat_interleave(n) // max(int(block), 1)
    std = coefficient_covariance(A, r, groups).diagonal().clamp_min(0).sqrt()
    names = parameter_names(chain)
    friction_names = linear_friction_names(chain, extra)
    friction_names += [f"{chain.joint_names[j]}.phi1" for j in range(n)] if phi is not None else []
    moving = _moving(Y.reshape(N * n, -1))
    # of those these recordings do not move, the ones no motion of this arm moves (e.g. the first link's inertia
    # about axes other than its joint's): seeded random states over the whole circle of every joint
    rng = torch.Generator().manual_seed(0)
    Q = (torch.rand(64, n, generator=rng, dtype=torch.float64) * 2 - 1) * math.pi
    anywhere = _regressor(chain, Q, *(torch.randn(64, n, generator=rng, dtype=torch.float64) for _ in range(2)), drive)
    possible = _moving(anywhere.reshape(64 * n, -1))
    uncertainty = {"condition_number": condition, "block_samples": int(block),
                   "names": _base_names(base, names) + friction_names, "value": x.tolist(), "std": std.tolist(),
                   "interval95": torch.stack([x - Z95 * std, x + Z95 * std], -1).tolist(),
                   "in_combination": [names[j] for j in base["dependent"] if j in moving],
                   "undetermined": [names[j] for j in range(len(names)) if j not in moving],
                   "never_moving": [names[j] for j in range(len(names)) if j not in possible]}
    model = ArmModel(chain, drive, "weighted least squares" if weighted else "least squares", friction,
                     base=base, beta=beta.numpy(), weights=weights)
    model.info["uncertainty"] = uncertainty
    return model


def linear_friction(coefs: torch.Tensor, forms, n: int) -> dict:
    """``{coefficient name: (n,)}`` of the linear friction ``forms`` from their least-squares coefficients
    (``_friction_columns``' layout: column ``j k + i`` is joint ``j``, form ``i``; extra entries after them
    are ignored)."""
    return {COEFFICIENTS[f][0]: coefs[torch.arange(n) * len(forms) + i].numpy() for i, f in enumerate(forms)}


def linear_friction_names(chain: SerialChain, forms) -> list[str]:
    """The names of ``_friction_columns``' coefficients, ``joint.coefficient`` in their order."""
    return [f"{chain.joint_names[j]}.{COEFFICIENTS[f][0]}" for j in range(chain.dof) for f in forms]


def _sigmoid_columns(qd, drive, phi2, phi3) -> torch.Tensor:
    """``(N, n, n)``: the sigmoid's shape per joint at ``(phi2, phi3)``, each joint's in its own column."""
    return torch.diag_embed(drive.shape("sigmoid", qd, phi2, phi3))


def _viscous_of(base: dict, beta: np.ndarray, n: int) -> np.ndarray:
    """The viscous coefficient per joint where it is a base parameter of its own (NaN where it is only
    identifiable in a combination)."""
    p = base["map"].shape[1]
    out = np.full(n, np.nan)
    M = np.asarray(base["map"])
    tiny = 1e-9 * np.abs(M).max(1, keepdims=True)  # (a map computed in floating point: round-off is no share)
    for j in range(n):
        col = p - n + j
        rows = np.nonzero(np.abs(M[:, col]) > tiny[:, 0])[0]
        if len(rows) == 1 and np.count_nonzero(np.abs(M[rows[0]]) > tiny[rows[0]]) == 1:
            out[j] = beta[rows[0]] / M[rows[0], col]
    return out


def base_least_squares(Y: torch.Tensor, tau: torch.Tensor, base: dict) -> np.ndarray:
    """Base parameters ``beta (r,)`` by ordinary least squares on ``tau = Y_B beta``."""
    YB = Y.detach().double().cpu().numpy()[:, base["independent"]]
    return np.linalg.lstsq(YB, tau.detach().double().cpu().numpy().reshape(-1), rcond=None)[0]


def _variable_projection(residual, n: int, start=None, coulomb_velocity: float = 0.02):
    """``(phi2 (n,), phi3 (n,))`` minimising ``|residual(phi)|^2`` (scipy's least squares; ``phi2`` on a
    log scale, starting at 30 s/rad and bounded by ``SLOPE_LIMIT / coulomb_velocity``, ``phi3`` at 0)."""
    import scipy.optimize

    top = np.log(SLOPE_LIMIT / coulomb_velocity)
    x0 = np.concatenate([np.log(np.full(n, 30.0)), np.zeros(n)]) if start is None else \
        np.concatenate([np.minimum(np.log(start[0].numpy()), top - 1e-9), start[1].numpy()])

    def fun(x):
        phi2, phi3 = torch.as_tensor(np.exp(x[:n])), torch.as_tensor(x[n:])
        return residual((phi2, phi3)).numpy()

    bounds = (np.full(2 * n, -np.inf), np.concatenate([np.full(n, top), np.full(n, np.inf)]))
    sol = scipy.optimize.least_squares(fun, x0, method="trf", x_scale="jac", max_nfev=200, bounds=bounds)
    return torch.as_tensor(np.exp(sol.x[:n])), torch.as_tensor(sol.x[n:])


def consistent_fit(chain: SerialChain, q, qd, qdd, tau, drive=None, weights=None, prior=0.01,
                   start: ArmModel | None = None, max_iterations: int = 300, validation=None,
                   extend: bool = True) -> ArmModel:
    """A physically consistent model (module docstring): starts from the description's inertias (and,
    given ``start``, that fit's passive friction coefficients), minimises the mean (weighted) squared
    torque error plus ``prior`` times the LogDet divergence from the description per link.

    ``prior`` a sequence (e.g. ``PRIORS``): each is fitted, the strongest first (each from where the
    previous ended), and the one whose model has the lowest torque error on ``validation`` ``(q, qd, qdd,
    tau[, payload])`` (the mean over joints of each joint's RMS, N m) is kept; where that is the strongest or
    the weakest given, stronger (weaker) ones are tried beyond it while the validation error falls (``EXTEND``,
    ``EXTEND_STEP``; not with ``extend`` False); ``info["prior_selection"]`` lists every prior's validation
    error."""
    import scipy.optimize

    drive = DriveModel.of(drive)
    q, qd, qdd, tau = _check(q, qd, qdd, tau, chain)
    N, n = q.shape
    Y = _regressor(chain, q, qd, qdd, drive).reshape(N * n, -1)
    w = torch.ones(n, dtype=q.dtype) if weights is None else torch.as_tensor(weights, dtype=q.dtype)
    w_rows = w.repeat(N)
    Yw, tw = Y * w_rows[:, None], tau.reshape(-1) * w_rows
    J0 = chain.J.to(q.dtype)
    logdet0 = torch.logdet(J0)
    names = drive.coefficient_names()
    others = [x for x in names if x != "b"]
    # the linear friction forms beyond viscous are columns beside the regressor's: with no sigmoid the squared
    # error is a quadratic form in x = (p, those coefficients), its Gram matrix computed once (no per-point work
    # in the iterations); the sigmoid's shape moves with phi2, phi3 and is evaluated per point
    linear = [f for f in drive.linear_forms if f != "viscous"] if "sigmoid" not in drive.forms else []
    W = Yw
    if linear:
        W = torch.cat([Yw, _friction_columns(qd, drive, linear).reshape(N * n, -1) * w_rows[:, None]], 1)
    A, b, c = W.T @ W / N, W.T @ tw / N, tw @ tw / N  # the squared error: x A x - 2 b x + c
    linear_names = [COEFFICIENTS[f][0] for f in linear]

    def unpack(theta):
        raw = theta[: 10 * n].reshape(n, 10)
        U = log_cholesky_factor(raw)
        J = U @ U.mT
        armature = theta[10 * n: 11 * n] ** 2
        coef = theta[11 * n:].reshape(len(names), n)
        values = {}
        for i, name in enumerate(names):
            values[name] = coef[i] if name in ("o", "phi3") else coef[i] ** 2  # passive ones non-negative
        if "d" in values and "c" in values:  # saturating friction: passive down to -k c
            values["d"] = values["d"] - drive.saturation_floor() * values["c"]
        return J, armature, values

    def loss(theta, strength):  # a sigmoid drive's (``closed`` below takes every other): its friction per point
        J, armature, values = unpack(theta)
        zero = torch.zeros(n, dtype=theta.dtype)
        p = torch.cat([classical_of(J).reshape(-1), armature, values.get("b", zero)])
        fr = drive.torque(qd, {k: values[k] for k in others} | {"b": zero}).reshape(-1) * w_rows
        err = p @ A @ p - 2 * b @ p + c + (fr @ fr - 2 * fr @ (tw - Yw @ p)) / N
        div = (torch.linalg.solve(J0, J).diagonal(dim1=-2, dim2=-1).sum(-1) - torch.logdet(J) + logdet0 - 4).sum()
        return err + strength * div

    raw0 = log_cholesky(J0)
    coef0 = []
    for name in names:
        value = np.zeros(n)
        if start is not None and name in start.friction_coefficients:
            value = np.nan_to_num(np.asarray(start.friction_coefficients[name], dtype=np.float64))
        elif name == "phi2":
            value = np.full(n, 30.0)
        if name == "d" and start is not None and "c" in start.friction_coefficients:
            value = value + drive.saturation_floor() * np.nan_to_num(np.asarray(start.friction_coefficients["c"]))
        if name not in ("o", "phi3"):
            value = np.sqrt(np.clip(value, 1e-8, None))
        coef0.append(torch.as_tensor(value))
    theta0 = torch.cat([raw0.reshape(-1), torch.full((n,), 0.05, dtype=q.dtype), *coef0])

    # every friction form linear in its coefficients: the objective, its gradient and Hessian in closed form
    # (``consistent_objective``); a sigmoid's shape is evaluated per point, by autograd
    closed = None
    if linear or not others:
        floor = drive.saturation_floor() if "d" in names and "c" in names else 0.0
        closed = ConsistentObjective(A.numpy(), b.numpy(), float(c), J0.numpy(), names, linear_names, floor)

    def solve(strength, x0):
        def fun(x):
            if closed is not None:
                return closed.value_and_gradient(x, strength)
            t = torch.as_tensor(x).requires_grad_(True)
            value = loss(t, strength)
            (grad,) = torch.autograd.grad(value, t)
            return float(value.detach()), grad.numpy()

        def hess(x):
            if closed is not None:
                return closed.hessian(x, strength)
            return torch.autograd.functional.hessian(lambda t: loss(t, strength), torch.as_tensor(x)).numpy()

        sol = scipy.optimize.minimize(fun, x0, jac=True, hess=hess, method="trust-exact",
                                      options={"maxiter": max_iterations, "gtol": 1e-10})
        sol.start_value = fun(x0)[0]
        return sol

    def model_of(x, strength, sol):
        J, armature, values = unpack(torch.as_tensor(x))
        pi = torch.cat([classical_of(J).reshape(-1), armature, values.get("b", torch.zeros(n, dtype=q.dtype))])
        friction = {k: v.detach().numpy() for k, v in values.items() if k != "b"}
        if "b" in values:
            friction["b"] = values["b"].detach().numpy()
        return ArmModel(chain, drive, "physically consistent", friction, pi=pi.detach().numpy(),
                        weights=None if weights is None else np.asarray(weights),
                        info={"prior": strength, "iterations": int(sol.nit), "converged": _stationary(sol)}), values

    priors = [float(prior)] if np.ndim(prior) == 0 else sorted((float(p) for p in prior), reverse=True)
    if len(priors) > 1 and validation is None:
        raise InputError("classical identification: choosing the prior among several needs validation data")
    if not priors or any(not (p >= 0) for p in priors):
        raise InputError(f"classical identification: prior must be >= 0, got {prior!r}")
    if validation is not None:
        vq, vqd, vqdd, vtau = _check(*validation[:4], chain)
        vparams = validation[4] if len(validation) > 4 else None
    def validation_error(model) -> float:  # the mean over joints of each joint's RMS, N m
        return float((model.inverse(vq, vqd, vqdd, vparams) - vtau).pow(2).mean(0).sqrt().mean())

    def fitted(strength, start):  # the model at ``strength``, solved from ``start``; and where it ended
        sol = solve(strength, start)
        return model_of(sol.x, strength, sol), sol.x

    best, x, scores, ends = None, theta0.numpy(), {}, {}
    for strength in priors:  # the strongest first; each starts where the previous ended
        candidate, x = fitted(strength, x)
        ends[strength] = x
        if validation is None:
            best = candidate
            break
        scores[strength] = validation_error(candidate[0])
        if best is None or scores[strength] < scores[best[0].info["prior"]]:
            best = candidate
    if extend and scores and len(priors) > 1 and best[0].info["prior"] in (priors[0], priors[-1]):
        # the best at an end of those given: the validation error may fall further beyond it (a description
        # as good as the manufacturer's table wants a stronger prior than the grid holds, a poor one a
        # weaker): priors EXTEND_STEP apart beyond that end while the validation error falls, EXTEND at most
        step = EXTEND_STEP if best[0].info["prior"] == priors[0] else 1 / EXTEND_STEP
        end, x = best[0].info["prior"], ends[best[0].info["prior"]]
        for k in range(1, EXTEND + 1 if end > 0 else 1):
            strength = float(f"{end * step ** k:.3g}")  # from 10: 31.6, 100, 316, 1000
            candidate, x = fitted(strength, x)
            scores[strength] = validation_error(candidate[0])
            if not scores[strength] < scores[best[0].info["prior"]]:
                break
            best = candidate
    model, values = best
    if scores:
        model.info["prior_selection"] = {"validation_rms_mean": {f"{k:g}": v for k, v in scores.items()},
                                         "chosen": model.info["prior"]}
    pi = torch.as_tensor(model.pi)
    fr = torch.zeros(N * n, dtype=q.dtype)
    if others:
        fr = drive.torque(qd, {k: values[k].detach() for k in others} | {"b": torch.zeros(n)}).reshape(-1) * w_rows
    residual = tw - Yw @ pi - fr
    model.info["uncertainty"] = _physical_uncertainty(chain, Yw, residual, pi, J0, model.info["prior"], N)
    return model


def _stationary(sol) -> bool:
    """Whether a trust-region solve ended at a stationary point: scipy's success, or an end without it (most often
    its step test failing at round-off: "A bad approximation caused failure to predict improvement") with the
    gradient's largest entry below 1e-6 of the objective at the start (``sol.start_value``, at least 1)."""
    return bool(sol.success or np.abs(sol.jac).max() <= 1e-6 * max(1.0, abs(sol.start_value)))


def _physical_uncertainty(chain: SerialChain, Yw, residual, pi, J0, prior: float, N: int) -> dict:
    """The Laplace covariance of the physical parameters ``pi`` (the classical ten per link, armature,
    damping) at a consistent fit: ``s^2 (Yw^T Yw + N prior H)^-1`` with ``s^2`` the residual variance and
    ``H`` the prior's Hessian there. A parameter that moves along a direction the data do not determine
    (``Yw^T Yw``'s eigenvalues below 1e-10 of its largest) is held by the prior towards the description,
    and named: its interval is the prior's, not the data's."""
    from torch.func import hessian

    n = chain.dof
    s2 = float(residual.pow(2).mean())

    def divergence(links):
        J = pseudo_inertia_of(links.reshape(n, 10))
        return (torch.linalg.solve(J0, J).diagonal(dim1=-2, dim2=-1).sum(-1) - torch.logdet(J)).sum()

    H = torch.zeros(12 * n, 12 * n, dtype=pi.dtype)
    H[: 10 * n, : 10 * n] = hessian(divergence)(pi[: 10 * n])
    data = Yw.T @ Yw
    total = data + N * prior * H
    keep = torch.nonzero(total.diagonal() > 0).reshape(-1)  # the damping of a drive without viscous friction: none
    std = torch.full((12 * n,), float("nan"), dtype=pi.dtype)
    std[keep] = (s2 * torch.linalg.pinv(total[keep][:, keep], hermitian=True)).diagonal().clamp_min(0).sqrt()
    # the directions the data cannot determine: the data's curvature below 1e-10 of its largest
    eigenvalues, vectors = torch.linalg.eigh(data[keep][:, keep])
    null = vectors[:, eigenvalues < 1e-10 * eigenvalues.max()]
    names = parameter_names(chain)
    by_prior = [names[j] for j, weight in zip(keep.tolist(), null.abs().amax(1).tolist() if null.shape[1] else
                                               [0.0] * len(keep), strict=True) if weight > 0.05]
    return {"names": names, "value": pi.tolist(), "std": std.tolist(),
            "interval95": torch.stack([pi - Z95 * std, pi + Z95 * std], -1).tolist(),
            "held_by_prior": by_prior, "residual_std": s2 ** 0.5}
