"""Joint reference trajectories for identification experiments: a finite Fourier series per joint (the
periodic excitation trajectories of robot identification), sampled at random and scaled to the arm's
limits.

    q_ref_j(t) = c_j + sum_{h=1..H} A_jh sin(2 pi h f0 t + phi_jh)

``f0`` the base frequency (Hz), ``H`` harmonics; ``qd_ref``, ``qdd_ref`` its exact derivatives. Arrays
are float64 numpy, ``(T, n)`` over the sample times ``t (T,)`` s for ``n`` joints; rad, rad/s, rad/s^2.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import InputError


@dataclass(frozen=True)
class FourierReference:
    """``centre (n,)`` rad, ``amplitude (n, H)`` rad, ``phase (n, H)`` rad, ``base_frequency`` f0 in Hz."""

    centre: np.ndarray
    amplitude: np.ndarray
    phase: np.ndarray
    base_frequency: float

    @property
    def omegas(self) -> np.ndarray:
        """The harmonics' angular frequencies ``2 pi h f0``, ``(H,)`` rad/s."""
        return 2 * np.pi * self.base_frequency * np.arange(1, self.amplitude.shape[1] + 1)

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(q, qd, qdd)`` at the times ``t (T,)`` s, each ``(T, n)``."""
        w = self.omegas
        arg = np.asarray(t, dtype=np.float64)[:, None, None] * w + self.phase  # (T, n, H)
        s, c = np.sin(arg), np.cos(arg)
        q = self.centre + (self.amplitude * s).sum(-1)
        qd = (self.amplitude * w * c).sum(-1)
        qdd = -(self.amplitude * w**2 * s).sum(-1)
        return q, qd, qdd

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Upper bounds ``(n,)`` of ``|q - centre|`` (rad) and of ``|qd|`` (rad/s) over all time:
        ``sum_h A_h`` and ``sum_h A_h 2 pi h f0``."""
        return self.amplitude.sum(-1), (self.amplitude * self.omegas).sum(-1)

    def scaled(self, factor) -> FourierReference:
        """The same reference with its amplitudes times ``factor`` (a number or ``(n,)``), centre kept."""
        return replace(self, amplitude=self.amplitude * np.reshape(np.asarray(factor, dtype=np.float64), (-1, 1)))


def sample_reference(rng: np.random.Generator, low, high, velocity_limit, base_frequency: float,
                     harmonics: int, margin: float) -> FourierReference:
    """A random reference for joints with ranges ``[low, high]`` ``(n,)`` rad that stays ``margin`` rad
    inside them and below ``velocity_limit (n,)`` rad/s at all times (by the bounds of ``bounds()``).

    Per joint: the centre uniform over the middle half of the range shrunk by ``margin``; amplitudes
    ``U(0, 1) / h`` (a falling spectrum) and phases ``U(0, 2 pi)``; then the amplitudes scaled to the
    largest excursion both limits allow, times ``U(0.5, 1)`` (the level varies between trajectories).
    Draws, in this order: centres ``(n,)``, amplitudes ``(n, H)``, phases ``(n, H)``, levels ``(n,)``.
    """
    low, high = np.asarray(low, dtype=np.float64) + margin, np.asarray(high, dtype=np.float64) - margin
    velocity_limit = np.asarray(velocity_limit, dtype=np.float64)
    if not (high > low).all():
        raise InputError(f"joint margin {margin} rad leaves no room inside the joint ranges")
    if not (np.isfinite(velocity_limit).all() and (velocity_limit > 0).all()):
        raise InputError(f"velocity limits must be positive, got {velocity_limit.tolist()}")
    if not (np.isfinite(base_frequency) and base_frequency > 0) or int(harmonics) < 1:
        raise InputError(f"a Fourier reference needs base_frequency > 0 Hz and harmonics >= 1, got "
                         f"{base_frequency}, {harmonics}")
    n, H = len(low), int(harmonics)
    mid, half = (low + high) / 2, (high - low) / 2
    centre = mid + half * rng.uniform(-0.5, 0.5, n)
    raw = FourierReference(centre, rng.uniform(0, 1, (n, H)) / np.arange(1, H + 1), rng.uniform(0, 2 * np.pi, (n, H)),
                           float(base_frequency))
    excursion, speed = raw.bounds()
    room = np.minimum(centre - low, high - centre)
    scale = np.minimum(room / excursion, velocity_limit / speed) * rng.uniform(0.5, 1.0, n)
    return raw.scaled(scale)


def within_torque(reference: FourierReference, t: np.ndarray, inverse_fn, torque_limit, shrink: float = 0.8,
                  max_shrinks: int = 20) -> tuple[FourierReference, float]:
    """The reference with its amplitudes shrunk (times ``shrink``, at most ``max_shrinks`` times) until
    the torques it needs, ``inverse_fn(q, qd, qdd) -> (T, n)`` N m at the times ``t``, stay within
    ``torque_limit (n,)`` N m. Returns the reference and the largest ratio ``|tau_j| / limit_j`` it
    needs (above 1 where even the last shrink did not suffice: gravity alone exceeds the limit)."""
    limit = np.asarray(torque_limit, dtype=np.float64)
    for k in range(max_shrinks + 1):
        tau = np.asarray(inverse_fn(*reference.evaluate(t)))
        ratio = float(np.abs(tau / limit).max())
        if ratio <= 1 or k == max_shrinks:
            break
        reference = reference.scaled(shrink)
    return reference, ratio
