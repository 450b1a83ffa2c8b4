"""A grey box of a robot arm started from classical identification: the rigid body's inertial parameters
are linear in the joint torques, so they are solved, not walked to.

``start_from_classical`` fits the physically consistent least-squares model (``classical_arm.consistent_fit``:
every link's pseudo-inertia, the armature and the drive model's coefficients, with the prior towards the
description chosen among ``classical_arm.PRIORS`` on the validation recordings, its rows' weighting too (each
joint's rows as recorded, or divided by the joint's ordinary residual spread as weighted least squares) and its
friction form: the drive model's terms, or all but one where that validates better by more than ``FORM_MARGIN``,
and a curve such as saturating friction only where validation asks for it) to the training recordings and writes
it into a model with the learned spatial part (``networks.parts.spatial``): its links and armature exactly, its
joint friction's coefficients and form (``LearnedForces.keep_forms``: the terms the chosen form leaves out stay
out), and the prior of the refinement that follows then pulls towards this start.
Gradient steps refine it from there; ``training.callbacks.SelectOnValidation`` keeps the state the validation
recordings prefer, the start included, so the trained model is never worse than the classical fit on validation.

    report = start_from_classical(model, system, train, val)   # Trajectories with torques, SI
"""

from __future__ import annotations

import dataclasses
import time

import torch

from ..errors import InputError
from ..mechanics.friction import COEFFICIENTS
from ..robots.regressor import pseudo_inertia_of
from .arm_comparison import WEIGHTED_CONSISTENT
from .classical_arm import PRIORS, clear_regressor_cache

CONSISTENT = "physically consistent"
# a term of the configured drive model is dropped only when the form without it lowers the validation torque
# error by more than this fraction: a short validation window ranks forms within a per cent or two of each
# other by chance (the Franka bag's 3.5 s: dropping viscous friction lowered validation by 0.8 % and raised the
# held-out error by 1.9 %; the real Panda's: 2.1 % lower on validation, the same held out)
FORM_MARGIN = 0.02
# the Coulomb smoothings (rad/s) the start chooses among with the configured one, by ordinary least squares on the
# validation recordings (a tanh of v / v_c has no physical v_c: a drive's friction turns over within 1-100 mrad/s);
# another than the configured is taken only where it validates better beyond chance (CHANCE_Z below)
COULOMB_VELOCITIES = (0.002, 0.005, 0.01, 0.02, 0.05, 0.1)
# terms of the configured drive model that the start keeps only where validation asks for them (the form with the
# term lower than the form without it by more than FORM_MARGIN), the other way round from the rest: a curve whose
# shape the data may not need (the UR10 bag's drives: saturating friction lowers validation 24 %; the real Panda's
# 0.8 %, the Franka bag's not at all: not kept)
ON_EVIDENCE = ("stribeck", "saturating")
# the velocities (rad/s) saturating friction may rise over (with the configured one), chosen with the Coulomb
# smoothing beside it (COULOMB_VELOCITIES): a wide Coulomb step imitates saturating friction, so the two are chosen
# together, by ordinary least squares on validation
SATURATION_VELOCITIES = (0.05, 0.1, 0.2, 0.5, 1.0)
# "better beyond chance" on validation (the Coulomb smoothing's test, ``_beyond_chance``): the candidate's squared
# torque errors (each joint's in units of the default's mean square) lower than the default's by more than CHANCE_Z
# standard errors of the mean over CHANCE_BLOCKS consecutive blocks of the validation points (errors are correlated
# in time: blocks, not points, are the independent draws)
CHANCE_BLOCKS, CHANCE_Z = 10, 2.0
# the start fits every STRIDE-th sample of each recording (filtered targets change little from one sample to the next)
STRIDE = 2
# singular values of the rigid body's regressor below this fraction of the largest are left out (its null space)
RANK_RTOL = 1e-8


def can_start(model) -> str | None:
    """Why ``model`` cannot start from a classical fit (None: it can): it needs the learned spatial part
    and joint friction on every joint (the drive model the fit uses)."""
    spatial = model.part("kinetic", "spatial") if hasattr(model, "part") else None
    if spatial is None or not spatial.learn:
        return "the model has no learned spatial arm part (kinetic: {spatial: {...}})"
    forces = getattr(model, "forces", None)
    if forces is None or not forces.friction or forces.num_joints != spatial.dof:
        return "the model has no joint friction on every joint (the drive model of the classical fit)"
    return None


def start_from_classical(model, system, train, val=None, *, priors=PRIORS, stride: int = STRIDE) -> dict:
    """Start ``model`` (a structured model with the learned spatial part and joint friction) at the physically
    consistent fit of ``train`` (``Trajectories`` with torques, or a list; every ``stride``-th point), its prior
    chosen on ``val`` (None: 0.01) among ``priors`` with the drive model's own form, and with ``val`` its
    Coulomb smoothing (``COULOMB_VELOCITIES``, ``smoothing_selection``; written into the model:
    ``LearnedForces.set_coulomb_velocity``), its rows' weighting (``weighting_selection``), then its friction
    form: the terms kept on evidence only (``ON_EVIDENCE``; saturating friction at the velocity and Coulomb
    smoothing chosen together by least squares on validation, ``_saturation_velocities``, their errors in
    ``saturation_selection``; each such form's prior chosen anew) where a form with them validates better than the
    form without them by more than ``FORM_MARGIN``, then each other term dropped where the form less that term
    (``_sub_forms``, at the chosen prior and its neighbours in ``priors``) validates better by more than
    ``FORM_MARGIN``. Returns the report:
    the method (weighting), form, prior and Coulomb smoothing kept, the chosen form's validation error per prior
    tried (``validation_rms_mean``), the whole prior search (``prior_search``), each form's and each weighting's
    validation error (``form_selection``, ``weighting_selection``), the fit's time."""
    try:
        return _start(model, system, train, val, priors, stride)
    finally:  # (the regressors it cached: training follows)
        clear_regressor_cache()


def _start(model, system, train, val, priors, stride: int) -> dict:
    from ..robots.kinematics import read_chain
    from ..robots.mujoco_arm import load_description
    from .arm_comparison import fit_classical

    reason = can_start(model)
    if reason is not None:
        raise InputError(f"a classical start needs an arm grey box: {reason}")
    spatial, forces = model.part("kinetic", "spatial"), model.forces
    chain = read_chain(load_description(spatial.description))
    began = time.perf_counter()
    # the terms kept on evidence only (ON_EVIDENCE) are judged last: the smoothing, weighting and prior are the form's
    # without them, so a model validation gives no such term starts where it would without them configured
    configured = forces.drive
    extra = [f for f in configured.forms if f in ON_EVIDENCE] if val is not None and "sigmoid" not in configured.forms \
        else []
    extra = extra if len(extra) < len(configured.forms) else []
    drive = configured.with_forms([f for f in configured.forms if f not in extra])
    smoothing = saturation = None
    if val is not None and {"coulomb", "stribeck"} & set(drive.forms) and "sigmoid" not in drive.forms:
        drive, smoothing = _coulomb_velocity(system, train, val, drive, stride, chain)
    # with validation data, the rows' weighting too: each joint's rows as they are, or divided by that joint's
    # ordinary residual spread (as weighted least squares), whichever validates better. On the five arms tried the
    # two came 0.06-1.2 % apart on validation (within chance by _beyond_chance on the three tested), yet the held-out
    # logs agreed with validation's ranking on four (not on the UR10 bag's, 0.06 % apart); keeping the rows as
    # recorded unless weighting validated better beyond chance was tried: right on two of the five
    methods = ("least squares", "weighted least squares", CONSISTENT, WEIGHTED_CONSISTENT) if val is not None \
        else ("least squares", CONSISTENT)
    fits = fit_classical(system, train, drive=drive, methods=methods, stride=stride,
                         prior=priors if val is not None else 0.01, val=val, chain=chain)
    weightings = {f.method: f for f in fits.values() if f.method in (CONSISTENT, WEIGHTED_CONSISTENT)}
    fit = min(weightings.values(), key=_validation_error)
    search = fit.info.get("prior_selection")
    forms = {drive.name: _validation_error(fit)}
    if val is not None and "sigmoid" not in drive.forms:
        # the friction form, each candidate with the chosen weighting
        chosen = fit.info["prior"]  # beyond priors where validation extended them (classical_arm.EXTEND)
        near = _near(chosen, priors)
        fitted = {drive: fit}

        def at(form, search: bool = False):  # the fit of ``form`` (a DriveModel) at the priors near the chosen one
            if form not in fitted:  # (``search``: the prior chosen anew, among every one)
                fitted[form] = next(iter(fit_classical(system, train, drive=form, methods=(fit.method,), stride=stride,
                                                       prior=priors if search else near, val=val, chain=chain,
                                                       extend=search).values()))
            return fitted[form]

        # the terms kept on evidence only: a form with them where it validates better than the form without them
        # by more than FORM_MARGIN (saturating friction at the velocities _saturation_velocities chooses)
        candidates = {drive.with_forms([*drive.forms, e]) for e in extra}  # (with_forms orders them)
        candidates |= {drive.with_forms(configured.forms)} if len(extra) > 1 else set()
        if "saturating" in extra:  # its velocity and the Coulomb smoothing beside it, chosen together
            (coulomb_velocity, saturation_velocity), saturation = _saturation_velocities(
                system, train, val, drive.with_forms([*drive.forms, "saturating"]),
                configured, stride, chain)
            candidates = {dataclasses.replace(c, coulomb_velocity=coulomb_velocity,
                                              saturation_velocity=saturation_velocity)
                          if "saturating" in c.forms else c for c in candidates}
        # one such term, then two: each level's best kept where it beats the best with fewer by more than FORM_MARGIN
        for level in sorted({len(c.forms) - len(drive.forms) for c in candidates}):
            best = min((at(c, search=True) for c in candidates if len(c.forms) - len(drive.forms) == level),
                       key=_validation_error)  # (search: a curve the plain form lacks can move the prior a long way)
            if _validation_error(best) < (1 - FORM_MARGIN) * _validation_error(fit):
                fit = best
        # the configured drive's other terms: the form less one of them (at the priors near the one now chosen),
        # kept where it lowers the validation error by more than FORM_MARGIN
        near = _near(fit.info["prior"], priors)
        full = _validation_error(fit)
        for sub in _sub_forms(fit.drive):
            other = at(sub)
            error = _validation_error(other)
            if error < (1 - FORM_MARGIN) * full and error < _validation_error(fit):
                fit = other
        for form, other in fitted.items():  # each form's validation error (at its best velocity)
            forms[form.name] = min(forms.get(form.name, float("inf")), _validation_error(other))
    drive = fit.drive
    n = chain.dof
    pi = torch.as_tensor(fit.pi, dtype=torch.float64)
    spatial.start_at(pseudo_inertia_of(pi[: 10 * n].reshape(n, 10)), pi[10 * n: 11 * n])
    if drive.coulomb_velocity != forces.drive.coulomb_velocity:
        forces.set_coulomb_velocity(drive.coulomb_velocity)
    if "saturating" in configured.forms and drive.saturation_velocity != forces.drive.saturation_velocity:
        forces.set_saturation_velocity(drive.saturation_velocity)
    units = forces.units.double()
    # a passive coefficient the fit puts at zero starts just above it (where the softplus still moves it);
    # saturating friction's d just above its own floor, -k c (DriveModel.saturation_floor)
    floors = {"b": 1e-6 * units[0], "c": 1e-6 * units[1], "s": 1e-6 * units[1], "d": 1e-6 * units[1],
              "phi1": 1e-6 * units[1]}
    coefficients = {}
    for form in forces.drive.forms:  # a term the chosen form leaves out at zero (its floor), then kept out
        for name in COEFFICIENTS[form]:
            value = fit.friction_coefficients.get(name, torch.zeros(n, dtype=torch.float64))
            value = torch.as_tensor(value, dtype=torch.float64)
            floor = floors.get(name)
            if name == "d":
                floor = floor - forces.drive.saturation_floor() * coefficients.get("c", 0.0)
            coefficients[name] = value if floor is None else value.clamp_min(floor)
    forces.start_with(coefficients)
    configured_name = forces.drive.name
    # the model is the chosen form from now on: a term left out adds no torque, and gradient steps cannot bring
    # it back (a new-user trial's refinement grew a saturating term the start had left out, which the fit's report
    # and the exported description did not show)
    forces.keep_forms(fit.drive.forms)
    selection = fit.info.get("prior_selection")
    return {"method": fit.method, "drive": configured_name, "form": fit.drive.name, "prior": fit.info["prior"],
            "validation_rms_mean": None if selection is None else selection["validation_rms_mean"],
            "prior_search": None if search is None else search["validation_rms_mean"],
            "form_selection": forms if len(forms) > 1 else None,
            "weighting_selection": ({k: _validation_error(f) for k, f in weightings.items()} if len(weightings) > 1
                                    else None),
            "coulomb_velocity": drive.coulomb_velocity, "smoothing_selection": smoothing,
            **({"saturation_velocity": drive.saturation_velocity, "saturation_selection": saturation}
               if "saturating" in configured.forms else {}),
            "fit_seconds": time.perf_counter() - began, "train_points": fit.info.get("train_points"),
            # the physical parameters the training data do not determine (the prior towards the description holds
            # them): an export of the model says so beside the values it writes
            "held_by_prior": list((fit.info.get("uncertainty") or {}).get("held_by_prior") or [])}


def _coulomb_velocity(system, train, val, drive, stride: int, chain) -> tuple:
    """The drive model with the Coulomb smoothing validation prefers (``COULOMB_VELOCITIES`` and the
    configured one; ordinary least squares, its validation torque error; another than the configured only
    where it is lower beyond chance: ``CHANCE_Z``), and each smoothing's validation
    error ``{v: N m}`` (the mean over joints of each joint's RMS)."""
    from .arm_comparison import fit_classical, stacked_points

    q, qd, qdd, tau, params = stacked_points(val, stride)
    errors, squares = {}, {}
    for v in sorted({drive.coulomb_velocity, *COULOMB_VELOCITIES}):
        fit = next(iter(fit_classical(system, train, drive=dataclasses.replace(drive, coulomb_velocity=v),
                                      methods=("least squares",), stride=stride, chain=chain).values()))
        squares[v] = (fit.inverse(q, qd, qdd, params) - tau).double().pow(2)  # (points, joints)
        errors[v] = float(squares[v].mean(0).sqrt().mean())
    best = min(errors, key=errors.get)
    if not _beyond_chance(squares[drive.coulomb_velocity], squares[best]):
        best = drive.coulomb_velocity
    return dataclasses.replace(drive, coulomb_velocity=best), errors


def _beyond_chance(default: torch.Tensor, other: torch.Tensor) -> bool:
    """Whether the squared validation torque errors ``other`` (points, joints) are lower than ``default``'s
    beyond chance: each point's gain (its joints' squared errors in units of ``default``'s mean square per joint,
    summed) averaged over ``CHANCE_BLOCKS`` consecutive blocks, the blocks' mean above ``CHANCE_Z`` standard
    errors (False with fewer than two points per block)."""
    gain = ((default - other) / default.mean(0).clamp_min(1e-300)).sum(-1)
    if len(gain) < 2 * CHANCE_BLOCKS:
        return False
    blocks = torch.stack([b.mean() for b in gain.tensor_split(CHANCE_BLOCKS)])
    return bool(blocks.mean() > CHANCE_Z * blocks.std() / CHANCE_BLOCKS ** 0.5)


def _saturation_velocities(system, train, val, drive, configured, stride: int, chain) -> tuple:
    """``((v_c, v_d), errors)``: the Coulomb smoothing and the velocity of saturating friction of ``drive`` (a form
    with it) whose ordinary least-squares fit of ``train`` has the lowest validation torque error (the mean over
    joints of each joint's RMS) over the grid ``COULOMB_VELOCITIES`` x ``SATURATION_VELOCITIES`` (with
    ``configured``'s; beside a Coulomb term a pair and its mirror once, ``v_d > v_c``), and each ``v_d``'s error
    at its best ``v_c`` ``{v_d: N m}``. The rigid body's columns are
    solved once (their pseudo-inverse, truncated at ``RANK_RTOL`` of the largest singular value); each pair
    changes only the friction columns beside them."""
    from ..robots.regressor import payload_torque
    from .arm_comparison import stacked_points
    from .classical_arm import _friction_columns, _regressor

    def design(data):
        q, qd, qdd, tau, params = (x.double() for x in stacked_points(data, stride))
        Y = _regressor(chain, q, qd, qdd, drive).reshape(-1, 12 * chain.dof)
        return Y, qd, (tau - payload_torque(chain, q, qd, qdd, params)).reshape(-1), tau.shape

    Y, qd, tau, _ = design(train)
    Yv, qdv, tauv, shape = design(val)
    U, S, Vh = torch.linalg.svd(Y, full_matrices=False)
    keep = S > RANK_RTOL * S[0]
    U, S, Vh = U[:, keep], S[keep], Vh[keep]
    forms = [f for f in drive.linear_forms if f != "viscous"]
    errors = {}
    # the Coulomb smoothing only where a form reads it (else the drive's stands)
    smoothings = {configured.coulomb_velocity, *COULOMB_VELOCITIES} if {"coulomb", "stribeck"} & set(drive.forms) \
        else {drive.coulomb_velocity}
    saturations = sorted({configured.saturation_velocity, *SATURATION_VELOCITIES})
    for vc in sorted(smoothings):
        for vd in saturations:
            # beside a Coulomb term, a pair whose mirror (v_d, v_c) is tried too is tried once, with v_d above v_c:
            # the two tanh terms swap roles, the same least-squares model (a tie that round-off decided,
            # differently from run to run); at v_d = v_c they are one column twice
            if "coulomb" in drive.forms and (vd == vc or (vd < vc and vd in smoothings and vc in saturations)):
                continue
            at = dataclasses.replace(drive, coulomb_velocity=vc, saturation_velocity=vd)
            F, Fv = (_friction_columns(x, at, forms).reshape(-1, len(forms) * chain.dof) for x in (qd, qdv))
            # Frisch-Waugh: the friction coefficients from the parts of F and tau the rigid body leaves
            beta = torch.linalg.lstsq(F - U @ (U.mT @ F), tau - U @ (U.mT @ tau)).solution
            theta = Vh.mT @ ((U.mT @ (tau - F @ beta)) / S)
            residual = (Yv @ theta + Fv @ beta - tauv).reshape(shape)
            errors[(vc, vd)] = float(residual.pow(2).mean(0).sqrt().mean())
    best = min(errors, key=errors.get)
    per_velocity = {}
    for (_, vd), error in errors.items():
        per_velocity[vd] = min(per_velocity.get(vd, float("inf")), error)
    return best, per_velocity


def _near(prior: float, priors) -> list[float]:
    """``prior`` and those of ``priors`` within a factor 3.5 of it (the neighbours a candidate form is fitted at)."""
    return sorted({prior} | {p for p in priors if prior / 3.5 <= p <= 3.5 * prior})


def _validation_error(fit) -> float:
    """The validation torque error (mean over joints of each joint's RMS, N m) of a consistent fit at its
    chosen prior (NaN without validation data)."""
    selection = fit.info.get("prior_selection")
    return float("nan") if selection is None else selection["validation_rms_mean"][f"{fit.info['prior']:g}"]


def _sub_forms(drive) -> list:
    """The drive model less one of its terms (but those kept on evidence only, ``ON_EVIDENCE``), each (the forms
    validation chooses among)."""
    if len(drive.forms) < 2:
        return []
    return [drive.with_forms([f for f in drive.forms if f != gone]) for gone in drive.forms if gone not in ON_EVIDENCE]
