"""CSV recordings as users write them (``lnn_torch.data.importer``): time stamps in ms, lengths in mm,
semicolon- or tab-delimited files with decimal commas, a byte-order mark, comment and blank lines,
recordings sampled at different rates, dotted file names, short recordings and windows, and forces
on length coordinates; every refusal one line naming the file, the line of the file and the column."""

import gzip
import json
import re

import numpy as np
import pytest
import torch

from lnn_torch.cli import main
from lnn_torch.data import read_dataset
from lnn_torch.data.importer import ImportSpec, import_recordings
from lnn_torch.data.tables import read_csv_table, recording_name
from lnn_torch.errors import InputError

N = 200  # samples of a recording (0.4 s at 2 ms)


def signals(t: np.ndarray) -> dict:
    """Two coordinates (an angle ``a``, rad, and a length ``x``, m) and two inputs, at times ``t`` (s)."""
    return {"a": np.sin(1.3 * t), "x": 0.5 * np.cos(2.1 * t), "ta": np.cos(0.7 * t), "fx": np.sin(0.9 * t)}


def text(t: np.ndarray, cols: dict, sep: str = ",", decimal: str = ".", before: str = "", blank_every: int = 0) -> str:
    """A CSV table of ``time`` and ``cols`` (``before``: lines ahead of the header; a blank line after every
    ``blank_every`` rows)."""
    names = ["time", *cols]
    rows = np.stack([t, *(np.asarray(cols[n], dtype=np.float64) for n in cols)], -1)
    lines = [sep.join(names)]
    for k, r in enumerate(rows):
        lines.append(sep.join(repr(float(v)).replace(".", decimal) for v in r))
        if blank_every and (k + 1) % blank_every == 0:
            lines.append("")
    return before + "\n".join(lines) + "\n"


def spec(**kw) -> ImportSpec:
    return ImportSpec(**{"coordinates": ["a", "x"], "inputs": ["ta", "fx"], "angle_mask": [True, False],
                         "split": [1.0, 0.0, 0.0], **kw})


def arrays(path) -> dict:
    f = read_dataset(path)
    return {k: np.asarray(f.read(k)) for k in ("t", "q", "tau", "lengths")}


T = np.arange(N) * 0.002


@pytest.fixture
def reference(tmp_path):
    """The recording in s and m, comma-delimited, imported: what every other form must reproduce."""
    path = tmp_path / "ref" / "run.csv"
    path.parent.mkdir()
    path.write_text(text(T, signals(T)))
    return arrays(import_recordings([path], tmp_path / "ref.h5", spec()))


# ---------------------------------------------------------------------------- 1. time and length units
def test_time_and_length_units_convert_to_seconds_and_metres(reference, tmp_path):
    cols = signals(T)
    cols["x"] = 1000 * cols["x"]  # mm
    path = tmp_path / "run.csv"
    path.write_text(text(1000 * T, cols))  # ms
    got = arrays(import_recordings([path], tmp_path / "ms.h5", spec(time_units="ms", length_units="mm")))
    assert read_dataset(tmp_path / "ms.h5").dt == pytest.approx(0.002)
    for k in ("t", "lengths"):
        np.testing.assert_array_equal(got[k], reference[k])
    for k in ("q", "tau"):  # stamps divided by 1000 may differ from the seconds' in the last bit
        np.testing.assert_allclose(got[k], reference[k], rtol=0, atol=1e-12)
    # velocities in mm/s per second of time, whatever the time column's unit; nanoseconds and cm too
    cols = signals(T) | {"da": 1.3 * np.cos(1.3 * T), "dx": 100 * -1.05 * np.sin(2.1 * T)}
    cols["x"] = 100 * cols["x"]
    path.write_text(text((1e9 * T).round(), cols))
    f = read_dataset(import_recordings([path], tmp_path / "ns.h5", spec(time_units="ns", length_units="cm",
                                                                         velocities=["da", "dx"])))
    qd = np.asarray(f.read("qd"))[0]
    np.testing.assert_allclose(qd[:, 1], -1.05 * np.sin(2.1 * T), atol=1e-12)
    np.testing.assert_allclose(qd[:, 0], 1.3 * np.cos(1.3 * T), atol=1e-12)
    assert json.loads(f.attrs["provenance"])["settings"]["time_units"] == "ns"
    for bad, message in (({"time_units": "min"}, "time_units must be one of s, ms, us, ns, got 'min'"),
                         ({"length_units": "in"}, "length_units must be one of m, cm, mm, got 'in'"),
                         # (a cart's millimetres were read as degrees without a word)
                         ({"length_units": "mm", "angle_mask": None}, "length_units is mm, but every coordinate is an "
                                                                      "angle: mark the lengths false in angle_mask")):
        with pytest.raises(InputError, match=message):
            spec(**bad)


def test_the_import_command_reads_units_and_notes_a_slow_sampling_interval(tmp_path, capsys):
    path = tmp_path / "run.csv"
    path.write_text(text(1000 * T, signals(T)))  # ms stamps
    base = ["import", str(path), "--coordinates", "a", "x", "--angle-mask", "1", "0", "--inputs", "ta", "fx",
            "--split", "1", "0", "0"]
    assert main([*base, "-o", str(tmp_path / "s.h5")]) == 0  # read as seconds: accepted, with a note
    out = capsys.readouterr().out.strip().splitlines()
    notes = [line for line in out if line.startswith("note:")]
    assert len(notes) == 1 and "run.csv 2 s" in notes[0] and "time_units" in notes[0], out
    assert main([*base, "-o", str(tmp_path / "ms.h5"), "--time-units", "ms", "--length-units", "cm"]) == 0
    assert "note:" not in capsys.readouterr().out
    f = read_dataset(tmp_path / "ms.h5")
    assert f.dt == pytest.approx(0.002)
    np.testing.assert_allclose(np.asarray(f.read("q"))[0, :, 1], 0.005 * np.cos(2.1 * T), atol=1e-15)


# ---------------------------------------------------------------------------- 2. the default dt
def test_recordings_at_different_rates_need_dt_and_agreeing_ones_keep_the_first_median(tmp_path):
    """Median intervals 2 ms and 1 ms: refused without dt (the 1 ms recording would be thinned to 2 ms);
    2 ms and 2.03 ms (1.5 %), or 2 ms and 1.96 ms (2 %, but both round to 2 ms): dt = 2 ms as before."""
    slow = tmp_path / "a_slow.csv"
    fast = tmp_path / "b_fast.csv"
    slow.write_text(text(T, signals(T)))
    t_fast = np.arange(2 * N) * 0.001
    fast.write_text(text(t_fast, signals(t_fast)))
    out = tmp_path / "x.h5"
    with pytest.raises(InputError) as err:
        import_recordings([slow, fast], out, spec())
    message = str(err.value)
    assert "\n" not in message and "a_slow.csv 2 ms" in message and "b_fast.csv 1 ms" in message
    assert "differ by more than 2 %" in message and "set dt" in message and not out.exists()
    assert read_dataset(import_recordings([slow, fast], out, spec(dt=0.001))).dt == 0.001
    # within 2 %: the rounded median of the first, as before
    close = tmp_path / "c_close.csv"
    t_close = np.arange(N) * 0.00203
    close.write_text(text(t_close, signals(t_close)))
    assert read_dataset(import_recordings([close, slow], tmp_path / "y.h5", spec())).dt == 0.002
    # more than 2 % apart but each rounding to the same interval (jittered stamps): that interval
    t_close = np.arange(N) * 0.00196
    close.write_text(text(t_close, signals(t_close)))
    assert read_dataset(import_recordings([close, slow], tmp_path / "z.h5", spec())).dt == 0.002


# ---------------------------------------------------------------------------- 3. and 4. delimiters, decimals, BOM
@pytest.mark.parametrize("form", ["semicolon", "tab", "explicit", "bom", "bom_gz", "semicolon_gz"])
def test_delimiters_decimal_commas_and_a_byte_order_mark_read_as_the_plain_csv(reference, tmp_path, form):
    sep = {"semicolon": ";", "semicolon_gz": ";", "tab": "\t", "explicit": "|"}.get(form, ",")
    body = text(T, signals(T), sep=sep, decimal="," if sep in ";\t" else ".")
    name = "run.csv.gz" if form.endswith("_gz") else "run.csv"
    path = tmp_path / name
    encoding = "utf-8-sig" if form.startswith("bom") else "utf-8"
    if name.endswith(".gz"):
        with gzip.open(path, "wt", encoding=encoding) as fh:
            fh.write(body)
    else:
        path.write_text(body, encoding=encoding)
    kw = {"delimiter": "|"} if form == "explicit" else {}
    got = arrays(import_recordings([path], tmp_path / "x.h5", spec(**kw)))
    for k in reference:
        np.testing.assert_array_equal(got[k], reference[k])


def test_a_misread_delimiter_or_decimal_is_named_in_one_line(tmp_path):
    path = tmp_path / "run.csv"
    path.write_text(text(T, signals(T), sep="|"))
    with pytest.raises(InputError, match=r"run\.csv: no column 'time', 'a', 'x', 'ta', 'fx' in the header on line 1 "
                                         r"\(delimiter ','; columns: time\|a\|x\|ta\|fx\); set delimiter"):
        import_recordings([path], tmp_path / "x.h5", spec())
    path.write_text(text(T, signals(T), sep=";", decimal=","))
    with pytest.raises(InputError, match=r"run\.csv: line 2: column 'time': '0,0' is not a number \(decimal commas"):
        import_recordings([path], tmp_path / "x.h5", spec(decimal="."))
    path.write_text(text(T, signals(T), sep="\t", decimal=","))
    values, _ = read_csv_table(path, ["time", "x"], delimiter="tab", decimal=",")
    np.testing.assert_array_equal(values[:, 1], signals(T)["x"])
    with pytest.raises(InputError, match="decimal ',' needs a delimiter other than ','"):
        spec(delimiter=",", decimal=",")
    # a number written with a point in a file of decimal commas: 1.5, or 1500 with a thousands separator?
    lines = text(T, signals(T), sep=";", decimal=",").splitlines(keepends=True)
    lines[6] = "1.500" + lines[6][lines[6].index(";"):]
    path.write_text("".join(lines))
    with pytest.raises(InputError, match=r"run\.csv: line 7: column 'time': '1\.500' has a point where line 2 writes "
                                         r"'0,0' in column 'time' with a decimal comma \(a thousands separator\?"):
        import_recordings([path], tmp_path / "x.h5", spec())
    path.write_text(text(T, signals(T), sep=";"))  # points alone, semicolons: read as written ...
    values, _ = read_csv_table(path, ["time", "a"])
    np.testing.assert_array_equal(values[:, 1], signals(T)["a"])
    with pytest.raises(InputError, match=r"line 2: column 'time': '0\.0' has a point with decimal ','"):
        read_csv_table(path, ["time", "a"], decimal=",")  # ... but not where decimal commas are declared
    with pytest.raises(InputError, match="delimiter must be one character"):
        spec(delimiter=";;")


# ---------------------------------------------------------------------------- 5. line numbers
def test_errors_name_the_files_own_lines_past_comments_and_blank_lines(tmp_path):
    before = "# rig 3, 2024-05-01\n# units: s, rad, m\n"  # the header is line 3
    path = tmp_path / "run.csv"
    t = T.copy()
    t[30] = t[29]  # the 31st row: line 3 + 31 + 3 blank lines (one after every 10 rows)
    path.write_text(text(t, signals(T), before=before, blank_every=10))
    with pytest.raises(InputError, match=r"run\.csv: line 37: time repeats"):
        import_recordings([path], tmp_path / "x.h5", spec())
    t = T.copy()
    t[25:] += 0.1  # a gap before the 26th row: line 3 + 26 + 2
    path.write_text(text(t, signals(T), before=before, blank_every=10))
    with pytest.raises(InputError, match=r"run\.csv: line 31: a gap of 0\.102 s"):
        import_recordings([path], tmp_path / "x.h5", spec(max_gap=0.01))
    cols = signals(T)
    cols["x"][11] = np.nan  # the 12th row: line 3 + 12 + 1
    path.write_text(text(T, cols, before=before, blank_every=10))
    with pytest.raises(InputError, match=r"run\.csv: line 16: NaN or Inf in column 'x'"):
        import_recordings([path], tmp_path / "x.h5", spec())
    path.write_text(text(T, signals(T), before=before + "\n", blank_every=10))  # a blank line before the header too
    _, lines = read_csv_table(path, ["time", "a"])
    assert lines[:3].tolist() == [5, 6, 7] and lines[10] == 16 and len(lines) == N
    # a logger's comment line between rows (a marker) is a comment there too, and counts as a line
    body = text(T, signals(T)).splitlines(keepends=True)
    path.write_text("".join(body[:11] + ["# marker: payload attached\n"] + body[11:]))
    values, lines = read_csv_table(path, ["time", "a"])
    np.testing.assert_array_equal(values[:, 0], T)
    assert lines[9:11].tolist() == [11, 13] and len(lines) == N


# ---------------------------------------------------------------------------- 6. and 7. cells and columns
@pytest.mark.parametrize("problem, message", [
    ("empty", r"run\.csv: line 4: column 'x' is empty$"),
    ("text", r"run\.csv: line 4: column 'ta': 'n/a' is not a number$"),
    ("short", r"run\.csv: line 4: no value in column 'fx' \(the row has 4 cells, the header 5\)$"),
    ("twice", r"run\.csv: line 1: the header names column 'x' 2 times"),
    ("merged", r"run\.csv: line 4: 10 cells, the header names 5 \(two rows run together"),
    # what Python's float reads and no logger writes for a number: read as 1000 and 12 before
    ("underscore", r"run\.csv: line 4: column 'ta': '1_000' is not a number$"),
    ("digits", r"run\.csv: line 4: column 'ta': '١٢' is not a number$"),
    ("quote", r"run\.csv: line 4: a quoted cell in column 'ta' runs on for \d+ lines \(a quote that is never closed"),
    ("latin1", r"run\.csv: line 4: byte 0xb0 is not UTF-8 text .*: save it as UTF-8$"),
])
def test_a_bad_cell_or_a_repeated_column_is_named(tmp_path, problem, message):
    path = tmp_path / "run.csv"
    lines = text(T, signals(T)).splitlines()
    cells = lines[3].split(",")
    if problem == "empty":
        cells[2] = " "
    elif problem == "text":
        cells[3] = "n/a"
    elif problem == "short":
        cells = cells[:4]
    elif problem in ("underscore", "digits"):
        cells[3] = "1_000" if problem == "underscore" else "١٢"
    elif problem == "quote":
        cells[3] = '"' + cells[3]
    elif problem == "merged":  # a logger's line break lost: two rows as one
        cells = cells + lines[4].split(",")
        lines[2] += ","  # a trailing delimiter (an empty cell past the header) is no matter
    else:
        lines[0] = lines[0].replace("fx", "x")
    lines[3] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    if problem == "latin1":  # a comment with a degree sign saved as Latin-1
        path.write_bytes(("\n".join(lines[:3]) + "\n# at 20 \u00b0C\n" + "\n".join(lines[4:]) + "\n").encode("latin-1"))
    with pytest.raises(InputError, match=message):
        import_recordings([path], tmp_path / "x.h5", spec(inputs=["ta", "x"] if problem == "twice" else ["ta", "fx"]))
    if problem == "twice":  # a repeated column that is not read is no matter
        f = read_dataset(import_recordings([path], tmp_path / "y.h5", spec(coordinates=["a", "ta"], inputs=None)))
        np.testing.assert_array_equal(np.asarray(f.read("q"))[0, :, 1], signals(T)["ta"])


def test_angles_wrapped_into_one_turn_are_made_continuous_and_a_wrong_angle_unit_is_noted(tmp_path, capsys):
    """An encoder that reports its angle in -180..180 degrees while the joint turns over and over: the import makes
    it continuous (the same dataset as the continuous log, to round-off) and says so; a length coordinate is never
    touched. Degrees read as radians move 57 times too fast: the import notes it; the same log in degrees gives no
    note."""
    t = np.arange(2000) * 0.002  # 4 s
    turning = signals(t) | {"a": 9.0 * t + 0.5 * np.sin(3 * t)}  # 5.7 turns from 0 to 36 rad: 6 wraps
    continuous = tmp_path / "c" / "run.csv"
    continuous.parent.mkdir()
    continuous.write_text(text(t, turning | {"a": np.degrees(turning["a"])}))
    wrapped = tmp_path / "run.csv"
    wrapped.write_text(text(t, turning | {"a": (np.degrees(turning["a"]) + 180) % 360 - 180}))
    want = arrays(import_recordings([continuous], tmp_path / "c.h5", spec(angle_units="deg")))
    assert main(["import", str(wrapped), "-o", str(tmp_path / "w.h5"), "--angle-units", "deg", "--coordinates", "a",
                 "x", "--angle-mask", "1", "0", "--inputs", "ta", "fx", "--split", "1", "0", "0"]) == 0
    printed = capsys.readouterr().out
    assert "run.csv: angle a wraps into one turn (6 jumps of a whole turn between two rows): made continuous" in printed
    assert "note: the angles move" not in printed and "empty" not in printed  # (split 1 0 0: as asked)
    got = arrays(tmp_path / "w.h5")
    # a recording alone under the default fractions: validation and test are empty, and the import says how to split
    assert main(["import", str(wrapped), "-o", str(tmp_path / "one.h5"), "--angle-units", "deg", "--coordinates",
                 "a", "x", "--angle-mask", "1", "0", "--inputs", "ta", "fx"]) == 0
    assert ("note: the fractions [0.7, 0.15, 0.15] of 1 recording leave validation and test empty (fractions split "
            "whole recordings): split recordings in time with windows, e.g. split: {train: ['run[0:60]'], val: "
            "['run[60:80]'], test: ['run[80:]']} (seconds)") in capsys.readouterr().out
    np.testing.assert_allclose(got["q"], want["q"], rtol=0, atol=1e-9)
    assert np.abs(np.diff(got["q"][0, :, 0])).max() < 0.05
    assert main(["import", str(continuous), "-o", str(tmp_path / "r.h5"), "--coordinates", "a", "x", "--angle-mask",
                 "1", "0", "--inputs", "ta", "fx", "--split", "1", "0", "0"]) == 0  # degrees read as radians
    assert re.search(r"note: the angles move at up to run\.csv 5\d\d\.\d rad/s \(95th percentile; angle columns read "
                     r"in rad, time in s, median interval 2 ms\): if they are in degrees, set angle_units: deg "
                     r"\(--angle-units deg\); if the time column is in another unit, set time_units",
                     capsys.readouterr().out)


# ---------------------------------------------------------------------------- 8. names
def test_a_recording_is_named_by_its_file_name_without_its_extensions(tmp_path):
    assert [recording_name(n) for n in ("run.csv", "run.csv.gz", "run.tsv", "run.TXT", "run.dat.gz", "run.log",
                                        "exp_2024.05.01_a.csv", "exp_2024.05.01_a.csv.gz", "v1.2_run.gz")] == [
        "run", "run", "run", "run", "run", "run.log", "exp_2024.05.01_a", "exp_2024.05.01_a", "v1.2_run"]
    files = []
    for name in ("exp_2024.05.01_a.csv", "exp_2024.05.01_b.csv.gz"):
        files.append(tmp_path / name)
        body = text(T, signals(T))
        if name.endswith(".gz"):
            with gzip.open(files[-1], "wt") as fh:
                fh.write(body)
        else:
            files[-1].write_text(body)
    split = {"train": ["exp_2024.05.01_a"], "val": ["exp_2024.05.01_b[0.1:0.3]"]}
    f = read_dataset(import_recordings(files, tmp_path / "x.h5", spec(split=split)))
    assert json.loads(f.attrs["recordings"]) == ["exp_2024.05.01_a", "exp_2024.05.01_b[0.1:0.3]"]


# ---------------------------------------------------------------------------- 9. and 10. short entries, windows
def test_short_recordings_and_windows_are_refused_and_windows_count_from_the_first_sample(tmp_path):
    path = tmp_path / "tiny.csv"
    path.write_text(text(T[:10], signals(T[:10])))
    long = tmp_path / "long.csv"
    long.write_text(text(T, signals(T)))
    with pytest.raises(InputError, match=r"recording 'tiny' holds 10 samples at dt = 0\.002 s, fewer than 16"):
        import_recordings([long, path], tmp_path / "x.h5", spec(split={"train": ["long"], "val": ["tiny"]}))
    with pytest.raises(InputError, match=r"window 'long\[0\.1:0\.12\]' holds 10 samples of long at dt = 0\.002 s, "
                                         r"fewer than 16"):
        import_recordings([long], tmp_path / "x.h5", spec(split={"train": ["long[0:0.1]"], "val": ["long[0.1:0.12]"]}))
    # a time column of epoch seconds: windows are seconds from the first sample, and an empty one says so
    epoch = tmp_path / "epoch.csv"
    epoch.write_text(text(1.7e9 + T, signals(T)))
    with pytest.raises(InputError, match=r"window 'epoch\[1700000000\.1:1700000000\.3\]' holds no sample of epoch "
                                         r"\([0-9.]+ s long\); windows count seconds from the recording's first "
                                         r"sample, t = 1\.7e\+09 s"):
        import_recordings([epoch], tmp_path / "x.h5", spec(split={"train": ["epoch[1700000000.1:1700000000.3]"]}))
    f = read_dataset(import_recordings([epoch], tmp_path / "x.h5", spec(split={"train": ["epoch[0.1:0.3]"]})))
    assert json.loads(f.attrs["provenance"])["entries"][0]["window"] == [50, 150]  # 0.1-0.3 s after the first


# ---------------------------------------------------------------------------- 11. input units
def test_inputs_acting_on_lengths_are_forces(tmp_path):
    path = tmp_path / "run.csv"
    path.write_text(text(T, signals(T)))
    f = read_dataset(import_recordings([path], tmp_path / "x.h5", spec()))
    assert json.loads(f.attrs["inputs"])["units"] == ["N m", "N"]
    assert json.loads(f.attrs["units"])["tau"] == ["N m", "N"]
    f = read_dataset(import_recordings([path], tmp_path / "y.h5", spec(input_matrix=[[1, 1], [0, 1]])))
    assert json.loads(f.attrs["inputs"])["units"] == ["N m", "N or N m"]
    # a force's error is reported in N (evaluate's table and figure, the fit's summary said N m for every input)
    from lnn_torch.evaluation import evaluate_model
    from lnn_torch.systems import get_system
    from lnn_torch.training.datamodule import TrajectoryDataModule

    force = read_dataset(import_recordings([path], tmp_path / "z.h5", spec(coordinates=["x"], inputs=["fx"],
                                                                           angle_mask=[False])))
    system = get_system(force.scene["name"], **force.scene["config"])
    assert system.input_units == ("N",)

    from lnn_torch.networks.capabilities import INVERSE_DYNAMICS

    class Echo:  # inverse dynamics of zero (only the units matter here)
        capabilities = frozenset({INVERSE_DYNAMICS})

        def inverse(self, q, qd, qdd, params):
            return torch.zeros(len(q), 1, dtype=q.dtype)

    dm = TrajectoryDataModule(path=str(tmp_path / "z.h5"), targets={"method": "spline", "lam": None})
    result = evaluate_model(Echo(), system, dm.trajectories("train"), sections=["torques"])
    assert any("RMS (N): mean (tau1)" in row for row in result["_sections"]["torques"].rows)


def test_the_unit_notes_name_the_recordings_read_in_a_doubtful_unit():
    """Time stamps in ms read as seconds sample every 0.5 s or more; degrees read as radians move at 100 rad/s or
    more: each note lists the recordings that do, with the value, and names the setting; none where none does."""
    from lnn_torch.commands.import_recordings import fast_angles_note, slow_sampling_note

    sources = [{"file": "a.csv", "timing": {"median_interval_s": 2.0}, "angle_speed_p95_rad_s": 3.0},
               {"file": "b.csv", "timing": {"median_interval_s": 0.002}, "angle_speed_p95_rad_s": 172.0}]
    provenance = {"sources": sources, "settings": {"time_units": "s", "angle_units": "rad"}}
    assert slow_sampling_note(provenance) == ("note: median sampling interval a.csv 2 s (time column read in s): if "
                                              "its stamps are in ms, us or ns, set time_units (--time-units)")
    assert fast_angles_note(provenance).startswith("note: the angles move at up to b.csv 172 rad/s (95th percentile")
    calm = {"sources": [sources[0] | {"timing": {"median_interval_s": 0.01}}], "settings": {}}
    assert slow_sampling_note(calm) is None and fast_angles_note(calm) is None


def test_settings_of_the_wrong_kind_and_splits_that_cannot_mean_anything_are_named(tmp_path):
    """A config's string where a number or a list belongs (tracebacks, or a string split into letters), a window
    past the recording's end (cut to it without a word), a negative or infinite window, fractions that are not
    numbers, and a resampling interval far below the sampling interval (100 million samples asked for)."""
    path = tmp_path / "run.csv"
    path.write_text(text(T, signals(T)))
    for fields, message in (({"dt": "10ms"}, r"^import: dt must be a number \(s\), got '10ms'$"),
                            ({"max_gap": "1s"}, r"^import: max_gap must be a number \(s\), got '1s'$"),
                            ({"seed": "abc"}, r"^import: seed must be a whole number, got 'abc'$"),
                            ({"friction": "no"}, r"^import: friction must be true or false, got 'no'$"),
                            ({"coordinates": "a"}, r"^import: coordinates must be a list of column names, got 'a'$"),
                            ({"split": 5}, r"^split must be three fractions summing to 1 .*, got 5$"),
                            ({"split": [float("nan"), 0.5, 0.5]}, r"^split must be three fractions .*, got \[nan, "),
                            ({"split": {"train": ["run[0:0.3]"], "test": ["run[0.3:1.0]"]}},
                             r"^split: window 'run\[0.3:1.0\]' reaches beyond the recording 'run', which is 0.4\d* s "
                             r"long \(leave the end out for the rest of it: run\[0.3:\]\)$"),
                            ({"split": {"train": ["run[-1:0.3]"]}}, r"^split: window 'run\[-1:0.3\]': start and end "
                                                                    r"must be finite seconds"),
                            ({"split": {"train": ["run[0:inf]"]}}, r"must be finite seconds"),
                            ({"dt": 1e-7}, r"^import: dt = 1e-07 s is under 1/20 of the recordings' shortest median "
                                           r"sampling interval \(0.002 s\)")):
        with pytest.raises(InputError, match=message):
            import_recordings([path], tmp_path / "x.h5", spec(**{"split": [1.0, 0.0, 0.0], **fields}))
    assert ImportSpec(**{"coordinates": ["a"], "torque_delay": False}).torque_delay == "off"  # YAML's unquoted off
    assert not (tmp_path / "x.h5").exists()


def test_the_output_is_never_a_recording_and_a_file_is_read_as_named(tmp_path, capsys):
    """``-o run.csv --overwrite`` replaced the recording with the dataset; ``run[1].csv`` imported ``run1.csv`` (a
    glob); a file given twice became one recording; a gzip file is read whatever its name says; a key given twice
    in the config is refused."""
    from lnn_torch.commands.import_recordings import recording_paths

    path = tmp_path / "run.csv"
    path.write_text(text(T, signals(T)))
    before = path.read_bytes()
    with pytest.raises(InputError, match=r"^import: the output .*run.csv is one of the recordings read$"):
        import_recordings([path], path, spec(), overwrite=True)
    assert path.read_bytes() == before
    # a refused import leaves no folder behind (they were created before the work); a folder is no output file
    with pytest.raises(InputError, match="split: window"):
        import_recordings([path], tmp_path / "new" / "deeper" / "d.h5", spec(split={"train": ["run[0:9]"]}))
    assert not (tmp_path / "new").exists()
    with pytest.raises(IsADirectoryError, match=r"names a folder: give the dataset file's path \(e.g. "):
        import_recordings([path], f"{tmp_path}/", spec())
    (tmp_path / "run[1].csv").write_text(text(T, signals(T + 1)))
    (tmp_path / "run1.csv").write_text(text(T, signals(T)))
    assert recording_paths([str(tmp_path / "run[1].csv")]) == [str(tmp_path / "run[1].csv")]
    assert recording_paths([str(tmp_path / "run[0-9].csv")]) == [str(tmp_path / "run1.csv")]  # a pattern still is one
    with pytest.raises(InputError, match=r"/\./run.csv is given twice \(as .*/run.csv too\)$"):
        recording_paths([str(path), f"{tmp_path}/./run.csv"])
    (tmp_path / "zipped.csv").write_bytes(gzip.compress(path.read_bytes()))
    (tmp_path / "upper.csv.GZ").write_bytes(gzip.compress(path.read_bytes()))
    for name in ("zipped.csv", "upper.csv.GZ"):
        np.testing.assert_array_equal(read_csv_table(tmp_path / name, ["time", "a"])[0],
                                      read_csv_table(path, ["time", "a"])[0])
    config = tmp_path / "import.yaml"
    config.write_text("coordinates: [a, x]\nangle_units: rad\nangle_units: deg\n")
    assert main(["import", str(path), "--config", str(config), "-o", str(tmp_path / "d.h5")]) == 2
    assert "the key 'angle_units' is given twice" in capsys.readouterr().err and not (tmp_path / "d.h5").exists()
    # YAML's merge key is no key given twice; 1e-3 (text to YAML) is a number
    config.write_text("base: &b {coordinates: [a, x], inputs: [ta, fx]}\n<<: *b\nangle_mask: [true, false]\n"
                      "split: [1.0, 0.0, 0.0]\nmax_gap: 1e-1\ndrive_gains: [1e2, 2E+1]\n")
    from lnn_torch.commands.config_files import read_config

    fields = read_config(config)
    assert fields["coordinates"] == ["a", "x"] and fields["max_gap"] == 0.1 and fields["drive_gains"] == [100.0, 20.0]


def test_a_delimiter_inside_a_quoted_header_name_is_no_delimiter(tmp_path):
    """``"torque;filtered"`` named a column of a comma file: the header's ``;`` made it read as ``;``-delimited."""
    path = tmp_path / "run.csv"
    path.write_text('time,"angle;rad",x\n0,1,2\n1,2,3\n2,3,4\n')
    values, lines = read_csv_table(path, ["time", "angle;rad"])
    np.testing.assert_array_equal(values, [[0, 1], [1, 2], [2, 3]])


def test_columns_aligned_by_spaces_read_with_the_whitespace_delimiter(tmp_path):
    """A physics lab's ``.dat`` file: columns aligned by runs of spaces (and a tab), a comment first; the same
    values as the CSV."""
    path = tmp_path / "run.dat"
    path.write_text("# aligned\n  time     a        x\n  0.0      1.5      -2\n  0.1\t   2.5      -3\n\n"
                    "  0.2      3.5e-1   -4\n")
    values, lines = read_csv_table(path, ["time", "a", "x"], delimiter="whitespace")
    np.testing.assert_array_equal(values, [[0.0, 1.5, -2], [0.1, 2.5, -3], [0.2, 0.35, -4]])
    assert lines.tolist() == [3, 4, 6]
    # one space is a delimiter as a CSV has it: quoted names with a space in them read as before
    quoted = tmp_path / "quoted.txt"
    quoted.write_text('"time s" q\n0 1\n0.1 2\n')
    np.testing.assert_array_equal(read_csv_table(quoted, ["time s", "q"], delimiter=" ")[0], [[0, 1], [0.1, 2]])
