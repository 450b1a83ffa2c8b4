"""``lnn-torch generate``: write a ground-truth trajectory dataset (HDF5)."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from ..systems import SYSTEMS
from .parser import CommandParser


class _DefaultsHelp(argparse.ArgumentDefaultsHelpFormatter):
    """Defaults in the help, except where the help already says its default or there is none."""

    def _get_help_string(self, action):
        text = action.help or ""
        if "default" in text or action.default is None or action.default is False or \
                action.default is argparse.SUPPRESS:  # (a default of 0 is shown: 0 == False)
            return text
        return super()._get_help_string(action)


def _generate_parser() -> argparse.ArgumentParser:
    p = CommandParser(
        prog="lnn-torch generate",
        description=(
            "Generate a ground-truth trajectory dataset (HDF5): closed-form accelerations, seeded per "
            "trajectory, integrated in float64 with a fixed-step 8th-order Runge-Kutta method. "
            "The default is the reference double-pendulum set: 2000 trajectories x 20 s at dt=0.005 s."
        ),
        formatter_class=_DefaultsHelp,
    )
    p.add_argument("--scene", default="double_pendulum",
                   help=f"scene: one of {', '.join(sorted(n for n, c in SYSTEMS.items() if c.closed_form))}")
    p.add_argument("--scene-config", default="{}", metavar="JSON",
                   help='sampler ranges of the scene as JSON, e.g. \'{"l1_range": [1.0, 1.5]}\'')
    p.add_argument("--num-trajectories", "-n", type=int, default=2000, help="trajectories in all splits")
    p.add_argument("--duration", type=float, default=20.0, help="seconds per trajectory")
    p.add_argument("--dt", type=float, default=0.005, help="sampling interval, s")
    p.add_argument("--seed", type=int, default=0, help="seed of the parameters and initial states")
    p.add_argument("--split", type=float, nargs=3, default=(0.8, 0.1, 0.1), metavar=("TRAIN", "VAL", "TEST"),
                   help="fractions of the trajectories (default: 0.8 0.1 0.1)")
    p.add_argument("--integrator", default="rk8", help="fixed-step integrator for the ground truth")
    p.add_argument("--substeps", type=int, default=None,
                   help="integrator steps per sampling interval (default: the scene's ground_truth_substeps: 1, "
                        "8 for actuated_double_pendulum, 4 for robot_arm)")
    p.add_argument("--targets", choices=("analytic", "finite_difference"), default="analytic",
                   help="qdd targets: closed form (default) or finite differences of qd")
    p.add_argument("--output", "-o", default=None, help="output file (default: data/<scene>.h5)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.add_argument("--threads", type=int, default=2, help="torch threads")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


# what generation holds at its peak per byte of the arrays it writes (measured: 661 MB for an 86 MiB file)
PEAK_PER_BYTE = 4.5


def _memory_estimate(args) -> str | None:
    """A refusal where the arrays of the dataset asked for, held in memory while they are generated, would not fit
    in this machine's memory (a NumPy memory error, or minutes of nothing, before); None where they fit."""
    import os

    from ..systems import get_system

    try:
        system = get_system(args.scene, **json.loads(args.scene_config))
        points = int(round(args.duration / args.dt)) + 1
    except (ValueError, TypeError, ZeroDivisionError, OverflowError):
        return None  # (the specification's own checks name the problem)
    columns = 3 * system.dof + 1 + getattr(system, "num_inputs", 0) + 2
    need = PEAK_PER_BYTE * 8.0 * args.num_trajectories * points * columns
    try:
        have = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None
    if need <= 0.8 * have:
        return None
    n = args.num_trajectories
    return (f"{n} trajector{'y' if n == 1 else 'ies'} of {points} points need about {need / 2**30:.3g} GiB of memory "
            f"while they are generated, this machine has {have / 2**30:.3g} GiB: fewer trajectories, a shorter "
            "duration or a larger dt (or several files)")


def main(argv: list[str]) -> int:
    from ..data import DatasetSpec, generate_dataset, read_dataset

    args = _generate_parser().parse_args(argv)
    for name in ("seed", "threads"):
        value = getattr(args, name)
        if value < (0 if name == "seed" else 1):
            raise ValueError(f"--{name} must be {'>= 0' if name == 'seed' else 'a positive number of threads'}, "
                             f"got {value}")
    estimate = _memory_estimate(args)
    if estimate is not None:
        raise ValueError(estimate)
    try:
        scene_config = json.loads(args.scene_config)
    except json.JSONDecodeError as err:
        raise ValueError(f"--scene-config is not valid JSON: {err}") from None
    spec = DatasetSpec(scene=args.scene, scene_config=scene_config, num_trajectories=args.num_trajectories,
                       duration=args.duration, dt=args.dt, seed=args.seed, split=tuple(args.split),
                       integrator=args.integrator, substeps=args.substeps, targets=args.targets)
    output = Path(args.output or f"data/{args.scene}.h5")
    start = time.perf_counter()
    path = generate_dataset(spec, output, overwrite=args.overwrite, progress=not args.no_progress,
                            num_threads=args.threads)
    size = path.stat().st_size / 2**20
    print(f"wrote {path.resolve()} ({size:.1f} MiB; {spec.num_trajectories} trajectories x {spec.num_points} points) "
          f"in {time.perf_counter() - start:.1f} s")
    checked = json.loads(read_dataset(path).attrs.get("tolerances", "{}") or "{}")
    if checked.get("refined_trajectories"):
        print(f"note: {checked['refined_trajectories']} of {spec.num_trajectories} trajectories failed the "
              f"{spec.integrator} pass's accuracy check and were integrated again with adaptive DOP853 steps "
              "(the file's tolerances attribute; its data are those)")
    return 0
