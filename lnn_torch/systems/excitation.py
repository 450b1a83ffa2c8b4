"""Seeded excitation signals for the inputs of actuated scenes (motor torques), sampled at the data rate.

An excitation is a dict (recorded in every dataset file):

* ``kind``: ``"multisine"`` (a sum of sines with random phases over a frequency band, the classic
  identification signal), ``"steps"`` (piecewise-constant levels held for random durations),
  ``"chirp"`` (a linear frequency sweep over the band), ``"none"`` (zero inputs: free motion), or a
  list of these, one chosen per trajectory;
* ``amplitude``: the peak value per input (a number or one per input, N m); every signal is clipped
  to it (the actuator limit);
* ``band``: ``[f_low, f_high]`` in Hz (multisine, chirp); ``num_sines`` (multisine);
  ``hold``: ``[min, max]`` hold durations in s (steps).

The samples are held over each sample interval (zero-order hold): input ``k`` acts on ``[t_k, t_{k+1})``.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError

KINDS = ("multisine", "steps", "chirp", "none")
DEFAULTS = {"band": [0.1, 2.0], "num_sines": 6, "hold": [0.2, 1.0]}


def validate(excitation: dict, num_inputs: int) -> dict:
    """The excitation with defaults filled in; ``ValueError`` naming what is wrong."""
    if not excitation:
        return {"kind": "none"}
    ex = {**DEFAULTS, **excitation}
    kinds = ex.get("kind", "multisine")
    kinds = [kinds] if isinstance(kinds, str) else list(kinds)
    unknown = [k for k in kinds if k not in KINDS]
    if unknown or not kinds:
        raise InputError(f"excitation kind must be one of {', '.join(KINDS)} (or a list of them), "
                         f"got {ex.get('kind')!r}")
    if num_inputs == 0 and kinds != ["none"]:
        raise InputError("an excitation was given, but the scene has no inputs (it is not actuated)")
    amplitude = ex.get("amplitude", 1.0)
    amplitude = [float(amplitude)] * num_inputs if np.isscalar(amplitude) else [float(a) for a in amplitude]
    if len(amplitude) != num_inputs or not all(math.isfinite(a) and a >= 0 for a in amplitude):
        raise InputError(f"excitation amplitude must be one value >= 0 or {num_inputs} of them (one per input), "
                         f"got {ex.get('amplitude')!r}")
    lo, hi = (float(f) for f in ex["band"])
    if not (0 < lo <= hi):
        raise InputError(f"excitation band must be [f_low, f_high] with 0 < f_low <= f_high (Hz), got {ex['band']!r}")
    h0, h1 = (float(h) for h in ex["hold"])
    if not (0 < h0 <= h1):
        raise InputError(f"excitation hold must be [min, max] durations > 0 (s), got {ex['hold']!r}")
    if int(ex["num_sines"]) < 1:
        raise InputError(f"excitation num_sines must be >= 1, got {ex['num_sines']!r}")
    return {**ex, "kind": kinds[0] if len(kinds) == 1 else kinds, "amplitude": amplitude, "band": [lo, hi],
            "hold": [h0, h1], "num_sines": int(ex["num_sines"])}


def sample(excitation: dict, rng: np.random.Generator, t: np.ndarray, num_inputs: int) -> np.ndarray:
    """One trajectory's inputs ``(len(t), num_inputs)`` (float64) at the sample times ``t`` (s)."""
    ex = validate(excitation, num_inputs)
    kinds = ex["kind"] if isinstance(ex["kind"], list) else [ex["kind"]]
    kind = kinds[int(rng.integers(len(kinds)))] if len(kinds) > 1 else kinds[0]
    out = np.zeros((len(t), num_inputs))
    lo, hi = ex["band"]
    for j, amp in enumerate(ex["amplitude"]):
        if kind == "none" or amp == 0:
            continue
        if kind == "multisine":
            f = np.exp(rng.uniform(np.log(lo), np.log(hi), ex["num_sines"]))  # log-uniform over the band
            phase = rng.uniform(0, 2 * np.pi, ex["num_sines"])
            u = np.sin(2 * np.pi * f[None] * t[:, None] + phase[None]).sum(-1)
            u *= amp / max(np.abs(u).max(), 1e-12) * rng.uniform(0.5, 1.0)
        elif kind == "steps":
            u, k = np.empty(len(t)), 0
            while k < len(t):
                n = max(1, int(round(rng.uniform(*ex["hold"]) / max(t[1] - t[0], 1e-12)))) if len(t) > 1 else 1
                u[k:k + n] = rng.uniform(-amp, amp)
                k += n
        else:  # chirp: a linear sweep from lo to hi (or back) over the trajectory
            duration = max(t[-1] - t[0], 1e-12)
            f0, f1 = (lo, hi) if rng.random() < 0.5 else (hi, lo)
            phase = 2 * np.pi * (f0 * t + 0.5 * (f1 - f0) * t**2 / duration) + rng.uniform(0, 2 * np.pi)
            u = amp * rng.uniform(0.5, 1.0) * np.sin(phase)
        out[:, j] = np.clip(u, -amp, amp)
    return out
