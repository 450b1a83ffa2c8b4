"""Velocities and accelerations from measured positions (and velocities), for training without true
accelerations. Zero-phase methods only (no lag):

* ``finite_difference``: second-order central differences (``np.gradient``), of the positions (twice),
  or of the measured velocities once: what the reference design does; noise is amplified by 1/dt^2;
* ``butterworth``: a zero-phase low-pass (``scipy.signal.butter`` + ``filtfilt``, ``order``,
  ``cutoff`` in Hz) of the positions (or of the measured velocities), then central differences; each
  end is first extended by the cubic fitted to its last period of the cutoff (``_extended``), so the
  derivatives hold up to the recording's ends;
* ``savgol``: Savitzky-Golay fits (``window`` in samples, ``polyorder``) giving the smoothed signal and
  its derivatives directly;
* ``spline``: a smoothing spline per coordinate (``scipy.interpolate.make_smoothing_spline``,
  ``lam`` in s^3; default: generalised cross-validation, ``gcv_lambda``) and its derivatives.

``use_measured_velocity``: where velocities were measured, take them (smoothed the same way) as the
velocity and differentiate them once for the acceleration, instead of differentiating positions
twice. Every setting is recorded (``describe``).
"""

from __future__ import annotations

import numpy as np
import torch

from ..errors import InputError

METHODS = ("finite_difference", "butterworth", "savgol", "spline")
DEFAULTS = {"finite_difference": {}, "butterworth": {"cutoff": 10.0, "order": 4},
            "savgol": {"window": 31, "polyorder": 3}, "spline": {"lam": None}}


def settings(targets: dict | str | None) -> dict | None:
    """The derivative settings with defaults filled in (None: use the file's accelerations)."""
    if targets in (None, "file", {}):
        return None
    if isinstance(targets, str):
        targets = {"method": targets}
    method = targets.get("method")
    if method not in METHODS:
        raise InputError(f"targets method must be one of file, {', '.join(METHODS)}; got {method!r}")
    out = {"method": method, "use_measured_velocity": _flag(targets.get("use_measured_velocity", True)),
           **DEFAULTS[method], **{k: v for k, v in targets.items() if k not in ("method", "use_measured_velocity")}}
    unknown = set(out) - {"method", "use_measured_velocity", *DEFAULTS[method]}
    if unknown:
        raise InputError(f"targets method '{method}' takes no setting {', '.join(sorted(unknown))}")
    for key in DEFAULTS[method]:  # a command-line override (--data.targets.cutoff=25) arrives as text
        out[key] = _number(key, out[key], integer=key in ("order", "window", "polyorder"))
    if method == "savgol" and (int(out["window"]) % 2 == 0 or int(out["window"]) <= int(out["polyorder"])):
        raise InputError("savgol window must be odd and larger than polyorder, "
                         f"got {out['window']}, {out['polyorder']}")
    return out


def _flag(value) -> bool:
    if isinstance(value, str) and value.strip().lower() in ("true", "false"):
        return value.strip().lower() == "true"
    if isinstance(value, (bool, int)):
        return bool(value)
    raise InputError(f"targets use_measured_velocity must be true or false, got {value!r}")


def _number(key: str, value, integer: bool):
    """A targets setting as a number (``lam`` may be None: chosen by the spline's own criterion)."""
    if value is None and key == "lam":
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InputError(f"targets {key} must be a number, got {value!r}") from None
    if integer:
        if number != int(number):
            raise InputError(f"targets {key} must be a whole number, got {value!r}")
        return int(number)
    return number


def _smooth(x: np.ndarray, dt: float, s: dict, deriv: int) -> np.ndarray:
    """The smoothed signal (``deriv`` 0) or its first or second derivative along axis 0 of ``x (T, n)``."""
    method = s["method"]
    if method == "savgol":
        from scipy.signal import savgol_filter

        window = min(int(s["window"]), len(x) - (1 - len(x) % 2))
        return savgol_filter(x, window, int(s["polyorder"]), deriv=deriv, delta=dt, axis=0)
    if method == "spline":
        from scipy.interpolate import make_smoothing_spline

        t = dt * np.arange(len(x))
        out = []
        for j in range(x.shape[1]):
            lam = s["lam"] if s["lam"] is not None else gcv_lambda(t, x[:, j])
            spline = make_smoothing_spline(t, x[:, j], lam=lam)
            out.append(spline.derivative(deriv)(t) if deriv else spline(t))
        return np.stack(out, -1)
    y = x
    if method == "butterworth":
        from scipy.signal import butter, filtfilt

        nyquist = 0.5 / dt
        if not 0 < s["cutoff"] < nyquist:
            raise InputError(f"butterworth cutoff must lie in (0, {nyquist:g}) Hz (the Nyquist frequency), "
                             f"got {s['cutoff']}")
        b, a = butter(int(s["order"]), s["cutoff"] / nyquist)
        settle = max(4, int(round(1.0 / (s["cutoff"] * dt))))  # samples in one period of the cutoff
        padded, pad = _extended(x, 3 * settle, settle)
        y = filtfilt(b, a, padded, axis=0, padlen=min(3 * max(len(a), len(b)), len(padded) - 1))
        y = y[pad:len(y) - pad]
    for _ in range(deriv):
        y = np.gradient(y, dt, axis=0, edge_order=2)
    return y


# the least smoothing GCV may choose, in units of dt^3 (half a sample: below it the spline all but interpolates,
# and its piecewise-linear second derivative is coarse where the motion is fast against the sampling)
GCV_FLOOR = 0.5
GCV_PROBES = 8  # random probes of the hat matrix's trace (Hutchinson's estimator)


def gcv_lambda(t: np.ndarray, y: np.ndarray) -> float:
    """The smoothing ``lam`` (s^3) of a cubic smoothing spline through ``y (T,)`` at uniform times ``t`` that
    minimises generalised cross-validation, ``T RSS / (T - tr A)^2`` (``tr A``, the hat matrix's trace, from
    ``GCV_PROBES`` fixed random probes), over a logarithmic range from ``GCV_FLOOR dt^3``. (SciPy's own choice,
    ``lam=None``, searches a linear range with an absolute tolerance of 1e-5 s^3, which at 200 Hz and above is
    coarser than the smoothing the noise asks for: the accelerations were over-smoothed, identification's
    lengths biased by 0.2-1 %, worse at higher rates.)"""
    from scipy.interpolate import make_smoothing_spline
    from scipy.optimize import minimize_scalar

    n = len(y)
    dt = (t[-1] - t[0]) / (n - 1)
    probes = np.random.default_rng(0).choice([-1.0, 1.0], (n, GCV_PROBES))
    stacked = np.column_stack([y, probes])

    def smooth(lam: float) -> np.ndarray:  # SciPy before 1.16 fits one column at a time
        try:
            return make_smoothing_spline(t, stacked, lam=lam)(t)
        except ValueError:
            return np.column_stack([make_smoothing_spline(t, c, lam=lam)(t) for c in stacked.T])

    def score(log_lam: float) -> float:
        fit = smooth(float(np.exp(log_lam)))
        trace = float(np.mean(np.sum(probes * fit[:, 1:], 0)))
        return n * float(np.sum((fit[:, 0] - y) ** 2)) / max(n - trace, 1e-9) ** 2

    grid = np.linspace(np.log(GCV_FLOOR * dt ** 3), np.log(1e8 * dt ** 3), 17)
    k = int(np.argmin([score(g) for g in grid]))
    if k == 0:
        return float(np.exp(grid[0]))
    best = minimize_scalar(score, bounds=(grid[k - 1], grid[min(k + 1, len(grid) - 1)]), method="bounded",
                           options={"xatol": 1e-2})
    return float(np.exp(best.x))


def _extended(x: np.ndarray, pad: int, fit: int) -> tuple[np.ndarray, int]:
    """``x (T, n)`` extended at each end by ``pad`` samples of the cubic fitted (least squares) to its
    ``fit`` samples there, and ``pad`` (0 for a series too short to fit). A zero-phase filter's start-up
    transient then runs in the extension: the usual odd reflection keeps value and slope at an end but
    makes the curvature zero there, so the second derivative of the filtered signal was wrong within
    about a period of the cutoff of each end."""
    fit = min(fit, len(x))
    if fit < 8 or pad < 1:
        return x, 0
    t = np.arange(fit, dtype=np.float64) - (fit - 1) / 2  # centred: a well-conditioned fit
    V = np.vander(t, 4)
    ends = []
    for block, steps in ((x[:fit], np.arange(-pad, 0) - (fit - 1) / 2),
                         (x[len(x) - fit:], np.arange(fit, fit + pad) - (fit - 1) / 2)):
        coef = np.linalg.lstsq(V, block.reshape(fit, -1), rcond=None)[0]
        ends.append((np.vander(steps, 4) @ coef).reshape(pad, *x.shape[1:]))
    return np.concatenate([ends[0], x, ends[1]]), pad


def estimate(q: np.ndarray, dt: float, s: dict, qd: np.ndarray | None = None):
    """``(qd, qdd)`` estimates ``(T, dof)`` from positions ``q (T, dof)`` (and measured ``qd``) of ONE
    recording sampled every ``dt`` s, with the settings ``s`` (``settings``)."""
    if s["use_measured_velocity"] and qd is not None and np.isfinite(qd).all():
        return _smooth(qd, dt, s, 0), _smooth(qd, dt, s, 1)
    return _smooth(q, dt, s, 1), _smooth(q, dt, s, 2)


def smooth_inputs(tau: np.ndarray, dt: float, s: dict) -> np.ndarray:
    """The inputs ``tau (T, n_u)`` of ONE recording through the same smoothing as the targets (the
    smoothed signal itself, no derivative): with both sides of ``M qdd + ... = B tau`` filtered alike,
    noise in the recorded inputs no longer biases a fit of accelerations to them."""
    return _smooth(tau, dt, s, 0)


def describe(s: dict | None) -> str:
    if s is None:
        return "the file's accelerations"
    rest = ", ".join(f"{k} = {v}" for k, v in s.items() if k not in ("method", "use_measured_velocity"))
    source = "measured velocities (differentiated once)" if s["use_measured_velocity"] else "positions"
    return f"{s['method']} of the {source}" + (f" ({rest})" if rest else "")


# default derivative estimates, chosen per observation from its noise: a short quartic Savitzky-Golay
# fit where the positions are smooth to NOISE_FREE (exact to ~1e-6 of the rms on noise-free motion at
# 200 Hz), else a smoothing spline with its smoothing chosen by generalised cross-validation (``gcv_lambda``)
SMOOTH = {"method": "savgol", "window": 11, "polyorder": 4}
NOISY = {"method": "spline", "lam": None}
NOISE_FREE = 1e-6


def position_noise(q: np.ndarray) -> float:
    """The rms deviation of ``q (T, dof)`` from its short quartic Savitzky-Golay fit, corrected for the
    fit's own share: an estimate of white position noise (~0 for smooth noise-free motion)."""
    from scipy.signal import savgol_coeffs, savgol_filter

    h = float(savgol_coeffs(SMOOTH["window"], SMOOTH["polyorder"])[SMOOTH["window"] // 2])
    e = q - savgol_filter(q, SMOOTH["window"], SMOOTH["polyorder"], axis=0)
    return float(np.sqrt(np.mean(e[SMOOTH["window"]:-SMOOTH["window"]] ** 2) / max(1 - h, 1e-6)))


def estimate_derivatives(q: torch.Tensor, dt: float, qd: torch.Tensor | None = None, qdd: torch.Tensor | None = None,
                         derivative: dict | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Velocities and accelerations ``(N, T, dof)`` (rad/s and rad/s², or m/s and m/s²) of observed
    positions ``q (N, T, dof)`` sampled every ``dt`` s: those given, else estimated (``derivative``:
    ``settings``; None: chosen from each observation's noise, ``SMOOTH`` or
    ``NOISY``). A given ``qd`` is used by the estimate of ``qdd``."""
    if qd is not None and qdd is not None:
        return qd, qdd
    est = []
    for i in range(len(q)):
        choice = derivative or (SMOOTH if position_noise(q[i].numpy()) < NOISE_FREE else NOISY)
        s = settings({**choice, "use_measured_velocity": qd is not None})
        est.append(estimate(q[i].numpy(), dt, s, None if qd is None else qd[i].numpy()))
    return (qd if qd is not None else torch.as_tensor(np.stack([e[0] for e in est])),
            qdd if qdd is not None else torch.as_tensor(np.stack([e[1] for e in est])))
