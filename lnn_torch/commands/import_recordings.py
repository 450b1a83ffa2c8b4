"""``lnn-torch import``: recordings of a real system (CSV files or ROS bags) -> an lnn_torch HDF5 dataset.

One CSV per recording (``.csv`` or ``.csv.gz``; ``,``, ``;`` or tab delimited, as the header shows), a
header row naming the columns. Name the columns of time, coordinates and (optionally) velocities and
inputs; declare the units (``--time-units``, ``--angle-units``, ``--length-units``) and the angle
convention. Each recording is linearly interpolated onto a uniform grid (``--dt``; default the
median sampling interval, the same in every recording) and split by recording (``--split``
fractions, seeded, or ``--split-recordings``; a recording is named by its file name without ``.gz``
and ``.csv``). Settings can also come from a YAML file (``--config``; the fields of
``lnn_torch.data.importer.ImportSpec``), which the command line overrides.

ROS bags of sensor_msgs/JointState (ROS 2 ``.db3`` or ``.mcap``, the file alone or its rosbag2 folder;
ROS 1 ``.bag``; needs ``pip install 'lnn-torch[bags]'``): the topic (``--topic``, default /joint_states)
and the bag's joint names mapped to the model's in the config (``joints: {bag name: model name}``);
positions, velocities and efforts are read, stale repeated messages dropped and counted. For every
log with inputs the delay of the torques behind the positions is estimated and printed (applied with
``--torque-delay auto`` or a number of seconds).

    lnn-torch import recordings/*.csv -o data/arm.h5 --coordinates pos1 pos2 --velocities vel1 vel2 \\
        --inputs tau1 tau2 --angle-combination 1 1 --conventions "q2 relative to link 1"
    lnn-torch import ../shared/data/ros2_bags/panda_exciting_trajectory.db3 \\
        --config configs/import/franka_bag.yaml -o data/franka_bag.h5
"""

from __future__ import annotations

import argparse
import glob
import json
from pathlib import Path

from ..errors import InputError
from .parser import CommandParser


def _parser() -> argparse.ArgumentParser:
    ap = CommandParser(prog="lnn-torch import", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="+", help="CSV recordings, or ROS bags (.db3, .mcap, .bag, a rosbag2 folder); "
                    "globs are expanded")
    ap.add_argument("--output", "-o", required=True, help="the HDF5 dataset to write")
    ap.add_argument("--config", default=None, help="YAML (or JSON) with ImportSpec fields")
    ap.add_argument("--time", default=None, help="time column (default 'time')")
    ap.add_argument("--time-units", choices=("s", "ms", "us", "ns"), default=None,
                    help="the time column's unit (default s)")
    ap.add_argument("--coordinates", nargs="+", default=None, help="coordinate columns")
    ap.add_argument("--velocities", nargs="+", default=None, help="measured velocity columns (optional)")
    ap.add_argument("--inputs", nargs="+", default=None, help="input columns, e.g. motor torques in N m (optional)")
    ap.add_argument("--currents", nargs="+", default=None, help="motor current columns (A), instead of --inputs")
    ap.add_argument("--drive-gains", nargs="+", type=float, default=None, help="N m per A, one per current column")
    ap.add_argument("--robot", default=None, help="a robot arm's description (shipped name or MJCF/URDF path); "
                    "bodies removed, tool, armature and damping in the config's robot")
    ap.add_argument("--coord-names", nargs="+", default=None)
    ap.add_argument("--input-names", nargs="+", default=None)
    ap.add_argument("--angle-mask", nargs="+", type=int, default=None, help="1 for an angle coordinate, 0 for a length")
    ap.add_argument("--angle-units", choices=("rad", "deg"), default=None)
    ap.add_argument("--length-units", choices=("m", "cm", "mm"), default=None,
                    help="unit of the coordinates that are lengths and their velocities (default m)")
    ap.add_argument("--delimiter", default=None, help="the files' delimiter, one character, 'tab' or 'whitespace' "
                    "(default: the header's, ';' if it holds one, else a tab if it holds one, else ',')")
    ap.add_argument("--decimal", choices=("auto", ".", ","), default=None,
                    help="decimal mark (default auto: decimal commas too where the delimiter is not ',')")
    ap.add_argument("--conventions", default=None, help="the angle convention in words (recorded)")
    ap.add_argument("--angle-combination", nargs="+", type=float, action="append", default=None,
                    help="an extra feature angle as coefficients over the coordinates (repeatable), e.g. 1 1")
    ap.add_argument("--no-friction", action="store_true", help="models learn no joint friction")
    ap.add_argument("--coulomb-velocity", type=float, default=None, help="Coulomb friction smoothing, rad/s")
    ap.add_argument("--dt", type=float, default=None, help="resampling interval, s")
    ap.add_argument("--max-gap", type=float, default=None,
                    help="longest interval between time stamps interpolated across, s (a window may not cross a "
                    "longer gap)")
    ap.add_argument("--split", type=float, nargs=3, default=None, metavar=("TRAIN", "VAL", "TEST"))
    ap.add_argument("--split-recordings", nargs="+", default=None, metavar="PART=NAME,NAME",
                    help="e.g. train=run1,run2 val=run3 test=run4 (names: file names without .gz, .csv)")
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--topic", default=None, help="a ROS bag's topic of sensor_msgs/JointState (default /joint_states)")
    ap.add_argument("--effort-topic", default=None,
                    help="a ROS bag's topic of the efforts where another than --topic's (JointState of the same "
                    "joints; interpolated to the positions' times)")
    ap.add_argument("--stamps", choices=("auto", "header", "receive", "sequence"), default=None,
                    help="a ROS bag's time: the messages' header stamps, the bag's receive times, sequence (one --dt "
                    "apart), or auto (default: the header stamps unless every one is zero)")
    ap.add_argument("--streams", nargs="+", choices=("position", "velocity", "effort"), default=None,
                    help="the JointState fields a ROS bag's import reads (default all three)")
    ap.add_argument("--torque-delay", default=None, metavar="S|auto|off",
                    help="the inputs' delay behind the positions: estimated and reported by default; 'auto' applies "
                    "the estimate, a number (s) applies that delay, 'off' skips the estimate")
    ap.add_argument("--repeated-rows", choices=("drop", "keep"), default=None,
                    help="rows identical to the previous one while the joints move (default: dropped from bags, "
                    "kept in CSV files; counted either way)")
    ap.add_argument("--label", default=None, help="the system's name (recorded)")
    ap.add_argument("--overwrite", action="store_true")
    return ap


def resolved_robot(robot, base: Path):
    """A robot description setting (a name, a path, or a dict with ``source``) whose file path, where
    relative, is taken relative to ``base`` (the import config's folder) when the file is there, else to
    the working folder, and written absolute: the dataset (and every checkpoint trained on it) then
    finds the description from any folder. A shipped name stays as it is; a file found in neither place is
    refused, naming both."""
    from ..robots import DESCRIPTIONS

    source = robot.get("source") if isinstance(robot, dict) else robot
    if not isinstance(source, str) or source in DESCRIPTIONS or Path(source).is_absolute():
        return robot
    for candidate in (base / source, Path(source)):
        if candidate.exists():
            absolute = str(candidate.resolve())
            return {**robot, "source": absolute} if isinstance(robot, dict) else absolute
    from ..errors import InputError

    raise InputError(f"robot description {source}: no such file beside the import config ({(base / source).resolve()})"
                     f" or from the working folder ({Path(source).resolve()}), and not a shipped one "
                     f"({', '.join(DESCRIPTIONS)})")


def spec_from_args(args):
    from ..data.importer import ImportSpec

    fields: dict = {}
    if args.config:
        from .config_files import read_config

        fields = read_config(args.config, "import config")
        if fields.get("robot") is not None:
            fields["robot"] = resolved_robot(fields["robot"], Path(args.config).resolve().parent)
    flags = {"time": args.time, "time_units": args.time_units, "coordinates": args.coordinates,
             "velocities": args.velocities, "inputs": args.inputs,
             "currents": args.currents, "drive_gains": args.drive_gains,
             "robot": None if args.robot is None else resolved_robot(args.robot, Path.cwd()),
             "coord_names": args.coord_names, "input_names": args.input_names,
             "angle_mask": None if args.angle_mask is None else [bool(a) for a in args.angle_mask],
             "angle_units": args.angle_units, "length_units": args.length_units, "delimiter": args.delimiter,
             "decimal": args.decimal, "conventions": args.conventions,
             "angle_combinations": args.angle_combination, "coulomb_velocity": args.coulomb_velocity, "dt": args.dt,
             "max_gap": args.max_gap, "seed": args.seed, "label": args.label, "topic": args.topic,
             "effort_topic": args.effort_topic,
             "torque_delay": args.torque_delay, "repeated_rows": args.repeated_rows, "stamps": args.stamps,
             "streams": args.streams}
    fields.update({k: v for k, v in flags.items() if v is not None})
    if args.no_friction:
        fields["friction"] = False
    if args.split is not None:
        fields["split"] = list(args.split)
    if args.split_recordings:
        split = {}
        for item in args.split_recordings:
            part, _, names = item.partition("=")
            if part not in ("train", "val", "test") or not names:
                raise InputError(f"--split-recordings takes train=..., val=..., test=...; got {item!r}")
            split[part] = [n for n in names.split(",") if n]
        fields["split"] = split
    if "coordinates" not in fields and "joints" not in fields and fields.get("robot") is None:
        raise InputError("import: name the coordinate columns (--coordinates or the config's coordinates), or a ROS "
                         "bag's joints (the config's joints), or give the robot whose joints they are named as")
    unknown = set(fields) - set(ImportSpec.__dataclass_fields__)
    if unknown:
        raise InputError(f"import config: unknown field(s) {', '.join(sorted(unknown))}")
    return ImportSpec(**fields)


def _beyond(provenance: dict, value, limit: float, unit: str) -> str:
    """The recordings whose ``value(source)`` reaches ``limit``, each with its value (``''``: none)."""
    hits = [(s["file"], value(s)) for s in provenance.get("sources", []) if value(s) >= limit]
    return ", ".join(f"{name} {v:.4g} {unit}" for name, v in hits)


def slow_sampling_note(provenance: dict) -> str | None:
    """One line when a recording's median sampling interval is 0.5 s or more (time stamps in ms, us or ns
    read as seconds?), suggesting ``time_units``; else None."""
    listing = _beyond(provenance, lambda s: (s.get("timing") or {}).get("median_interval_s", 0.0), 0.5, "s")
    if not listing:
        return None
    units = provenance.get("settings", {}).get("time_units", "s")
    return (f"note: median sampling interval {listing} (time column read in {units}): if its stamps are in ms, us "
            "or ns, set time_units (--time-units)")


FAST_ANGLES = 100.0  # rad/s: angles moving faster than this (95th percentile of a recording) were read in a wrong unit?


def fast_angles_note(provenance: dict) -> str | None:
    """One line when a recording's angles move at ``FAST_ANGLES`` or faster (degrees read as radians?: 57 times
    their speed), suggesting ``angle_units``; else None."""
    listing = _beyond(provenance, lambda s: s.get("angle_speed_p95_rad_s", 0.0), FAST_ANGLES, "rad/s")
    if not listing:
        return None
    settings = provenance.get("settings", {})
    units, time_units = settings.get("angle_units", "rad"), settings.get("time_units", "s")
    median = min((s.get("timing") or {}).get("median_interval_s", 1.0) for s in provenance.get("sources", [{}]))
    # (a speed is per second of the time column as read: stamps in s declared as ms make every angle 1000x faster)
    return (f"note: the angles move at up to {listing} (95th percentile; angle columns read in {units}, time in "
            f"{time_units}, median interval {1e3 * median:.3g} ms): if they are in degrees, set angle_units: deg "
            "(--angle-units deg); if the time column is in another unit, set time_units")


def _listed(first: list, count: int) -> str:
    """The first message or line numbers of ``count``, ``...`` where there are more."""
    return ", ".join(str(x) for x in first) + (", ..." if count > len(first) else "")


def source_lines(provenance: dict) -> list[str]:
    """One line per bag read (format, topic, messages, the time's source) and per recording with repeated
    rows (how many, dropped or kept)."""
    lines = []
    for src in provenance.get("sources", []):
        if src.get("format"):
            ignored = f"; ignored joints {', '.join(src['ignored_joints'])}" if src.get("ignored_joints") else ""
            efforts = (f"; efforts from {src['effort_topic']} ({src['effort_messages']} messages, median interval "
                       f"{1e3 * src['effort_median_interval_s']:.3g} ms), interpolated to these messages' times"
                       if src.get("effort_topic") else "")
            lines.append(f"{src['file']}: {src['format']}, topic {src['topic']} ({src['type']}), {src['messages']} "
                         f"messages, time from {src['time']}{ignored}{efforts}")
            for what, left in (src.get("skipped") or {}).items():
                count, first = left["count"], _listed(left["first"], left["count"])
                what, _, topic = what.partition(" on ")  # (messages of the efforts' topic: "... on /topic")
                kind = {"other publisher": f"of another publisher (none of the joints read; theirs: "
                                           f"{', '.join(left.get('joints', []))})",
                        "zero header stamp": "with a zero header stamp (a driver that published before its clock "
                                             "was set)",
                        "repeated": "repeating the one before, stamp and values (stale)",
                        "outside the efforts": f"outside the efforts' times (before the first on "
                                               f"{src.get('effort_topic')}, after the last or in a gap)"
                        }.get(what, f"with no {what[len('empty '):]} values")
                on = f" on {topic}" if topic else ""
                lines.append(f"{src['file']}: {count} message{'s' if count > 1 else ''}{on} {kind} left out "
                             f"(message{'s' if count > 1 else ''} {first})")
            lines.extend(f"{src['file']}: {note}" for note in src.get("notes", []))
        for column, jumps in (src.get("wrapped") or {}).items():
            lines.append(f"{src['file']}: angle {column} wraps into one turn ({jumps} jump{'s' if jumps > 1 else ''} "
                         "of a whole turn between two rows): made continuous")
        rep = src.get("repeated_rows") or {}
        if rep.get("count"):
            at = ("message" if src.get("format") else "line") + ("s" if rep["count"] > 1 else "")
            first = _listed(rep["first"], rep["count"])
            what = "dropped" if rep["dropped"] else "kept (repeated_rows: drop drops them)"
            rows = f"{rep['count']} repeated row{'s' if rep['count'] > 1 else ''}"
            dup = rep.get("duplicates", 0)
            kinds = "identical to the previous one while the joints move: stale"
            if dup == rep["count"]:
                kinds = "exact duplicates of the previous one, the time stamp too"
            elif dup:
                kinds = (f"{rep['count'] - dup} identical to the previous one while the joints move (stale), {dup} "
                         f"exact duplicate{'s' if dup > 1 else ''} (the time stamp too)")
            lines.append(f"{src['file']}: {rows} ({kinds}; {at} {first}) {what}")
    return lines


def recording_paths(patterns: list[str]) -> list[str]:
    """The recordings the command line names: a path that exists as it is written (``run[1].csv`` holds glob
    brackets) taken as it is, else the pattern's matches in sorted order (a shell that left the pattern
    unexpanded), all sorted by name; a file named twice is refused (``pend.csv pend.csv`` became one recording
    without a word)."""
    out = []
    for pattern in patterns:
        out += [pattern] if Path(pattern).exists() else sorted(glob.glob(pattern)) or [pattern]
    seen = {}
    for f in out:
        key = Path(f).resolve()
        if key in seen:
            raise InputError(f"import: {f} is given twice" + (f" (as {seen[key]} too)" if seen[key] != f else ""))
        seen[key] = f
    return sorted(out)


def empty_split_note(split, f, names: list[str]) -> str | None:
    """A note where a split given a fraction holds no recording (too few recordings for the fractions), or None."""
    from ..errors import is_number

    if isinstance(split, dict) and all(is_number(v) for v in split.values()):  # fractions by name
        split = [split.get(part, 0.0) for part in ("train", "val", "test")]
    if not isinstance(split, (list, tuple)):
        return None
    empty = [part for part, fraction in zip(("train", "val", "test"), split, strict=False)
             if float(fraction) > 0 and not len(f.splits.get(part, ()))]
    if not empty:
        return None
    first = names[0] if names else "NAME"
    return (f"note: the fractions {list(split)} of {len(names)} recording{'s' if len(names) != 1 else ''} leave "
            f"{' and '.join({'val': 'validation', 'test': 'test'}.get(p, p) for p in empty)} empty (fractions split "
            f"whole recordings): split recordings in time with windows, e.g. split: {{train: ['{first}[0:60]'], "
            f"val: ['{first}[60:80]'], test: ['{first}[80:]']}} (seconds)")


def main(argv: list[str]) -> int:
    from ..data import read_dataset
    from ..data.bags import delay_lines
    from ..data.importer import import_recordings
    from ..data.resampling import resampling_report

    args = _parser().parse_args(argv)
    files = recording_paths(args.files)
    spec = spec_from_args(args)
    path = import_recordings(files, args.output, spec, overwrite=args.overwrite)
    f = read_dataset(path)
    names = json.loads(f.attrs["recordings"])
    splits = "; ".join(f"{k}: {', '.join(names[i] for i in v)}" for k, v in f.splits.items() if len(v))
    provenance = json.loads(f.attrs["provenance"])
    for line in source_lines(provenance) + resampling_report(provenance):
        print(line)
    delay = provenance.get("torque_delay")
    if delay:
        for line in delay_lines(delay, delay["mode"], delay["applied_s"]):
            print(line)
    if provenance.get("tools"):
        from ..data.import_tools import tool_lines

        for line in tool_lines(provenance["tools"]):
            print(line)
    for note in (slow_sampling_note(provenance), fast_angles_note(provenance), empty_split_note(spec.split, f, names)):
        if note:
            print(note)
    count = f"{f.num_trajectories} recording{'' if f.num_trajectories == 1 else 's'}"
    print(f"wrote {path} ({count}, dt = {f.dt:g} s, up to {f.num_points} points; {splits})")
    return 0
