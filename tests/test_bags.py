"""Robot logs as robotics users have them (``lnn_torch.data.bags``): ROS 2 bags (sqlite3 and MCAP, the
storage file alone or its rosbag2 folder) and ROS 1 bags of ``sensor_msgs/JointState``, written here by
the ``rosbags`` library's own writers from known arrays, import to the same dataset as the CSV of the same
data; joint names mapped in another order land in their columns; stale repeated messages are dropped and
counted; a missing topic, an unmapped joint or the missing extra is one line; a known delay of the
torques behind the positions is recovered (by the arm's regressor and by the compact basis) and applied.
The two real bags in ``../shared/data/ros2_bags/`` import with the shipped configs (skipped without
them)."""

from __future__ import annotations

import json
import math
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from lnn_torch.cli import main
from lnn_torch.data import read_dataset
from lnn_torch.data.importer import ImportSpec, import_recordings
from lnn_torch.errors import InputError

rosbags = pytest.importorskip("rosbags")

from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin  # noqa: E402
from rosbags.rosbag2 import Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data" / "ros2_bags"
EPOCH = 1_700_000_000_123_456_789  # ns: a bag's stamps are times since 1970
BAG_JOINTS = ["arm_a", "arm_b", "arm_c"]
MODEL = ["q1", "q2", "q3"]
KINDS = ("sqlite3", "mcap", "ros1", "folder")


def motion(n: int = 400, dt: float = 0.005, seed: int = 0) -> dict:
    """Known arrays of three joints: stamps (ns, 5 ms with +-1 ms jitter, from ``EPOCH``), positions
    (rad), velocities (rad/s), efforts (N m)."""
    rng = np.random.default_rng(seed)
    t = dt * np.arange(n) + rng.uniform(-0.001, 0.001, n) * (np.arange(n) > 0)
    w = np.array([1.1, 1.7, 2.3])
    return {"ns": EPOCH + np.round(t * 1e9).astype(np.int64), "pos": np.sin(w * t[:, None]),
            "vel": w * np.cos(w * t[:, None]), "eff": np.cos(0.7 * t[:, None] + w)}


def write_bag(path: Path, kind: str, data: dict, names=BAG_JOINTS, topic="/joint_states", header=True,
              order=None, received=None, blank=()) -> Path:
    """The messages of ``data`` written by rosbags' own writer: ``kind`` sqlite3 or mcap (the storage file
    alone, no metadata.yaml beside it), folder (a rosbag2 folder with metadata.yaml), ros1 (a .bag). Each
    message lists the joints ``names`` (columns of ``data``) in the order ``order(k)`` (default as given);
    ``header``: False writes zero header stamps (or the messages whose numbers, from 0, it lists: a driver
    without its clock); ``received``: the receive times (default the stamps); ``blank``: messages written with
    an empty velocity array (a driver that had none that cycle)."""
    ros1 = kind == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    JointState, Header, Time = (store.types[f] for f in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header",
                                                          "builtin_interfaces/msg/Time"))
    folder = path.with_suffix("") if not ros1 else None
    writer = Writer1(path.with_suffix(".bag")) if ros1 else Writer2(
        folder, version=9, storage_plugin=StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3)
    with writer as w:
        conn = w.add_connection(topic, JointState.__msgtype__, typestore=store)
        for k, ns in enumerate(data["ns"]):
            idx = list(order(k)) if order else list(range(len(names)))
            zero = not header if isinstance(header, bool) else k in header
            stamp = Time(sec=0, nanosec=0) if zero else Time(sec=int(ns // 10**9), nanosec=int(ns % 10**9))
            head = Header(seq=k, stamp=stamp, frame_id="") if ros1 else Header(stamp=stamp, frame_id="")
            msg = JointState(header=head, name=[names[i] for i in idx],
                             position=np.ascontiguousarray(data["pos"][k, idx]),
                             velocity=np.ascontiguousarray(data["vel"][k, idx]) if k not in blank else np.zeros(0),
                             effort=np.ascontiguousarray(data["eff"][k, idx]) if data["eff"] is not None
                             else np.zeros(0))
            raw = store.serialize_ros1(msg, JointState.__msgtype__) if ros1 else store.serialize_cdr(
                msg, JointState.__msgtype__)
            w.write(conn, int(ns if received is None else received[k]), raw)
    if ros1:
        return path.with_suffix(".bag")
    if kind == "folder":
        return folder
    storage = folder / f"{folder.name}{'.mcap' if kind == 'mcap' else '.db3'}"
    alone = path.parent / "alone" / storage.name  # the file as users have it: no metadata.yaml beside it
    alone.parent.mkdir(exist_ok=True)
    shutil.move(storage, alone)
    shutil.rmtree(folder)
    return alone


def write_csv(path: Path, data: dict, names=BAG_JOINTS) -> Path:
    """The CSV of the same data: time (s from the first stamp), then p_, v_, e_ of each joint."""
    cols = {"time": (data["ns"] - data["ns"][0]) / 1e9}
    for field, key in (("p", "pos"), ("v", "vel"), ("e", "eff")):
        for j, name in enumerate(names):
            cols[f"{field}_{name}"] = data[key][:, j]
    rows = np.stack(list(cols.values()), -1)
    path.write_text(",".join(cols) + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n")
    return path


SPLIT = {"train": ["run[0:1.2]"], "val": ["run[1.2:1.6]"], "test": ["run[1.6:]"]}


def csv_spec(**kw) -> ImportSpec:
    return ImportSpec(**{"coordinates": [f"p_{j}" for j in BAG_JOINTS], "velocities": [f"v_{j}" for j in BAG_JOINTS],
                         "inputs": [f"e_{j}" for j in BAG_JOINTS], "coord_names": MODEL, "split": SPLIT, **kw})


def bag_spec(**kw) -> ImportSpec:
    return ImportSpec(**{"joints": dict(zip(BAG_JOINTS, MODEL, strict=True)), "split": SPLIT, **kw})


def dataset(path) -> tuple[dict, dict, dict]:
    """``(arrays, splits, provenance)`` of an imported file."""
    f = read_dataset(path)
    arrays = {k: np.asarray(f.read(k)) for k in ("t", "q", "qd", "tau", "lengths", "windows")}
    return arrays, {k: np.asarray(v).tolist() for k, v in f.splits.items()}, json.loads(f.attrs["provenance"])


def assert_same_dataset(a, b):
    (arr_a, split_a, _), (arr_b, split_b, _) = dataset(a), dataset(b)
    assert split_a == split_b
    for k in arr_a:
        np.testing.assert_array_equal(arr_a[k], arr_b[k], err_msg=k)
    assert read_dataset(a).attrs["scene_json"] == read_dataset(b).attrs["scene_json"]


# ---------------------------------------------------------------------------- 1. a bag is its CSV
@pytest.mark.parametrize("kind", KINDS)
def test_a_bag_imports_to_the_same_dataset_as_the_csv_of_the_same_data(kind, tmp_path):
    data = motion()
    bag = write_bag(tmp_path / "run", kind, data)
    csv = write_csv(tmp_path / "run.csv", data)
    assert_same_dataset(import_recordings([bag], tmp_path / "bag.h5", bag_spec()),
                        import_recordings([csv], tmp_path / "csv.h5", csv_spec()))
    arrays, splits, prov = dataset(tmp_path / "bag.h5")
    assert len(splits["train"]) == len(splits["val"]) == len(splits["test"]) == 1
    src = prov["sources"][0]
    assert src["messages"] == 400 and src["topic"] == "/joint_states" and src["first_stamp_ns"] == EPOCH
    assert src["time"] == "the messages' header stamps" and src["repeated_rows"]["count"] == 0
    assert src["format"].startswith("ROS 1" if kind == "ros1" else "ROS 2")
    # the torque delay is estimated on both (the same number: the same table)
    assert prov["torque_delay"] == dataset(tmp_path / "csv.h5")[2]["torque_delay"]
    # (these efforts are no function of the motion: not timed, and said why)
    assert "too little to time them" in prov["torque_delay"]["recordings"][0]["skipped"]


def test_joint_names_mapped_in_another_order_land_in_their_columns(tmp_path):
    """The bag lists its joints in an order that changes from message to message, with a gripper joint
    it does not import; the mapping sends arm_c to q1, arm_a to q2, arm_b to q3."""
    data = motion()
    names = [*BAG_JOINTS, "finger"]
    finger = 0.04 + 0.001 * np.arange(len(data["ns"]))[:, None]  # moving: no row repeats
    data4 = {k: (np.concatenate([v, finger], 1) if k != "ns" else v) for k, v in data.items()}
    bag = write_bag(tmp_path / "run", "mcap", data4, names=names,
                    order=lambda k: [3, 2, 1, 0] if k % 2 else [1, 3, 0, 2])
    spec = ImportSpec(joints={"arm_c": "q1", "arm_a": "q2", "arm_b": "q3"}, ignore_joints=["finger"], split=SPLIT)
    assert spec.coordinates == ["arm_c", "arm_a", "arm_b"] and spec.coord_names == MODEL
    arrays, _, prov = dataset(import_recordings([bag], tmp_path / "bag.h5", spec))
    reordered = {k: (v[:, [2, 0, 1]] if k != "ns" else v) for k, v in data.items()}
    csv = write_csv(tmp_path / "run.csv", reordered, names=["arm_c", "arm_a", "arm_b"])
    expected, _, _ = dataset(import_recordings([csv], tmp_path / "csv.h5", csv_spec(
        coordinates=["p_arm_c", "p_arm_a", "p_arm_b"], velocities=["v_arm_c", "v_arm_a", "v_arm_b"],
        inputs=["e_arm_c", "e_arm_a", "e_arm_b"])))
    for k in ("q", "qd", "tau"):
        np.testing.assert_array_equal(arrays[k], expected[k], err_msg=k)
    train = arrays["q"][0, :arrays["lengths"][0]]
    assert np.abs(train[:, 0] - np.sin(2.3 * arrays["t"][:len(train)])).max() < 0.05  # q1 is arm_c's angle
    assert prov["sources"][0]["ignored_joints"] == ["finger"]
    assert prov["sources"][0]["mapping"] == {"arm_c": "q1", "arm_a": "q2", "arm_b": "q3"}


# ---------------------------------------------------------------------------- 2. repeated rows
def test_repeated_rows_are_dropped_and_counted_and_rows_at_rest_kept(tmp_path, capsys):
    """Five stale messages (the previous one's values, a new stamp) and one exact duplicate (its stamp
    too) among 400; a start at rest (velocities zero: identical rows that are true samples) is kept.
    The bag drops the six, counted in the provenance and the printout, and imports as the data without
    them; a CSV of the same rows keeps them by default (counted), and drops them when asked."""
    data = motion()
    data["pos"][:20], data["vel"][:20], data["eff"][:20] = data["pos"][20], 0.0, data["eff"][20]  # at rest
    stale = [50, 120, 121, 200, 333]
    with_stale = {k: v.copy() for k, v in data.items()}
    for k in stale:
        for key in ("pos", "vel", "eff"):
            with_stale[key][k] = with_stale[key][k - 1]
    dup = 260  # the same message twice
    with_stale = {k: np.insert(v, dup + 1, v[dup], axis=0) for k, v in with_stale.items()}
    bag = write_bag(tmp_path / "run", "sqlite3", with_stale)
    assert main(["import", str(bag), "-o", str(tmp_path / "bag.h5"), "--config", str(
        _config(tmp_path, joints=dict(zip(BAG_JOINTS, MODEL, strict=True)), split=SPLIT))]) == 0
    out = capsys.readouterr().out
    assert "run.db3: 6 repeated rows (5 identical to the previous one while the joints move (stale), 1 exact " \
           "duplicate (the time stamp too); messages 51, 121, 122, 201, 262, ...) dropped" in out, out
    _, _, prov = dataset(tmp_path / "bag.h5")
    assert prov["sources"][0]["repeated_rows"] == {"count": 6, "dropped": True, "first": [51, 121, 122, 201, 262],
                                                   "duplicates": 1}
    assert prov["sources"][0]["rows"] == 401 - 6
    (tmp_path / "clean").mkdir()
    clean = write_csv(tmp_path / "clean" / "run.csv", {k: np.delete(v, stale, axis=0) for k, v in data.items()})
    assert_same_dataset(tmp_path / "bag.h5", import_recordings([clean], tmp_path / "clean.h5", csv_spec()))
    csv = write_csv(tmp_path / "run.csv", with_stale)
    with pytest.raises(InputError, match=r"run.csv: line 263: time repeats") as err:  # a CSV keeps them: as before,
        import_recordings([csv], tmp_path / "kept.h5", csv_spec())  # and the refusal says how to leave them out
    assert str(err.value).endswith("(an exact duplicate of the row before: repeated_rows: drop, or --repeated-rows "
                                   "drop, leaves it out)")
    csv = write_csv(csv, {k: np.delete(v, dup + 1, axis=0) for k, v in with_stale.items()})
    kept = dataset(import_recordings([csv], tmp_path / "kept.h5", csv_spec()))[2]
    assert kept["sources"][0]["repeated_rows"] == {"count": 5, "dropped": False, "first": [52, 122, 123, 202, 335],
                                                   "duplicates": 0}
    assert_same_dataset(import_recordings([csv], tmp_path / "drop.h5", csv_spec(repeated_rows="drop")),
                        tmp_path / "clean.h5")


def test_stamps_that_go_backwards_or_repeat_with_other_values_are_refused(tmp_path):
    data = motion()
    data["ns"][150] = data["ns"][149]  # repeats with other values
    bag = write_bag(tmp_path / "a", "mcap", data)
    with pytest.raises(InputError, match=r"a.mcap: message 151: time repeats \(t = 0.74") as err:
        import_recordings([bag], tmp_path / "a.h5", bag_spec())
    assert "\n" not in str(err.value)
    data = motion()
    data["ns"][200:] -= 10**9  # the driver's clock jumps back by a second (received in order)
    bag = write_bag(tmp_path / "b", "ros1", data, received=np.arange(len(data["ns"])) * 5_000_000 + EPOCH)
    with pytest.raises(InputError, match=r"b.bag: message 201: time decreases"):
        import_recordings([bag], tmp_path / "b.h5", bag_spec())


def test_messages_reordered_on_the_way_are_sorted_by_their_stamps_and_reported(tmp_path, capsys):
    """Three messages received a few cycles late (their header stamps in order of the motion): the import
    sorts them by their stamps, says so, and gives the dataset of the data in order; read by the receive
    times (``stamps: receive``) it keeps the order received and notes the stamps that run backwards."""
    data = motion()
    arrival = np.arange(len(data["ns"]))
    for k, late in ((100, 3), (230, 2), (301, 1)):  # message k arrives after the `late` ones that follow it
        arrival[k:k + late + 1] = np.r_[arrival[k + 1:k + late + 1], arrival[k]]
    shuffled = {key: v[arrival] for key, v in data.items()}
    bag = write_bag(tmp_path / "run", "mcap", shuffled, received=np.sort(data["ns"]))
    config = _config(tmp_path, joints=dict(zip(BAG_JOINTS, MODEL, strict=True)), split=SPLIT)
    assert main(["import", str(bag), "--config", str(config), "-o", str(tmp_path / "bag.h5")]) == 0
    out = capsys.readouterr().out
    assert "run.mcap: 3 messages arrived out of order (up to " in out and "sorted by their stamps" in out, out
    assert_same_dataset(tmp_path / "bag.h5", import_recordings([write_csv(tmp_path / "run.csv", data)],
                                                               tmp_path / "csv.h5", csv_spec()))
    _, _, prov = dataset(import_recordings([bag], tmp_path / "receive.h5", bag_spec(stamps="receive")))
    notes = prov["sources"][0]["notes"]
    assert notes[0] == ("the header stamps step back 3 times: the receive times are used, as stamps: receive asks "
                        "(stamps: header sorts messages a few cycles late by their stamps)")
    assert notes[1].startswith("the times on /joint_states are receive times (when the recorder got each message, "
                               "not when it was sampled): intervals ") and len(notes) == 2


def test_messages_without_the_arms_joints_or_a_field_or_a_stamp_are_left_out_and_reported(tmp_path, capsys):
    """On the topic: a gripper driver's messages (its finger alone: another publisher), messages with an empty
    velocity array and, at the start, messages with zero header stamps (a driver before its clock was set).
    Each kind is left out, counted in the provenance and the printout, and the rest imports as the data
    without those messages; a bag where no message holds every field read is refused in one line."""
    data = motion()
    names = [*BAG_JOINTS, "finger"]
    data4 = {k: (np.concatenate([v, np.full((len(v), 1), 0.04)], 1) if k != "ns" else v) for k, v in data.items()}
    gripper, blank, unset = [40, 41, 190], [77, 300], [0, 1]
    bag = write_bag(tmp_path / "run", "sqlite3", data4, names=names, header=unset, blank=blank,
                    order=lambda k: [3] if k in gripper else [0, 1, 2, 3])
    config = _config(tmp_path, joints=dict(zip(BAG_JOINTS, MODEL, strict=True)), ignore_joints=["finger"],
                     split={"train": ["run[0:1.2]"], "val": ["run[1.2:1.6]"], "test": ["run[1.6:]"]})
    assert main(["import", str(bag), "--config", str(config), "-o", str(tmp_path / "bag.h5")]) == 0
    out = capsys.readouterr().out
    assert "run.db3: 3 messages of another publisher (none of the joints read; theirs: finger) left out (messages " \
           "41, 42, 191)" in out, out
    assert "run.db3: 2 messages with no velocity values left out (messages 78, 301)" in out, out
    assert "run.db3: 2 messages with a zero header stamp (a driver that published before its clock was set) left " \
           "out (messages 1, 2)" in out, out
    _, _, prov = dataset(tmp_path / "bag.h5")
    src = prov["sources"][0]
    assert src["messages"] == 400 - 7 and src["rows"] == 400 - 7
    assert src["skipped"]["other publisher"] == {"count": 3, "first": [41, 42, 191], "joints": ["finger"]}
    kept = np.setdiff1d(np.arange(400), gripper + blank + unset)
    csv = write_csv(tmp_path / "run.csv", {k: v[kept] for k, v in data.items()})
    # the CSV's time counts from its first row, the bag's from its first message kept: the same rows
    assert_same_dataset(tmp_path / "bag.h5", import_recordings([csv], tmp_path / "csv.h5", csv_spec()))
    # no message with a velocity: refused, naming the field and the way out
    (tmp_path / "v").mkdir()
    none = write_bag(tmp_path / "v" / "run", "mcap", data, blank=range(400))
    err = _refused(tmp_path, capsys, none)
    assert "run.mcap: 0 messages on /joint_states hold every field read: message 1 holds 0 velocity values for its " \
           "joints, as do 399 more (leave it out of streams)" in err, err
    # imported without them (--streams), a fit whose targets ask for measured velocities says it has none
    assert main(["import", str(none), "--streams", "position", "effort", "-o", str(tmp_path / "novel.h5"), "--config",
                 str(_config(tmp_path, joints=dict(zip(BAG_JOINTS, MODEL, strict=True)), split=SPLIT))]) == 0
    from lnn_torch.training import TrajectoryDataModule

    capsys.readouterr()
    TrajectoryDataModule(path=str(tmp_path / "novel.h5"), targets={"method": "butterworth", "cutoff": 10.0,
                                                                     "use_measured_velocity": True}).setup("fit")
    assert "novel.h5 has no measured velocities: the targets differentiate the positions (twice) instead" in \
        capsys.readouterr().out


def test_zero_header_stamps_fall_back_to_the_receive_times_and_say_so(tmp_path):
    data = motion()
    bag = write_bag(tmp_path / "run", "sqlite3", data, header=False)
    _, _, prov = dataset(import_recordings([bag], tmp_path / "bag.h5", bag_spec()))
    assert prov["sources"][0]["time"] == "the bag's receive times (every header stamp is zero)"
    assert_same_dataset(tmp_path / "bag.h5", import_recordings([write_csv(tmp_path / "run.csv", data)],
                                                               tmp_path / "csv.h5", csv_spec()))
    with pytest.raises(InputError, match="every header stamp on /joint_states is zero: set stamps to receive"):
        import_recordings([bag], tmp_path / "h.h5", bag_spec(stamps="header"))


def test_receive_times_in_bursts_are_refused_and_a_fixed_rate_publisher_is_timed_by_its_sequence(tmp_path):
    """Unstamped messages a recorder received five at a time every 25 ms (a batching network) are not sample times:
    refused in one line that says so and what to do; ``stamps: sequence`` with the publisher's dt gives the dataset
    of the CSV of the same samples; a receive time repeated with other values is refused naming the message."""
    data = motion()
    data["ns"] = EPOCH + 5_000_000 * np.arange(len(data["ns"]))  # the publisher's samples, exactly 5 ms apart
    bursts = EPOCH + 25_000_000 * (np.arange(len(data["ns"])) // 5) + 1000 * (np.arange(len(data["ns"])) % 5)
    # batches of 200 at a 1 kHz publisher, every 0.2 s: the gaps between batches are under 1 % of the intervals
    many = write_bag(tmp_path / "many", "mcap", data, header=False,
                     received=EPOCH + 200_000_000 * (np.arange(len(data["ns"])) // 200) + 1000 * np.arange(400))
    with pytest.raises(InputError, match=r"many.mcap: the receive times on /joint_states come in bursts"):
        import_recordings([many], tmp_path / "m.h5", bag_spec())
    bag = write_bag(tmp_path / "run", "sqlite3", data, header=False, received=bursts)
    with pytest.raises(InputError, match=r"run.db3: the receive times on /joint_states come in bursts \(80 % of the "
                                         r"messages within 1.48 ms of the one before, .*: they are not the sample "
                                         r"times; .* set stamps: sequence with dt$"):
        import_recordings([bag], tmp_path / "b.h5", bag_spec())
    with pytest.raises(InputError, match="stamps: sequence times the messages one dt apart: set dt"):
        import_recordings([bag], tmp_path / "b.h5", bag_spec(stamps="sequence"))
    _, _, prov = dataset(import_recordings([bag], tmp_path / "bag.h5", bag_spec(stamps="sequence", dt=0.005)))
    assert prov["sources"][0]["time"] == "the messages' order, one dt (0.005 s) apart (stamps: sequence)"
    assert_same_dataset(tmp_path / "bag.h5", import_recordings([write_csv(tmp_path / "run.csv", data)],
                                                               tmp_path / "csv.h5", csv_spec(dt=0.005)))
    twice = data["ns"].copy()
    twice[7] = twice[6]  # received together with the message before, other values
    bag = write_bag(tmp_path / "twice", "mcap", data, header=False, received=twice)
    with pytest.raises(InputError, match=r"twice.mcap: message 8 on /joint_states was received at the same time as "
                                         r"message 7 with other values: receive times are not sample times"):
        import_recordings([bag], tmp_path / "t.h5", bag_spec())


def test_unstamped_messages_with_a_pause_are_no_bursts(tmp_path):
    """Receive times 5 ms apart with one pause of 3 s (a recorder paused) are steady, not bursts: the pause is a gap
    that windows keep out (its mean interval counted the pause and refused the bag as bursts)."""
    data = motion()
    received = data["ns"].copy()
    received[200:] += 3_000_000_000
    bag = write_bag(tmp_path / "run", "sqlite3", data, header=False, received=received)
    split = {"train": ["run[0:0.9]"], "val": ["run[4.1:4.5]"], "test": ["run[4.5:]"]}
    _, _, prov = dataset(import_recordings([bag], tmp_path / "bag.h5", bag_spec(split=split)))
    assert prov["sources"][0]["time"] == "the bag's receive times (every header stamp is zero)"


def write_two_topics(path: Path, data: dict, effort_ns: np.ndarray, efforts: np.ndarray) -> Path:
    """An MCAP bag with the positions and velocities of ``data`` on /joint_states (no efforts) and the efforts
    ``efforts`` stamped ``effort_ns`` on /joint_efforts (JointState of the same joints, another order)."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    JointState, Header, Time = (store.types[f] for f in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header",
                                                          "builtin_interfaces/msg/Time"))

    def message(ns, names, **arrays):
        stamp = Time(sec=int(ns // 10**9), nanosec=int(ns % 10**9))
        full = {f: np.ascontiguousarray(arrays.get(f, np.zeros(0))) for f in ("position", "velocity", "effort")}
        return store.serialize_cdr(JointState(header=Header(stamp=stamp, frame_id=""), name=names, **full),
                                   JointState.__msgtype__)

    with Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        states = w.add_connection("/joint_states", JointState.__msgtype__, typestore=store)
        torques = w.add_connection("/joint_efforts", JointState.__msgtype__, typestore=store)
        messages = [(int(ns), states, message(ns, BAG_JOINTS, position=data["pos"][k], velocity=data["vel"][k]))
                    for k, ns in enumerate(data["ns"])]
        messages += [(int(ns), torques, message(ns, BAG_JOINTS[::-1], effort=efforts[k, ::-1]))
                     for k, ns in enumerate(effort_ns)]
        for ns, conn, raw in sorted(messages, key=lambda m: m[0]):
            w.write(conn, ns, raw)
    return path


def test_efforts_on_a_topic_of_their_own_are_interpolated_to_the_positions_times(tmp_path, capsys):
    """Efforts published on /joint_efforts at the positions' stamps import to the dataset of the CSV of the same
    data; published at other times (a drive bus at its own rate, 3.3 ms after the 5 ms state and starting 50 ms
    later) they are the efforts at the positions' times to the linear interpolation's error, the position
    messages before the first effort left out and counted; named where streams leaves effort out, refused."""
    data = motion()
    (tmp_path / "same").mkdir()
    bag = write_two_topics(tmp_path / "same" / "run", data, data["ns"], data["eff"])
    spec = bag_spec(effort_topic="/joint_efforts")
    _, _, prov = dataset(import_recordings([bag], tmp_path / "bag.h5", spec))
    assert prov["sources"][0]["effort_topic"] == "/joint_efforts" and "skipped" not in prov["sources"][0]
    assert_same_dataset(tmp_path / "bag.h5", import_recordings([write_csv(tmp_path / "run.csv", data)],
                                                               tmp_path / "csv.h5", csv_spec()))
    with pytest.raises(InputError, match=r"0 messages on /joint_states hold every field read: .*name the topic that "
                                         r"has the efforts in effort_topic"):
        import_recordings([bag], tmp_path / "n.h5", bag_spec())

    w = np.array([1.1, 1.7, 2.3])
    effort_ns = EPOCH + 50_000_000 + np.arange(0, 2_000_000_000, 3_300_000)
    te = (effort_ns - EPOCH) / 1e9
    (tmp_path / "other").mkdir()
    bag = write_two_topics(tmp_path / "other" / "run", data, effort_ns, np.cos(0.7 * te[:, None] + w))
    config = _config(tmp_path, joints=dict(zip(BAG_JOINTS, MODEL, strict=True)), split=SPLIT,
                     effort_topic="/joint_efforts")
    assert main(["import", str(bag), "--config", str(config), "-o", str(tmp_path / "other.h5")]) == 0
    out = capsys.readouterr().out
    early = int(((data["ns"] - EPOCH) < 50_000_000).sum())
    assert f"run: {early} messages outside the efforts' times (before the first on /joint_efforts, after the last or " \
        f"in a gap) left out (messages 1, 2, 3" in out and "efforts from /joint_efforts (607 messages, median " in out
    arrays, _, _ = dataset(tmp_path / "other.h5")
    first = (data["ns"][early] - EPOCH) / 1e9  # the recording now starts at the first message kept
    n = arrays["lengths"][0]  # the training window, from the recording's first sample
    truth = np.cos(0.7 * (first + arrays["t"][:n, None]) + w)
    np.testing.assert_allclose(arrays["tau"][0, :n], truth, atol=2e-5)  # (linear over 3.3 ms: under 1e-5)
    # a stale effort message sent again (its stamp and values) is left out and counted, not refused
    effort_ns2 = np.insert(effort_ns, 100, effort_ns[99])
    efforts2 = np.insert(np.cos(0.7 * te[:, None] + w), 100, np.cos(0.7 * te[99] + w), axis=0)
    (tmp_path / "stale").mkdir()
    stale = write_two_topics(tmp_path / "stale" / "run", data, effort_ns2, efforts2)
    _, _, prov = dataset(import_recordings([stale], tmp_path / "stale.h5", bag_spec(effort_topic="/joint_efforts")))
    assert prov["sources"][0]["skipped"]["repeated on /joint_efforts"]["count"] == 1
    with pytest.raises(InputError, match="stamps: sequence times one topic's messages by their order"):
        import_recordings([bag], tmp_path / "q.h5", bag_spec(effort_topic="/joint_efforts", stamps="sequence",
                                                             dt=0.005))
    with pytest.raises(InputError, match="effort_topic names the efforts' topic, but streams leaves effort out"):
        import_recordings([bag], tmp_path / "s.h5", bag_spec(effort_topic="/joint_efforts",
                                                             streams=["position", "velocity"]))


# ---------------------------------------------------------------------------- 3. one-line refusals
def _config(tmp_path, **fields) -> Path:
    import yaml

    path = tmp_path / f"import_{len(list(tmp_path.glob('import_*.yaml')))}.yaml"
    path.write_text(yaml.safe_dump(fields))
    return path


def _refused(tmp_path, capsys, bag, **fields) -> str:
    config = _config(tmp_path, **{"joints": dict(zip(BAG_JOINTS, MODEL, strict=True)), "split": SPLIT, **fields})
    assert main(["import", str(bag), "--config", str(config), "-o", str(tmp_path / "o.h5")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert not (tmp_path / "o.h5").exists()
    return err


def test_a_missing_topic_an_unmapped_joint_or_the_missing_extra_is_one_line(tmp_path, capsys, monkeypatch):
    data = motion(n=60)
    bag = write_bag(tmp_path / "run", "sqlite3", data)
    assert "run.db3: no topic /arm/joint_states in the bag (its topics: /joint_states (sensor_msgs/msg/JointState)): " \
           "set topic" in _refused(tmp_path, capsys, bag, topic="/arm/joint_states")
    # a joint the mapping names that the bag lacks; a joint of the bag the mapping leaves out
    err = _refused(tmp_path, capsys, bag, joints={"arm_a": "q1", "arm_b": "q2", "arm_z": "q3"})
    assert "run.db3: message 1 on /joint_states has no joint arm_z (its joints: arm_a, arm_b, arm_c)" in err
    err = _refused(tmp_path, capsys, bag, joints={"arm_a": "q1", "arm_b": "q2"}, coord_names=["q1", "q2"])
    assert "run.db3: the bag's joint arm_c (message 1 on /joint_states) not mapped: map it in joints, or list " \
           "it in ignore_joints" in err
    # a model coordinate no bag joint is mapped to (a robot's joints), and a name the model does not have
    err = _refused(tmp_path, capsys, bag, joints={"arm_a": "q1", "arm_b": "q2"}, coord_names=MODEL)
    assert "import: joints: no bag joint is mapped to q3" in err
    err = _refused(tmp_path, capsys, bag, joints={"arm_a": "q1", "arm_b": "q2", "arm_c": "q9"}, coord_names=MODEL)
    assert "no bag joint is mapped to q3; arm_c -> q9: not in coord_names (q1, q2, q3)" in err
    # effort asked for but not recorded
    (tmp_path / "e").mkdir()
    empty = write_bag(tmp_path / "e" / "run", "mcap", {**data, "eff": None})
    assert "0 messages on /joint_states hold every field read: message 1 holds 0 effort values for its joints, as " \
           "do 59 more (leave it out of streams, or name the topic that has the efforts in effort_topic)" in \
        _refused(tmp_path, capsys, empty)
    config = _config(tmp_path, joints=dict(zip(BAG_JOINTS, MODEL, strict=True)), split=[1.0, 0.0, 0.0],
                     streams=["position", "velocity"])
    assert main(["import", str(empty), "--config", str(config), "-o", str(tmp_path / "e.h5")]) == 0
    assert read_dataset(tmp_path / "e.h5").attrs.get("inputs") is None
    # a file that is no bag, and the optional extra missing
    fake = tmp_path / "fake.db3"
    fake.write_bytes(b"not a database")
    assert "fake.db3: cannot read it as a ROS bag" in _refused(tmp_path, capsys, fake)
    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)
    assert "import: reading ROS bags needs the rosbags library: pip install 'lnn-torch[bags]'" in \
        _refused(tmp_path, capsys, bag)


# ---------------------------------------------------------------------------- 4. the torque delay
ROBOT = {"source": "franka_panda", "remove": ["hand"], "armature": "zero", "damping": "zero"}
HOME = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])


def arm_motion(t: np.ndarray, seed: int = 0):
    """A Fourier exciting trajectory of the Panda (period 10 s, 4 harmonics, about +-0.8 rad): ``q, qd,
    qdd (T, 7)`` at times ``t``, exactly."""
    rng = np.random.default_rng(seed)
    a, b = rng.uniform(-0.8, 0.8, (2, 4, 7))
    w = 2 * np.pi / 10 * np.arange(1, 5)[:, None, None]  # (4, 1, 1)
    s, c = np.sin(w * t[None, :, None]), np.cos(w * t[None, :, None])
    q = HOME + ((a[:, None] * s + b[:, None] * c) / (w / w[0])).sum(0)
    qd = ((a[:, None] * c - b[:, None] * s) * w[0]).sum(0)
    qdd = (-(a[:, None] * s + b[:, None] * c) * w * w[0]).sum(0)
    return q, qd, qdd


def delayed_arm_csv(path: Path, dt: float, delay: float, seconds: float = 20.0, noise: float = 0.05):
    """The Panda (MuJoCo's inverse dynamics, viscous and Coulomb drive friction) on ``arm_motion``, logged
    every ``dt`` with its torques ``delay`` s late (the torque stamped t was applied at t - delay), torque
    noise ``noise`` N m, encoder noise 1e-4 rad, velocity noise 1e-3 rad/s; written as a CSV. Returns the
    true torque as a function of time."""
    from lnn_torch.robots.mujoco_arm import MujocoArm

    arm = MujocoArm(ROBOT)

    def torque(t):
        q, qd, qdd = arm_motion(t)
        return arm.inverse(q, qd, qdd).numpy() + 0.3 * np.tanh(qd / 0.02) + 0.5 * qd

    t = dt * np.arange(int(round(seconds / dt)))
    tau = torque(t - delay)
    q, qd, _ = arm_motion(t)
    rng = np.random.default_rng(1)
    cols = {"time": t}
    for name, x, sd in (("q", q, 1e-4), ("dq", qd, 1e-3), ("tau", tau, noise)):
        noisy = x + sd * rng.standard_normal(x.shape)
        cols.update({f"{name}{j + 1}": noisy[:, j] for j in range(7)})
    rows = np.stack(list(cols.values()), -1)
    path.write_text(",".join(cols) + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n")
    return torque


def arm_spec(**kw) -> ImportSpec:
    return ImportSpec(**{"coordinates": [f"q{j}" for j in range(1, 8)], "velocities": [f"dq{j}" for j in range(1, 8)],
                         "inputs": [f"tau{j}" for j in range(1, 8)], "split": {"train": ["arm[0:14]"],
                         "val": ["arm[14:17]"], "test": ["arm[17:]"]}, **kw})


@pytest.mark.parametrize("dt, delay", [(0.01, 0.012), (1 / 30, -0.010)])
def test_a_known_torque_delay_is_recovered_by_the_arms_regressor_and_applied(dt, delay, tmp_path):
    """At 100 Hz (1.2 samples late) and at 30 Hz (a third of a sample early): the estimate within 1 ms
    (and 4 standard errors); ``auto`` shifts the torques back onto the motion (the held-out window's
    torque error against the true torques, against the unshifted ones), a given delay alike."""
    pytest.importorskip("mujoco")
    truth = delayed_arm_csv(tmp_path / "arm.csv", dt, delay)
    spec = arm_spec(robot=ROBOT, coord_names=[f"joint{j}" for j in range(1, 8)], torque_delay="auto")
    _, _, prov = dataset(import_recordings([tmp_path / "arm.csv"], tmp_path / "auto.h5", spec))
    report = prov["torque_delay"]
    assert "arm's regressor" in report["method"] and report["mode"] == "auto"
    assert abs(report["delay_s"] - delay) < 1e-3 and abs(report["delay_s"] - delay) < 4 * report["se_s"] + 2e-4
    assert report["applied_s"] == report["delay_s"] and report["rms_delay"] < 0.9 * report["rms_zero"]

    def error(path, entry=2):
        """The torque error (N m rms) of the held-out window's stored span against the true torques at its
        times: from the recording's first row kept (``t0_s``; a negative delay drops the rows whose shifted
        torque precedes the recording) and the span's start, every ``dt`` of the file."""
        f = read_dataset(path)
        prov = json.loads(f.attrs["provenance"])
        got = np.asarray(f.read("tau"))[entry, :np.asarray(f.read("lengths"))[entry]]
        t = prov["sources"][0]["t0_s"] + prov["entries"][entry]["from_s"] + f.dt * np.arange(len(got))
        return np.sqrt(((got - truth(t)) ** 2).mean())

    shifted = error(tmp_path / "auto.h5")
    assert shifted < 0.06  # the noise (0.05 N m; less after interpolation)
    raw = import_recordings([tmp_path / "arm.csv"], tmp_path / "raw.h5", arm_spec(torque_delay="off"))
    assert error(raw) > 1.5 * shifted  # unshifted: the delay's error on top
    fixed = dataset(import_recordings([tmp_path / "arm.csv"], tmp_path / "fixed.h5", arm_spec(
        robot=ROBOT, coord_names=[f"joint{j}" for j in range(1, 8)], torque_delay=delay)))
    assert fixed[2]["torque_delay"]["applied_s"] == delay and fixed[2]["torque_delay"]["mode"] == "fixed"
    assert "torque_delay" not in dataset(tmp_path / "raw.h5")[2]


def test_auto_applies_no_delay_that_is_within_its_errors_of_none(tmp_path, capsys):
    """Torques on time (no delay): the estimate lies within three standard errors of zero, and auto applies none
    (exact simulated torques were shifted by -11 +- 5 ms and cut by three samples), saying so."""
    pytest.importorskip("mujoco")
    delayed_arm_csv(tmp_path / "arm.csv", 0.01, 0.0)
    spec = arm_spec(robot=ROBOT, coord_names=[f"joint{j}" for j in range(1, 8)], torque_delay="auto")
    _, _, prov = dataset(import_recordings([tmp_path / "arm.csv"], tmp_path / "auto.h5", spec))
    report = prov["torque_delay"]
    assert abs(report["delay_s"]) <= 3 * report["se_s"] and not report["significant"], report
    assert report["applied_s"] == 0.0
    from lnn_torch.data.bags import delay_lines

    line = delay_lines(report, "auto", 0.0)[-1]
    assert line.endswith("not applied: within 3 standard errors of none (torque_delay: auto does not apply it "
                         "either)"), line


def test_a_known_torque_delay_is_recovered_without_a_description(tmp_path, capsys):
    """A measured system with seven angles and torques (no description): the compact basis finds a 24 ms
    delay at 125 Hz within 2 ms; the command prints the estimate per recording and for all."""
    pytest.importorskip("mujoco")
    delayed_arm_csv(tmp_path / "arm.csv", 0.008, 0.024)
    config = _config(tmp_path, **{k: v for k, v in vars(arm_spec()).items() if k in (
        "coordinates", "velocities", "inputs", "split")})
    assert main(["import", str(tmp_path / "arm.csv"), "--config", str(config), "-o", str(tmp_path / "a.h5")]) == 0
    out = capsys.readouterr().out
    report = dataset(tmp_path / "a.h5")[2]["torque_delay"]
    assert "compact basis" in report["method"] and abs(report["delay_s"] - 0.024) < 2e-3
    assert report["applied_s"] == 0.0 and report["units"] == "N m"
    assert f"torque delay, all recordings: {1e3 * report['delay_s']:+.2f} +- " in out
    assert "not applied (torque_delay: auto applies it; friction the model lacks" in out and "the halves agree" in out
    # a second recording 30 ms apart from the first: the halves disagree, auto refuses to apply a pooled delay
    delayed_arm_csv(tmp_path / "late.csv", 0.008, 0.054)
    spec = arm_spec(torque_delay="auto", torque_delay_range=0.08, split=[1.0, 0.0, 0.0])
    halves = r"\+2\d(\.\d)?, \+2\d(\.\d)?, \+5\d(\.\d)?, \+5\d(\.\d)? ms"
    with pytest.raises(InputError, match=r"torque_delay auto: the delay is not determined \(the recordings' halves "
                                         rf"give {halves}, beyond their errors"):
        import_recordings([tmp_path / "arm.csv", tmp_path / "late.csv"], tmp_path / "b.h5", spec)


def test_inputs_the_state_does_not_explain_give_no_delay_and_an_undetermined_half_no_agreement(tmp_path):
    """A recording whose torque columns hold only the sensor's noise (a free swing, the motors off): no delay is
    estimated for it, and auto says why; halves of which one is undetermined (its best shift at the edge searched)
    are not called in agreement."""
    from lnn_torch.data.bags import delay_lines

    pytest.importorskip("mujoco")
    delayed_arm_csv(tmp_path / "arm.csv", 0.008, 0.0, seconds=8.0)
    lines = (tmp_path / "arm.csv").read_text().splitlines()
    header = lines[0].split(",")
    rng = np.random.default_rng(0)
    rows = [[float(v) for v in line.split(",")] for line in lines[1:]]
    for r in rows:
        for j in range(7):
            r[header.index(f"tau{j + 1}")] = 0.05 * rng.standard_normal()
    (tmp_path / "swing.csv").write_text(lines[0] + "\n" + "\n".join(",".join(map(repr, r)) for r in rows) + "\n")
    spec = arm_spec(torque_delay="auto", split=[1.0, 0.0, 0.0])
    with pytest.raises(InputError, match=r"torque_delay auto: no recording gives an estimate of the delay \(swing: the "
                                         r"state explains \d+% of its inputs' variance at no delay, a fit of noise "
                                         r"\d+%: too little to time them"):
        import_recordings([tmp_path / "swing.csv"], tmp_path / "s.h5", spec)
    report = {"method": "m", "searched_s": 0.05, "delay_s": -0.05, "se_s": math.inf, "birge": math.inf,
              "consistent": False, "recordings": []}
    line = delay_lines(report, "estimate", 0.0)[-1]
    assert "a half's delay is undetermined (at the edge searched)" in line and "agree" not in line


def test_a_torque_delay_setting_is_checked(tmp_path):
    for bad in ("soon", float("nan"), True):
        with pytest.raises(InputError, match="torque_delay must be a delay in s, auto or off"):
            csv_spec(torque_delay=bad)
    assert csv_spec(torque_delay="0.004").torque_delay == 0.004  # the command line's text
    with pytest.raises(InputError, match="streams lists position and any of velocity, effort"):
        bag_spec(streams=["velocity"])
    data = motion()
    csv = write_csv(tmp_path / "run.csv", data)
    with pytest.raises(InputError, match="joints maps a ROS bag's joint names; a CSV's columns are named"):
        import_recordings([csv], tmp_path / "x.h5", bag_spec())
    bag = write_bag(tmp_path / "other", "mcap", data)
    with pytest.raises(InputError, match="give CSV recordings or ROS bags, not both"):
        import_recordings([csv, bag], tmp_path / "x.h5", bag_spec())


# ---------------------------------------------------------------------------- 5. the two real bags
def _shared(name: str) -> Path:
    path = SHARED / name
    if not path.exists():
        pytest.skip(f"{path} is not here (the shared ROS 2 bags)")
    return path


def test_the_real_franka_bag_imports_with_its_plain_config(tmp_path, capsys):
    bag = _shared("panda_exciting_trajectory.db3")
    assert main(["import", str(bag), "--config", str(ROOT / "configs" / "import" / "franka_bag.yaml"),
                 "-o", str(tmp_path / "franka.h5")]) == 0
    out = capsys.readouterr().out
    assert "panda_exciting_trajectory.db3: ROS 2 bag (sqlite3), topic /joint_states (sensor_msgs/msg/JointState), " \
           "727 messages, time from the messages' header stamps" in out
    assert "panda_exciting_trajectory.db3: 14 repeated rows (identical to the previous one while the joints move" \
           in out and ") dropped" in out
    assert "torque delay, all recordings: " in out
    f = read_dataset(tmp_path / "franka.h5")
    prov = json.loads(f.attrs["provenance"])
    src = prov["sources"][0]
    assert src["repeated_rows"]["count"] == 14 and src["rows"] == 727 - 14 and src["messages"] == 727
    assert src["mapping"]["fer_joint1"] == "joint1" and src["joints"]["position"][6] == "fer_joint7"
    assert f.scene["coord_names"] == [f"joint{j}" for j in range(1, 8)] and f.dt == pytest.approx(0.0333)
    assert f.scene["config"]["description"]["source"] == "franka_panda"
    assert abs(prov["torque_delay"]["delay_s"]) < 0.0333 and "arm's regressor" in prov["torque_delay"]["method"]
    from lnn_torch.robots.mujoco_arm import MujocoArm

    limits = MujocoArm(ROBOT).joint_range.numpy()  # (7, 2): each fer_jointN within jointN's range
    q = np.asarray(f.read("q"))[0, :np.asarray(f.read("lengths"))[0]]
    assert (q >= limits[:, 0]).all() and (q <= limits[:, 1]).all()


def test_the_real_ur10_bag_imports_with_its_description_and_as_a_measured_system(tmp_path, capsys):
    """The UR10 bag with its shipped config: the description (configs/import/ur10.xml) names its joints as the
    bag does, so no mapping is needed; the arm's regressor explains the torques, and the two halves' delay
    estimates agree (about 13 ms, as the drives' smoothed currents would put them). Without the description
    (joints mapped to q1..q6) it is a measured system, its delay estimated on the compact basis."""
    bag = _shared("ur10_exciting_trajectory.db3")
    config = ROOT / "configs" / "import" / "ur10_bag.yaml"
    assert main(["import", str(bag), "--config", str(config), "-o", str(tmp_path / "ur10.h5")]) == 0
    out = capsys.readouterr().out
    assert "3441 messages, time from the messages' header stamps" in out and "repeated row" not in out
    f = read_dataset(tmp_path / "ur10.h5")
    prov = json.loads(f.attrs["provenance"])
    assert f.scene["dof"] == 6 and f.scene["coord_names"][0] == "shoulder_pan_joint"
    assert f.scene["config"]["description"]["source"].endswith("ur10.xml")
    assert f.dt == pytest.approx(0.008) and prov["sources"][0]["repeated_rows"]["count"] == 0
    assert prov["sources"][0]["joints"]["position"][0] == "shoulder_pan_joint"
    delay = prov["torque_delay"]
    assert "arm's regressor" in delay["method"] and 0.005 < delay["delay_s"] < 0.025, delay
    assert {k: len(v) for k, v in f.splits.items()} == {"train": 1, "val": 1, "test": 1}
    # without the description: a measured system
    names = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
             "wrist_3_joint")
    plain = config.read_text().replace("robot: {source: ur10.xml, flange: flange}\n", "joints: {"
                                       + ", ".join(f"{n}: q{i + 1}" for i, n in enumerate(names)) + "}\n")
    assert plain != config.read_text()
    (tmp_path / "plain.yaml").write_text(plain)
    assert main(["import", str(bag), "--config", str(tmp_path / "plain.yaml"), "-o", str(tmp_path / "m.h5")]) == 0
    f = read_dataset(tmp_path / "m.h5")
    prov = json.loads(f.attrs["provenance"])
    assert f.scene["coord_names"] == [f"q{j}" for j in range(1, 7)] and f.scene["config"].get("description") is None
    assert "compact basis" in prov["torque_delay"]["method"] and abs(prov["torque_delay"]["delay_s"]) < 0.05


def test_the_delays_filtered_basis_is_the_same_computed_in_segments(monkeypatch):
    """``bags._filtered_at`` (the delay's basis low-passed along time, at the rows the fit uses) gives the same
    values whether a recording is filtered at once or in segments with their margins (long recordings)."""
    from lnn_torch.data import bags

    rng = np.random.default_rng(0)
    T, dt = 3000, 0.002
    t = dt * np.arange(T)[:, None]
    q = np.sin(2 * np.pi * 0.7 * t + np.arange(3)) + 0.01 * rng.standard_normal((T, 3))
    qd, qdd = np.gradient(q, dt, axis=0), np.gradient(np.gradient(q, dt, axis=0), dt, axis=0)

    def basis(q, qd, qdd):  # (t 2, p): two equations per sample, nonlinear in the state
        return np.stack([np.concatenate([np.sin(q), qd * qdd], -1), np.concatenate([np.cos(q), np.tanh(qd)], -1)], 1)

    settings = {"method": "butterworth", "cutoff": 10.0, "order": 4, "use_measured_velocity": True}
    rows = np.arange(100, T - 100, 7)
    whole = bags._filtered_at(basis, q, qd, qdd, rows, dt, settings)
    assert whole.shape == (2 * len(rows), 6)
    monkeypatch.setattr(bags, "SEGMENT", 400)
    segmented = bags._filtered_at(basis, q, qd, qdd, rows, dt, settings)
    np.testing.assert_allclose(segmented, whole, rtol=0, atol=1e-6 * np.abs(whole).max())
