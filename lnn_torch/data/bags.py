"""Robot logs as robotics users have them: ROS bags of ``sensor_msgs/JointState`` read as the table a CSV
gives, and two checks ``lnn-torch import`` makes of every log (a CSV's too): rows that repeat the previous
one (stale messages), and the delay of the torque stream behind the positions.

Bags: ROS 2 (sqlite3 ``.db3``, MCAP ``.mcap``; the storage file alone, as users often have it, or a rosbag2
folder with its ``metadata.yaml``) and ROS 1 (``.bag``), read by the ``rosbags`` library (the optional extra
``pip install 'lnn-torch[bags]'``). One topic (``ImportSpec.topic``, default ``/joint_states``) of
``sensor_msgs/JointState``; each message is a row: time (s from the first message: its header stamp, or
the bag's receive time where every header stamp is zero; ``stamps``), then the positions, velocities and
efforts of the named joints in the model's order (``coordinates``, ``velocities``, ``inputs``: joints of
the bag; or ``joints``, a mapping of the bag's names to the model's). A joint the mapping needs that a
message lacks, a joint of the bag neither mapped nor in ``ignore_joints``, a short array and a NaN are
refused in one line naming the message (counted from 1 along the topic). Left out, counted and reported
(``info["skipped"]``): messages with none of the joints read (another publisher on the topic, e.g. a gripper's
driver), messages with an empty array of a field read (where no message has that field, the import is refused:
leave it out of ``streams``), and messages with a zero header stamp among wall-clock ones (a driver that
published before its clock was set). Messages received a few cycles late (their stamps behind the latest
before them by at most ``MAX_REORDER_INTERVALS`` median intervals) are sorted by their stamps, and said so.
The recording's name is the file's without ``.db3``, ``.mcap`` or ``.bag`` (a folder's: its name).

Repeated rows (``repeated_rows``): a row identical to the previous one in every imported value while the
joints move (a publisher that sent its last state again) is dropped in a bag by default and counted; in a
CSV it is counted and kept unless ``repeated_rows: drop``. A row at rest (every measured velocity exactly
zero; without velocities, the next row's positions equal) is a legitimate sample and kept; an exact
duplicate (the time stamp repeated too) is dropped whenever rows are dropped. Stamps that go further back than a
few cycles (a clock that jumped), or repeat with other values, are refused as in a CSV.

The torque delay (``torque_delay``): the shift ``d`` of the input columns that best explains them by the state,
``tau(t + d) = f(q(t), qd(t), qdd(t))``: positive where the torques are stamped late (a sensor or bus delay).
Both sides of the regression equation are low-passed alike by a zero-phase filter (4th-order Butterworth,
``min(10 Hz, 0.2 / dt)``): the torques, and the basis below computed from states filtered more widely
(``WIDE_HZ``; accelerations differentiated from the measured velocities where there are), column by column
(filtering the states to 10 Hz before a nonlinear basis biased a simulated 500 Hz arm's delay by -1 to -2 ms);
the shifted torques are a cubic spline of the filtered ones (sub-sample shifts). For a robot arm with its
description the model is the rigid body's inverse dynamics, linear in its inertial parameters
(``lnn_torch.robots.regressor.regressor``: the base parameters with armature and viscous damping) plus Coulomb
and offset friction per joint, fitted by ordinary least squares at each shift: the residual is smallest where
torques and motion line up, since a delay leaves ``d * dtau/dt`` that the instantaneous state cannot explain.
Without a description (any system) the same criterion with a compact basis, linear in its coefficients, of the
terms that carry a torque's variation at the frequencies of motion: ``1``, every ``qdd_k`` (inertia with a mean
mass matrix), ``qd_k`` and ``tanh(qd_k / v_c)`` (friction), ``sin q_k, cos q_k`` (gravity; a length enters as
itself): ``3 + 3 dof`` coefficients per input. Few on purpose: on one smooth trajectory any rich function of the
state is a rich function of time, which fits a shifted torque as well as the true one (a basis with products of
accelerations and angles and sums of angles, 184 coefficients per input for six joints, fitted the UR10 bag's
torques to 0.03 N m at every shift and ran to the end of any range searched). Measured on a simulated Panda with
a known delay (20 s of a 4-harmonic trajectory of about +-0.8 rad, torque noise 0.05-0.1 N m): the arm's
regressor within 0.4 ms at 30, 100, 125 and 500 Hz, the compact basis within 2 ms at 100-500 Hz and 7 ms at 30
Hz (the tests hold the regressor to 1 ms at 30 and 100 Hz, the basis to 2 ms at 125 Hz). Each recording's two
halves are fitted apart and their delays compared with their standard errors (``torque_delay``: the Birge
ratio); where they disagree the model misses part of the dynamics, the error is widened, the estimate marked,
and ``auto`` refuses it. The estimate is reported with the residual at zero delay and at the estimate, and
applied only when asked (``auto`` or a number): each input at ``t`` replaced by its value at ``t + d`` (a cubic
spline through the stamps), the rows at the recording's end (``d > 0``) or start (``d < 0``) without a shifted
input dropped (``t0_s`` in the provenance: the first row kept, from which windows count).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import InputError

BAG_SUFFIXES = (".db3", ".mcap", ".bag")
JOINT_STATE = ("sensor_msgs/msg/JointState", "sensor_msgs/JointState")
INSTALL = "pip install 'lnn-torch[bags]'"
FORMATS = {".db3": "ROS 2 bag (sqlite3)", ".mcap": "ROS 2 bag (MCAP)", ".bag": "ROS 1 bag"}


def is_bag(path: str | Path) -> bool:
    """A ROS bag: a ``.db3``, ``.mcap`` or ``.bag`` file, or a folder (a rosbag2 recording)."""
    path = Path(path)
    return path.suffix.lower() in BAG_SUFFIXES or path.is_dir()


def bag_name(path: str | Path) -> str:
    """A bag's recording name: its file's name without ``.db3``, ``.mcap`` or ``.bag``; a folder's name."""
    path = Path(path)
    return path.stem if path.suffix.lower() in BAG_SUFFIXES and path.stem else path.name


def _rosbags(ros1: bool):
    """``(AnyReader, typestore)``: the library's reader and the message types for bags that carry none."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise InputError(f"import: reading ROS bags needs the rosbags library: {INSTALL}") from None
    return AnyReader, get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)


def _storage(path: Path) -> tuple[Path, str]:
    """What the reader opens, and its format in words: the file; a rosbag2 folder with its metadata; a
    folder without ``metadata.yaml`` holding one storage file: that file."""
    if not path.is_dir():
        return path, FORMATS[path.suffix.lower()]
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in (".db3", ".mcap"))
    kinds = ", ".join(sorted({FORMATS[p.suffix.lower()][len("ROS 2 bag "):] for p in files}))
    if (path / "metadata.yaml").exists():
        return path, f"ROS 2 bag folder {kinds}".strip()
    if len(files) == 1:
        return files[0], FORMATS[files[0].suffix.lower()]
    what = "no .db3 or .mcap file" if not files else f"{len(files)} storage files ({', '.join(p.name for p in files)})"
    raise InputError(f"{path}: a folder without metadata.yaml and with {what}: give a bag file or a rosbag2 folder")


def _plural(items: list[str], one: str, many: str) -> str:
    return f"{one if len(items) == 1 else many} {', '.join(items)}"


def read_bag_table(path: str | Path, spec) -> tuple[np.ndarray, np.ndarray, dict]:
    """``(table (rows, 1 + k) float64, messages (rows,) int64, info)``: a bag's JointState messages on
    ``spec.topic`` as the table a CSV gives (time in s from the first message, then the positions of
    ``spec.coordinates``, the velocities of ``spec.velocities`` and the efforts of ``spec.input_columns``:
    joints of the bag; the efforts from ``spec.effort_topic`` where given: ``_merged``), each row's message
    number (from 1), and what was read (format, topic, type, messages, the time's source, the first stamp in
    ns, the joints)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    AnyReader, store = _rosbags(ros1=path.suffix.lower() == ".bag")
    target, form = _storage(path)
    efforts = [("effort", j) for j in spec.input_columns]
    fields = ([("position", j) for j in spec.coordinates] + [("velocity", j) for j in spec.velocities or []]
              + (efforts if not spec.effort_topic else []))
    ignored = set(spec.ignore_joints or [])
    try:
        with AnyReader([target], default_typestore=store) as reader:
            main = _read_topic(reader, path, spec.topic, fields, ignored)
            other = _read_topic(reader, path, spec.effort_topic, efforts, ignored) if spec.effort_topic and efforts \
                else None
    except InputError:
        raise
    except Exception as err:  # the library's reader errors, a damaged database or MCAP file, ...
        raise InputError(f"{path}: cannot read it as a ROS bag ({type(err).__name__}: {err})") from None
    streams = [main] + ([other] if other else [])
    source = spec.stamps
    if source == "auto":  # (both topics on one clock: the header stamps only where both have them)
        source = "header" if all(s["header_ns"].any() for s in streams) else "receive"
    elif source == "header":
        for s in streams:
            if not s["header_ns"].any():
                raise InputError(f"{path}: every header stamp on {s['topic']} is zero: set stamps to receive (the "
                                 "bag's receive times) or auto")
    elif source == "sequence" and spec.dt is None:
        raise InputError("import: stamps: sequence times the messages one dt apart: set dt (the publisher's "
                         "interval, s)")
    elif source == "sequence" and other:
        raise InputError("import: stamps: sequence times one topic's messages by their order; the efforts' topic "
                         "(effort_topic) has a rate of its own: stamp the messages, or use receive times")
    for s in streams:
        _timed(path, s, source, spec.dt)
    values, ns, numbers, notes, skipped = main["values"], main["ns"], main["numbers"], main["notes"], main["skipped"]
    info_other = {}
    if other:
        values, ns, numbers, dropped = _merged(path, main, other)
        notes = notes + [f"{spec.effort_topic}: {n}" for n in other["notes"]]
        skipped = {**skipped, **{f"{what} on {spec.effort_topic}": v for what, v in other["skipped"].items()}}
        if dropped:
            skipped["outside the efforts"] = dropped
        info_other = {"effort_topic": other["topic"], "effort_messages": len(other["values"]),
                      "effort_median_interval_s": float(np.median(np.diff(other["ns"]))) / 1e9}
    t = (ns - ns[0]) / 1e9  # integer nanoseconds from the first: no rounding of epoch times
    time = ("the messages' header stamps" if source == "header" else
            "the bag's receive times" + (" (every header stamp is zero)" if spec.stamps == "auto" else "")
            if source == "receive" else f"the messages' order, one dt ({spec.dt:g} s) apart (stamps: sequence)")
    info = {"format": form, "topic": main["topic"], "type": main["type"], "messages": len(values), "time": time,
            "first_stamp_ns": int(ns[0]),
            "joints": {"position": list(spec.coordinates), "velocity": list(spec.velocities or []),
                       "effort": list(spec.input_columns)},
            "ignored_joints": sorted(set(main["ignored"]) | set(other["ignored"] if other else [])), **info_other}
    if skipped:
        info["skipped"] = skipped
    if notes:
        info["notes"] = notes
    if spec.joints:
        info["mapping"] = dict(spec.joints)
    return np.concatenate([t[:, None], values], 1), numbers, info


def _read_topic(reader, path: Path, topic: str, fields: list, ignored: set) -> dict:
    """The JointState messages on ``topic``: the values of ``fields`` (``(field, joint)`` each) per message,
    their header stamps and receive times (ns), message numbers (from 1 along the topic), the messages left out
    (another publisher's, those with an empty array of a field read: ``others``, ``empty``) and the ignored
    joints seen; a message the fields cannot be read from is refused naming it."""
    wanted = list(dict.fromkeys(j for _, j in fields))
    topic = "/" + topic.lstrip("/")
    index: dict[tuple, np.ndarray | None] = {}
    rows, header, received, numbers = [], [], [], []
    others: dict[tuple, list[int]] = {}
    empty: dict[str, list[int]] = {}

    def columns(names: tuple, k: int) -> np.ndarray | None:
        """The message's array index of each field's joint (None: none of the joints read, another publisher's
        message); refusals name the joints and message."""
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise InputError(f"{path}: message {k} on {topic} names {_plural(twice, 'joint', 'joints')} twice")
        missing = [j for j in wanted if j not in names]
        if len(missing) == len(wanted):
            return None
        if missing:
            raise InputError(f"{path}: message {k} on {topic} has no {_plural(missing, 'joint', 'joints')} (its "
                             f"joints: {', '.join(names)}): map the bag's names in joints")
        unmapped = [n for n in names if n not in wanted and n not in ignored]
        if unmapped:
            them = "it" if len(unmapped) == 1 else "them"
            raise InputError(f"{path}: the bag's {_plural(unmapped, 'joint', 'joints')} (message {k} on {topic}) "
                             f"not mapped: map {them} in joints, or list {them} in ignore_joints")
        return np.array([names.index(j) for _, j in fields], dtype=np.int64)

    conns = [c for c in reader.connections if c.topic == topic]
    if not conns:
        listing = ", ".join(f"{c.topic} ({c.msgtype})" for c in reader.connections) or "none"
        raise InputError(f"{path}: no topic {topic} in the bag (its topics: {listing}): set "
                         f"{'topic' if fields[0][0] == 'position' else 'effort_topic'}")
    if any(c.msgtype not in JOINT_STATE for c in conns):
        raise InputError(f"{path}: topic {topic} holds {conns[0].msgtype} messages, not sensor_msgs/msg/JointState")
    kinds = [f for f in ("position", "velocity", "effort") if any(g == f for g, _ in fields)]
    for k, (conn, stamp, raw) in enumerate(reader.messages(connections=conns), start=1):
        msg = reader.deserialize(raw, conn.msgtype)
        names = tuple(msg.name)
        if names not in index:
            index[names] = columns(names, k)
        at = index[names]
        if at is None:
            others.setdefault(names, []).append(k)
            continue
        arrays = {f: np.asarray(getattr(msg, f), dtype=np.float64) for f in kinds}
        short = [f for f in kinds if len(arrays[f]) != len(names)]
        if any(len(arrays[f]) for f in short):
            f = next(f for f in short if len(arrays[f]))
            raise InputError(f"{path}: message {k} on {topic} holds {len(arrays[f])} {f} values for {len(names)} "
                             "joints")
        if short:
            for f in short:
                empty.setdefault(f, []).append(k)
            continue
        rows.append([arrays[f][i] for (f, _), i in zip(fields, at, strict=True)])
        header.append(int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec))
        received.append(int(stamp))
        numbers.append(k)
    left = f" ({sum(map(len, empty.values()))} with an empty array left out)" if empty else ""
    if len(rows) < 2 and empty:  # (almost) no message with every field read: the recording has not got one
        f, ks = next(iter(empty.items()))
        advice = "the positions are needed" if f == "position" else (
            "leave it out of streams, or name the topic that has the efforts in effort_topic" if f == "effort"
            else "leave it out of streams")
        verb = "holds" if len(rows) == 1 else "hold"
        raise InputError(f"{path}: {len(rows)} message{'s' if len(rows) != 1 else ''} on {topic} {verb} every field "
                         f"read: message {ks[0]} holds 0 {f} values for its joints, as do {len(ks) - 1} more "
                         f"({advice})")
    if not rows and others:
        names = next(iter(others))
        raise InputError(f"{path}: no message on {topic} has the joints {', '.join(wanted)} (its messages' joints: "
                         f"{', '.join(names) or 'none'}): map the bag's names in joints")
    if len(rows) < 2:
        raise InputError(f"{path}: {len(rows)} message{'s' if len(rows) != 1 else ''} on {topic}: fewer than "
                         f"two{left}")
    skipped = {"other publisher": {"count": sum(map(len, others.values())),
                                   "first": sorted(k for ks in others.values() for k in ks)[:5],
                                   "joints": sorted({n for names in others for n in names})}} if others else {}
    for f, ks in empty.items():
        skipped[f"empty {f}"] = {"count": len(ks), "first": ks[:5]}
    return {"topic": topic, "type": conns[0].msgtype, "fields": fields,
            "values": np.asarray(rows, dtype=np.float64).reshape(len(rows), len(fields)),
            "numbers": np.asarray(numbers, dtype=np.int64), "header_ns": np.asarray(header, dtype=np.int64),
            "received_ns": np.asarray(received, dtype=np.int64), "skipped": skipped, "notes": [],
            "ignored": sorted({n for names, at in index.items() if at is not None for n in names if n in ignored})}


def _timed(path: Path, s: dict, source: str, dt: float | None) -> None:
    """A topic's messages (``_read_topic``) timed by ``source`` (``header``, ``receive`` or ``sequence``: one
    ``dt`` apart), in place: ``ns`` (a header stamp of zero among wall-clock ones left out, messages a few cycles
    late sorted by their stamps), NaN and Inf refused naming the message; receive times that arrive in bursts, or
    repeat with other values, refused (they are not sample times), and their spread said."""
    topic, values, numbers = s["topic"], s["values"], s["numbers"]
    header_ns, received_ns = s["header_ns"], s["received_ns"]
    zero = header_ns == 0
    if source == "header" and zero.any() and header_ns.max() >= UNSET_BEFORE_NS:
        # zero stamps among wall-clock ones: a driver that published before its clock was set (a bag whose stamps
        # count from zero, e.g. simulated time, keeps its first message)
        s["skipped"]["zero header stamp"] = {"count": int(zero.sum()), "first": numbers[zero][:5].tolist()}
        values, header_ns, received_ns, numbers = values[~zero], header_ns[~zero], received_ns[~zero], numbers[~zero]
        if len(values) < 2:
            raise InputError(f"{path}: fewer than two messages on {topic} with a header stamp: set stamps to receive")
    bad = np.argwhere(~np.isfinite(values))  # (a message left out for its stamp is not read)
    if bad.size:
        r, c = bad[0]
        field, joint = s["fields"][c]
        raise InputError(f"{path}: message {numbers[r]} on {topic}: NaN or Inf in the {field} of {joint}")
    if source == "sequence":
        ns = received_ns[0] + np.round(dt * 1e9 * np.arange(len(values))).astype(np.int64)
    else:
        ns = header_ns if source == "header" else received_ns
        order, reordered = _local_order(ns)
        if reordered:
            values, ns, numbers = values[order], ns[order], numbers[order]
            header_ns, received_ns = header_ns[order], received_ns[order]
            s["notes"].append(reordered)
    back = int((np.diff(header_ns) < 0).sum())
    if source == "receive" and header_ns.all() and back:
        s["notes"].append(f"the header stamps step back {back} time{'s' if back > 1 else ''}: the receive times are "
                          "used, as stamps: receive asks (stamps: header sorts messages a few cycles late by their "
                          "stamps)")
    if source == "receive":
        s["notes"].append(_receive_times(path, topic, ns, values, numbers))
    s.update(values=values, ns=ns, numbers=numbers)


# receive times are refused as sample times where the median interval is below this fraction of the mean (messages
# delivered in bursts: a recorder or network that batches them), intervals over PAUSE_S s left out of the mean
BURST_RATIO, PAUSE_S = 0.3, 1.0


def _receive_times(path: Path, topic: str, ns: np.ndarray, values: np.ndarray, numbers: np.ndarray) -> str:
    """The line saying that a topic's times are receive times and how much their intervals spread; refusals where
    they cannot be sample times: delivered in bursts (``BURST_RATIO``), or a receive time repeated with other
    values."""
    steps = np.diff(ns) / 1e6  # ms
    # the mean interval without the pauses (over PAUSE_S: a recorder paused, which bursts are not)
    running = steps[steps <= 1e3 * PAUSE_S]
    mean = float((running if running.size else steps).mean())
    median = float(np.median(steps))
    remedy = ("stamp the messages' headers where they are sampled, or, for a publisher at a fixed rate that lost no "
              "message, set stamps: sequence with dt")
    if median < BURST_RATIO * mean:
        share = float((steps < BURST_RATIO * mean).mean())
        raise InputError(f"{path}: the receive times on {topic} come in bursts ({100 * share:.0f} % of the messages "
                         f"within {BURST_RATIO * mean:.3g} ms of the one before, median interval {median:.3g} ms "
                         f"against {mean:.3g} ms on average): they are not the sample times; {remedy}")
    same = np.nonzero((steps == 0) & (values[1:] != values[:-1]).any(1))[0]
    if same.size:
        i = int(same[0])
        raise InputError(f"{path}: message {numbers[i + 1]} on {topic} was received at the same time as message "
                         f"{numbers[i]} with other values: receive times are not sample times; {remedy}")
    p5, p95 = np.percentile(steps, [5, 95])
    return (f"the times on {topic} are receive times (when the recorder got each message, not when it was sampled): "
            f"intervals {p5:.3g}-{p95:.3g} ms (5th-95th percentile) around a median of {median:.3g} ms; their jitter "
            "moves each sample in time (stamp the messages' headers where you can)")


# an effort on another topic is interpolated to a position message's time only between two effort messages at most
# this many median effort intervals apart (rows in a longer gap of the efforts are left out)
MERGE_GAP_INTERVALS = 5


def _merged(path: Path, main: dict, other: dict) -> tuple:
    """``(values, ns, numbers, dropped)``: the main topic's rows with the efforts of ``other`` (another topic,
    timed alike) linearly interpolated to each row's time; rows before the first effort message, after the last,
    or within a gap of the efforts longer than ``MERGE_GAP_INTERVALS`` of their median interval left out (counted
    in ``dropped``, None if none)."""
    te, e, numbers = other["ns"], other["values"], other["numbers"]
    same = np.r_[False, (np.diff(te) == 0) & (e[1:] == e[:-1]).all(1)]  # a stale message sent again, stamp and all
    if same.any():
        other["skipped"]["repeated"] = {"count": int(same.sum()), "first": numbers[same][:5].tolist()}
        te, e, numbers = te[~same], e[~same], numbers[~same]
    if (np.diff(te) <= 0).any():
        i = int(np.nonzero(np.diff(te) <= 0)[0][0])
        raise InputError(f"{path}: message {numbers[i + 1]} on {other['topic']}: time repeats or decreases "
                         "(the efforts' times must increase)")
    t = main["ns"]
    at = np.searchsorted(te, t, side="right")  # te[at - 1] <= t < te[at]
    inside = (at > 0) & (at < len(te)) | (t == te[-1])
    lo, hi = np.clip(at - 1, 0, len(te) - 1), np.clip(at, 0, len(te) - 1)
    limit = MERGE_GAP_INTERVALS * float(np.median(np.diff(te)))
    keep = inside & ((te[hi] - te[lo]) <= limit)
    if keep.sum() < 2:
        raise InputError(f"{path}: the efforts on {other['topic']} overlap fewer than two messages on "
                         f"{main['topic']} in time")
    base = t[0]  # (float64 seconds from the first position message: no rounding of epoch times)
    x, xe = (t - base) / 1e9, (te - base) / 1e9
    merged = np.stack([np.interp(x, xe, e[:, j]) for j in range(e.shape[1])], -1)
    values = np.concatenate([main["values"], merged], 1)[keep]
    dropped = None
    if not keep.all():
        dropped = {"count": int((~keep).sum()), "first": main["numbers"][~keep][:5].tolist()}
    return values, t[keep], main["numbers"][keep], dropped


# a header stamp of zero is unset (left out) in a bag whose other stamps are wall-clock times, from 2001 on (1e9 s)
UNSET_BEFORE_NS = 10**18
# the largest step back in time a bag's messages may take and be sorted by their stamps (median intervals): messages
# reordered on the way (a network, a busy recorder) arrive a few cycles late; a clock that jumps back is refused
MAX_REORDER_INTERVALS = 10


def _local_order(ns: np.ndarray) -> tuple[np.ndarray | None, str | None]:
    """``(order, note)``: where a few messages' stamps lie behind the latest before them by at most
    ``MAX_REORDER_INTERVALS`` median intervals, the (stable) order that sorts them and a line saying so; else
    ``(None, None)`` (the time check that follows refuses what is left)."""
    steps = np.diff(ns)
    ahead = steps[steps > 0]
    if not (steps < 0).any() or not ahead.size:
        return None, None
    high = np.maximum.accumulate(ns)
    late = ns[1:] < high[:-1]  # behind the latest stamp before them
    lag = (high[:-1] - ns[1:])[late]
    if lag.max() > MAX_REORDER_INTERVALS * np.median(ahead):
        return None, None
    n = int(late.sum())
    return np.argsort(ns, kind="stable"), (f"{n} message{'s' if n > 1 else ''} arrived out of order (up to "
                                           f"{lag.max() / 1e6:.3g} ms behind the latest stamp before): sorted by "
                                           "their stamps")


# ---------------------------------------------------------------------------------------- repeated rows
def repeated_rows(table: np.ndarray, dof: int, velocities: bool) -> np.ndarray:
    """The rows of ``table (rows, 1 + k)`` (time, then ``dof`` positions, [``dof`` velocities], ...) that
    repeat the previous row in every value while the joints move, or repeat its time stamp too (module
    docstring): a boolean mask."""
    n = len(table)
    values = table[:, 1:]
    same = np.zeros(n, dtype=bool)
    same[1:] = (values[1:] == values[:-1]).all(1)
    stamp = np.zeros(n, dtype=bool)
    stamp[1:] = table[1:, 0] == table[:-1, 0]
    rest = np.zeros(n, dtype=bool)
    if velocities:
        rest = (table[:, 1 + dof:1 + 2 * dof] == 0).all(1)
    else:
        rest[:-1] = (table[1:, 1:1 + dof] == table[:-1, 1:1 + dof]).all(1)
    return same & (stamp | ~rest)


# ---------------------------------------------------------------------------------------- the torque delay
MAX_ROWS = 4000  # samples of a recording the delay's least squares uses (every k-th sample beyond)
MIN_ROWS = 40  # fewer interior samples than this in each half: no estimate for the recording
BIRGE = 3.0  # the halves' delays disagree beyond this many standard errors (Birge ratio): not determined
SIGNIFICANT = 3.0  # a delay within this many standard errors of zero is none: auto does not apply it
# a recording whose inputs the basis explains less of (share of their variance at zero delay, beyond what the same fit
# explains of noise) gets no estimate: its inputs are not a function of the state the basis holds (e.g. a free swing:
# the inputs are the sensor's noise)
EXPLAINED = 0.5


def delay_range(dt: float, span: float | None) -> float:
    """The delays searched, +- s: ``span``, else the larger of 5 samples and 50 ms."""
    return float(span) if span is not None else max(5 * dt, 0.05)


def _cutoff(dt: float) -> float:
    return min(10.0, 0.2 / dt)


# the states the delay's basis is computed from are filtered more widely (WIDE_HZ, at most 0.4 of the sampling rate)
# than the criterion's band (``_cutoff``): the basis and the torques are then low-passed alike, the regression
# equation filtered (exact for a model linear in its parameters). Low-passing the states before a nonlinear basis
# instead biased the delay of a simulated 500 Hz arm by -1 to -2 ms (its truth 0; -0.1 to -0.3 ms so), and leaves
# the real recordings' estimates within 0.1 ms
WIDE_HZ = 40.0
SEGMENT = 20_000  # samples of a recording whose basis is computed and filtered at once (with margins)


def _filtered_at(fn, q, qd, qdd, rows, dt: float, settings: dict) -> np.ndarray:
    """``fn(q, qd, qdd) -> (t k, p)`` (``k`` rows per sample) low-passed along time as ``settings``, at the
    samples ``rows``: ``(len(rows) k, p)``; computed over segments of at most ``SEGMENT`` samples, each with
    ten periods of the cutoff as margin on either side (what the filter's response reaches)."""
    from .derivatives import smooth_inputs

    T, rows = len(q), np.asarray(rows)
    margin = int(round(10.0 / (settings["cutoff"] * dt)))
    out = []
    for a in range(0, T, SEGMENT):
        at = rows[(rows >= a) & (rows < a + SEGMENT)]
        if not len(at):
            continue
        lo, hi = max(0, a - margin), min(T, a + SEGMENT + margin)
        Y = fn(*(np.ascontiguousarray(x[lo:hi]) for x in (q, qd, qdd)))
        Y = Y.reshape(hi - lo, -1, Y.shape[-1])
        k, p = Y.shape[1:]
        out.append(smooth_inputs(Y.reshape(hi - lo, k * p), dt, settings).reshape(hi - lo, k, p)[at - lo])
    return np.concatenate(out).reshape(-1, out[0].shape[-1])


def state_basis(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, angle_mask, coulomb_velocity: float,
                combinations=None) -> np.ndarray:
    """``(T, p)``: the compact basis of the delay's criterion at states ``(T, dof)``: ``1``, every
    ``qdd_k`` (inertia with a mean mass matrix), ``qd_k``, ``tanh(qd_k / v_c)`` (friction), ``sin q_k, cos
    q_k`` (gravity; a length ``q_k`` itself), and the sine and cosine of each of the system's further
    feature angles ``combinations`` (rows of coefficients over ``q``; e.g. a link's absolute angle)."""
    mask = np.asarray(angle_mask, dtype=bool)
    T = len(q)
    pose = [np.stack([np.sin(q[:, k]), np.cos(q[:, k])], -1) if mask[k] else q[:, k:k + 1] for k in range(q.shape[1])]
    for row in np.asarray(combinations if combinations is not None else [], dtype=np.float64).reshape(-1, q.shape[1]):
        angle = q @ row
        pose.append(np.stack([np.sin(angle), np.cos(angle)], -1))
    import torch

    from ..mechanics.friction import coulomb_sign

    coulomb = coulomb_sign(torch.as_tensor(qd, dtype=torch.float64), coulomb_velocity).numpy()
    return np.concatenate([np.ones((T, 1)), qdd, qd, coulomb, *pose], -1)


def _arm_basis(chain, q, qd, qdd, coulomb_velocity: float) -> np.ndarray:
    """``(T n, p)``: the rigid body's regressor (armature and damping included) and Coulomb and offset
    friction per joint, one row per joint equation."""
    import torch

    from ..mechanics.friction import DriveModel
    from ..robots.regressor import regressor

    args = [torch.as_tensor(x, dtype=torch.float64) for x in (q, qd, qdd)]
    Y = regressor(chain, *args).numpy()  # (T, n, 12 n)
    T, n = q.shape
    shapes = DriveModel.of("coulomb+offset", coulomb_velocity=coulomb_velocity).columns(args[1]).numpy()  # (T, n, 2)
    friction = (np.eye(n)[None, :, :, None] * shapes[:, :, None, :]).reshape(T, n, 2 * n)  # each joint its own columns
    return np.concatenate([Y, friction], -1).reshape(T * n, -1)


def _projector(A: np.ndarray):
    """``(A^T, W)`` with ``||P y||^2 = ||W^T A^T y||^2`` for the orthogonal projection ``P`` onto the column
    space of ``A`` (its columns scaled first; the normal matrix's eigenvalues below 1e-20 of the largest,
    singular values below 1e-10, dropped): the explained part of any ``y`` at the cost of ``A^T y``."""
    scale = np.linalg.norm(A, axis=0)
    keep = scale > 1e-12 * max(scale.max(), 1e-300)
    As = A[:, keep] / scale[keep]
    lam, V = np.linalg.eigh(As.T @ As)
    good = lam > 1e-20 * lam.max() if lam.size else lam > 0
    return As.T, V[:, good] / np.sqrt(lam[good])


def torque_delay(series: list[dict], dt: float, *, chain=None, payload=None, angle_mask=None, combinations=None,
                 coulomb_velocity: float = 0.02, span: float | None = None) -> dict:
    """The torque stream's delay (module docstring), per recording and for all together, with its
    consistency: each recording's two halves are fitted apart (a model of their own), and their delays
    compared with their standard errors (the Birge ratio ``sqrt(chi^2 / (m - 1))`` over the ``m`` halves;
    about 1 where the errors hold, several where the model misses part of the dynamics: the pooled error
    is then widened by the ratio, and above ``BIRGE`` the estimate is marked inconsistent). A bias that
    both halves share (a basis that misses the dynamics alike everywhere) is not caught.

    ``series``: one dict per recording, ``{"name", "q" (T, dof), "qd" (T, dof) or None, "tau" (T, n_u),
    "params" (P,)}`` in SI on the grid ``dt``; ``chain``: a robot arm's kinematic chain (its inputs are
    its joint torques), else the compact basis (``combinations``: the system's further feature angles);
    ``payload``: for an arm, whether ``params`` are the payload at the flange (its torques are removed
    first). Returns ``{"method", "searched_s", "cutoff_hz", "recordings": [{"name", "delay_s", "se_s",
    "halves_s", "rms_zero", "rms_delay", "at_edge"} or {"name", "skipped"}], "delay_s", "se_s", "birge",
    "consistent", "rms_zero", "rms_delay", "at_edge"}`` (from ``delay_s``: all recordings together;
    ``se_s`` the standard error, ``rms_*`` the residual at zero delay and at the estimate)."""
    import scipy.interpolate
    import scipy.optimize

    from .derivatives import estimate, smooth_inputs

    K = max(1, int(math.ceil(delay_range(dt, span) / dt - 1e-9)))
    search = K * dt
    cutoff = _cutoff(dt)
    settings = {"method": "butterworth", "cutoff": cutoff, "order": 4, "use_measured_velocity": True}
    edge = K + 2 + int(round(1.0 / (cutoff * dt)))
    method = ("least squares of the torques on the arm's regressor (rigid body, armature, damping) and Coulomb and "
              "offset friction" if chain is not None else
              "least squares of the inputs on a compact basis of the state (accelerations, velocities, Coulomb, sines "
              "and cosines of the angles)")
    flat = chain is not None
    independent = min(1.0, 2 * cutoff * dt)  # the share of the samples independent after the low-pass
    recordings, out = [], []
    for s in series:
        q, tau = s["q"], s["tau"]
        T = len(q)
        if T - 2 * edge < 2 * MIN_ROWS:
            out.append({"name": s["name"], "skipped": f"{T} samples: too short to estimate a delay of +-{search:g} s"})
            continue
        # the states widely filtered, the basis (and a known payload's torque) then low-passed as the torques
        qd, qdd = estimate(q, dt, {**settings, "cutoff": min(WIDE_HZ, 0.4 / dt)}, s.get("qd"))
        spline = scipy.interpolate.CubicSpline(dt * np.arange(T), smooth_inputs(tau, dt, settings), axis=0)
        rows = np.arange(edge, T - edge, max(1, (T - 2 * edge) // MAX_ROWS))
        offset = np.zeros((len(rows), tau.shape[1]))
        if chain is not None:
            A = _filtered_at(lambda *x: _arm_basis(chain, *x, coulomb_velocity), q, qd, qdd, rows, dt, settings)
            params = np.asarray(s.get("params", ()), dtype=np.float64)
            if payload and params.size and np.any(params):
                import torch

                from ..robots.regressor import payload_torque

                def load(q, qd, qdd, params=params):
                    return payload_torque(chain, q, qd, qdd, torch.as_tensor(np.tile(params, (len(q), 1)))).numpy()

                offset = _filtered_at(load, q, qd, qdd, rows, dt, settings).reshape(len(rows), -1)
        else:
            A = _filtered_at(lambda *x: state_basis(*x, angle_mask, coulomb_velocity, combinations), q, qd, qdd, rows,
                             dt, settings)
        n_eq = tau.shape[1] if flat else 1  # rows of A per sample
        halves = []
        for part in np.array_split(np.arange(len(rows)), 2):
            At, W = _projector(A.reshape(len(rows), n_eq, -1)[part].reshape(len(part) * n_eq, -1))

            def rss(shift, at=rows[part], offset=offset[part], At=At, W=W, spline=spline, memo={}):  # noqa: B006
                if shift not in memo:  # the scans of a half, of its recording and of all recordings share it
                    y = spline(dt * at + shift) - offset
                    y = y.reshape(-1, 1) if flat else y
                    memo[shift] = float((y * y).sum() - ((W.T @ (At @ y)) ** 2).sum())
                return memo[shift]

            halves.append((rss, len(part) * tau.shape[1], W.shape[1] * (1 if flat else tau.shape[1])))
        inputs = spline(dt * rows) - offset
        left, total = sum(g(0.0) for g, _, _ in halves), float((inputs * inputs).sum())
        explained = 1.0 - max(left, 0.0) / total if total > 0 else 0.0
        # what a fit of as many columns explains of noise filtered as the inputs are
        chance = min(1.0, sum(p for _, _, p in halves) / (sum(c for _, c, _ in halves) * independent))
        if explained - chance < EXPLAINED:
            out.append({"name": s["name"], "skipped": f"the state explains {explained:.0%} of its inputs' variance at "
                                                      f"no delay, a fit of noise {chance:.0%}: too little to time "
                                                      "them"})
            continue
        recordings.append((s["name"], halves))
    shifts = dt * np.arange(-K, K + 1)

    def minimise(parts):
        """``(delay, at the edge, standard error, rss)`` of the summed residual of ``parts``: the scan's
        best shift refined between its neighbours; the error from the curvature of the residual there,
        ``sqrt(2 s^2 / rss'')`` with ``s^2`` the residual variance, inflated for the samples the low-pass
        makes dependent (statistical: a model that misses the dynamics biases the delay beyond it)."""
        def f(x):
            return sum(g(x) for g, _, _ in parts)

        count, p = sum(c for _, c, _ in parts), sum(p for _, _, p in parts)
        values = np.array([f(x) for x in shifts])
        k = int(np.argmin(values))
        lo, hi = shifts[max(k - 1, 0)], shifts[min(k + 1, 2 * K)]
        best = float(scipy.optimize.minimize_scalar(f, bounds=(lo, hi), method="bounded",
                                                    options={"xatol": 1e-4 * dt}).x)
        h = 0.5 * dt
        curvature = (f(best + h) - 2 * f(best) + f(best - h)) / h**2
        variance = max(f(best), 0.0) / max(count - p, 1)
        se = math.sqrt(2 * variance / curvature / independent) if curvature > 0 else math.inf
        return best, k in (0, 2 * K), se, {"rms_zero": math.sqrt(max(f(0.0), 0) / count),
                                            "rms_delay": math.sqrt(max(f(best), 0) / count)}

    estimates = []  # (delay, se) of every half; a half whose best shift is at the edge searched is undetermined
    for name, halves in recordings:
        best, at_edge, se, rms = minimise(halves)
        parts = [(d, math.inf if edge_half else e) for d, edge_half, e, _ in (minimise([h]) for h in halves)]
        if not all(math.isfinite(e) for _, e in parts):  # a half undetermined: so is the recording's estimate
            se = math.inf
        estimates += parts
        out.append({"name": name, "delay_s": best, "se_s": se, "halves_s": [d for d, _ in parts], **rms,
                    "at_edge": at_edge})
    order = {s["name"]: i for i, s in enumerate(series)}
    report = {"method": method, "searched_s": search, "cutoff_hz": cutoff,
              "recordings": sorted(out, key=lambda r: order[r["name"]])}
    if recordings:
        best, at_edge, se, rms = minimise([h for _, halves in recordings for h in halves])
        d, e = np.array([x for x, _ in estimates]), np.array([x for _, x in estimates])
        w = np.where(np.isfinite(e) & (e > 0), 1.0 / np.where(e > 0, e, 1.0) ** 2, 0.0)
        determined = int((w > 0).sum())  # the halves compared: an undetermined one compares with none
        mean = float((w * d).sum() / w.sum()) if w.sum() > 0 else float(d.mean())
        birge = (math.sqrt(float((w * (d - mean) ** 2).sum()) / (determined - 1)) if determined == len(d) > 1
                 else math.inf)
        widened = se * max(1.0, birge)
        report.update({"delay_s": best, "se_s": widened, "birge": birge, "consistent": birge <= BIRGE,
                       "significant": bool(abs(best) > SIGNIFICANT * widened), **rms, "at_edge": at_edge})
    return report


def shift_inputs(table: np.ndarray, lines: np.ndarray, n_u: int, delay: float) -> tuple[np.ndarray, np.ndarray]:
    """``table (rows, 1 + k)`` with its last ``n_u`` columns (the inputs) at ``t`` replaced by their values
    at ``t + delay`` (a cubic spline through the stamps: a shift of a fraction of a sample keeps the
    torque's curvature, which linear interpolation at 30 Hz would not), the rows where that lies outside
    the recording dropped; and the kept rows' ``lines``."""
    import scipy.interpolate

    t = table[:, 0]
    keep = (t + delay >= t[0]) & (t + delay <= t[-1])
    out = table[keep].copy()
    spline = scipy.interpolate.CubicSpline(t, table[:, table.shape[1] - n_u:], axis=0)
    out[:, table.shape[1] - n_u:] = spline(np.clip(t[keep] + delay, t[0], t[-1]))
    return out, lines[keep]


def delay_lines(report: dict, mode: str, applied: float | None) -> list[str]:
    """The command's lines on the torque delay (from the file's provenance)."""
    if not report:
        return []
    unit = f" {report['units']}" if report.get("units") else ""

    def delay(r):
        se = f" +- {1e3 * r['se_s']:.2g}" if math.isfinite(r.get("se_s", math.inf)) else " (+- undetermined)"
        return f"{1e3 * r['delay_s']:+.2f}{se} ms"

    parts = []
    for r in report["recordings"]:
        if "skipped" in r:
            parts.append(f"{r['name']} not estimated ({r['skipped']})")
        else:
            edge = (" (at the edge of the range searched: widen torque_delay_range, or the recording excites the arm "
                    "too little to tell a delay)" if r["at_edge"] else "")
            halves = ", ".join(f"{1e3 * x:+.1f}" for x in r["halves_s"])
            parts.append(f"{r['name']} {delay(r)}{edge} (halves {halves} ms; residual {r['rms_zero']:.4g} -> "
                         f"{r['rms_delay']:.4g}{unit} rms)")
    lines = [f"torque delay (inputs behind positions, +- one standard error; {report['method']}; searched "
             f"+-{1e3 * report['searched_s']:.4g} ms): " + "; ".join(parts)]
    if "delay_s" in report:
        agree = (f"the halves agree (Birge ratio {report['birge']:.2g})" if report["consistent"] else
                 "a half's delay is undetermined (at the edge searched): no estimate to compare, and auto does not "
                 "apply it" if not math.isfinite(report["birge"]) else
                 f"the halves disagree beyond their errors (Birge ratio {report['birge']:.2g}): the model misses "
                 "part of the torques' dynamics; the error is widened by the ratio, and auto does not apply it")
        if applied:
            what = f"applied: {1e3 * applied:+.2f} ms" + (" (the estimate, torque_delay: auto)" if mode == "auto"
                                                           else " (torque_delay)")
        elif report["consistent"] and not report.get("significant", True):
            what = (f"not applied: within {SIGNIFICANT:g} standard errors of none (torque_delay: auto does not apply "
                    "it either)")
        else:
            what = "not applied" + (" (torque_delay: auto applies it; friction the model lacks, e.g. stiction, "
                                    "shifts both halves alike: check it on held-out recordings first)"
                                    if report["consistent"] else "")
        lines.append(f"torque delay, all recordings: {delay(report)}; {agree}; {what}")
    return lines
