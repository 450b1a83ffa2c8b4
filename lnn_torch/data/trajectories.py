"""``Trajectories``: whole trajectories of a dataset split in memory, as evaluations consume them."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import torch


@dataclass
class Trajectories:
    """Trajectories sampled every ``dt`` seconds (SI units, float64 unless converted).

    Attributes:
        q, qd: ``(B, T, dof)`` coordinates and velocities.
        params: ``(B, P)`` physical parameters, one vector per trajectory.
        dt: sampling interval, s.
        qdd: ``(B, T, dof)`` accelerations (targets), or None where none are known.
        index: ``(B,)`` trajectory indices in their file, or None.
        tau: ``(B, T, n_u)`` inputs (N m), sample ``k`` held over ``[t_k, t_{k+1})``; None for an
            unactuated system.
        lengths: ``(B,)`` points of each trajectory, the rest NaN padding (recordings of different
            lengths); None: all ``T``.
    """

    q: torch.Tensor
    qd: torch.Tensor
    params: torch.Tensor
    dt: float
    qdd: torch.Tensor | None = None
    index: torch.Tensor | None = None
    tau: torch.Tensor | None = None
    lengths: torch.Tensor | None = None

    def __post_init__(self) -> None:
        B, T, dof = self.q.shape
        if self.qd.shape != self.q.shape or (self.qdd is not None and self.qdd.shape != self.q.shape):
            raise ValueError(f"trajectories: q, qd and qdd shapes differ: {tuple(self.q.shape)}, "
                             f"{tuple(self.qd.shape)}, {None if self.qdd is None else tuple(self.qdd.shape)}")
        if self.params.ndim != 2 or self.params.shape[0] != B:
            raise ValueError(f"trajectories: params must be ({B}, P), got {tuple(self.params.shape)}")
        if not self.dt > 0:
            raise ValueError(f"trajectories: dt must be positive, got {self.dt}")
        if self.tau is not None and (self.tau.ndim != 3 or self.tau.shape[:2] != (B, T)):
            raise ValueError(f"trajectories: tau must be ({B}, {T}, n_u), got {tuple(self.tau.shape)}")

    def __len__(self) -> int:
        return self.q.shape[0]

    @property
    def num_points(self) -> int:
        return self.q.shape[1]

    @property
    def dof(self) -> int:
        return self.q.shape[2]

    def valid_lengths(self) -> list[int]:
        """Each trajectory's number of points (the rest of ``T`` is NaN padding)."""
        return [self.num_points] * len(self) if self.lengths is None else [int(n) for n in self.lengths]

    def entry(self, j: int) -> Trajectories:
        """Trajectory ``j`` alone (a batch of one)."""
        return self._map(lambda x: x[j:j + 1])

    def head(self, n: int | None) -> Trajectories:
        """The first ``n`` trajectories (all for None)."""
        if n is None or n >= len(self):
            return self
        return self._map(lambda x: x[:n])

    def to(self, *args, **kwargs) -> Trajectories:
        """Every tensor ``.to(*args, **kwargs)`` (device, floating dtype; the index keeps its dtype)."""
        return self._map(lambda x: x.to(*args, **kwargs) if x.is_floating_point() else x)

    def _map(self, fn) -> Trajectories:
        return replace(self, **{f.name: fn(getattr(self, f.name)) for f in fields(self)
                                if isinstance(getattr(self, f.name), torch.Tensor)})


def points(data, stride: int = 1) -> list[torch.Tensor]:
    """``q, qd, qdd, tau, params`` at the valid points of every trajectory (every ``stride``-th), float64."""
    out = {k: [] for k in ("q", "qd", "qdd", "tau", "params")}
    for j, n in enumerate(data.valid_lengths()):
        for k in ("q", "qd", "qdd", "tau"):
            out[k].append(getattr(data, k)[j, :n:stride].double())
        out["params"].append(data.params[j].double().expand(len(out["q"][-1]), -1))
    return [torch.cat(v) for v in out.values()]
