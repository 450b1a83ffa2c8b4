"""``scripts/join_trajectories.py``: a second seed's trajectories added to a dataset's training split,
its validation and test splits kept, and the files that are not one dataset refused."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from lnn_torch.data import DatasetSpec, generate_dataset, read_dataset
from lnn_torch.data.hdf5 import write_dataset

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "join_trajectories.py"


@pytest.fixture(scope="module")
def script():
    spec = importlib.util.spec_from_file_location("join_trajectories", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.path.insert(0, str(SCRIPT.parent))  # it imports _common from its folder
    try:
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(SCRIPT.parent))
    return module


def _pendulum(path: Path, seed: int, n: int, **kw) -> Path:
    return generate_dataset(DatasetSpec(scene="pendulum", num_trajectories=n, duration=0.2, dt=0.01, seed=seed, **kw),
                            path)


def test_the_second_seed_goes_to_training_and_the_first_files_splits_stay(tmp_path, script):
    a, b = _pendulum(tmp_path / "a.h5", 0, 10), _pendulum(tmp_path / "b.h5", 1, 10)
    arrays, splits, attrs = script.join(a, b)
    write_dataset(tmp_path / "ab.h5", arrays, splits, attrs)
    fa, fb, fab = read_dataset(a), read_dataset(b), read_dataset(tmp_path / "ab.h5")
    assert np.array_equal(fab.splits["val"], fa.splits["val"]) and np.array_equal(fab.splits["test"], fa.splits["test"])
    assert sorted(fab.splits["train"].tolist()) == sorted(fa.splits["train"].tolist()) + list(range(10, 20))
    with h5py.File(tmp_path / "ab.h5") as f, h5py.File(a) as fa_, h5py.File(b) as fb_:
        assert np.array_equal(f["q"][:10], fa_["q"][()]) and np.array_equal(f["q"][10:], fb_["q"][()])
        assert np.array_equal(f["params"][10:], fb_["params"][()])
    assert fab.spec["num_trajectories"] == 20 and fab.spec["seed"] == 0
    assert len(fb.splits["train"]) < 10  # the second file's own split is not kept: all of it trains


def test_files_that_are_not_one_datasets_trajectories_are_refused(tmp_path, script):
    a = _pendulum(tmp_path / "a.h5", 0, 4)
    with pytest.raises(SystemExit, match="same seed 0"):
        script.join(a, _pendulum(tmp_path / "same.h5", 0, 4))
    with pytest.raises(SystemExit, match="dt"):
        script.join(a, generate_dataset(DatasetSpec(scene="pendulum", num_trajectories=4, duration=0.2, dt=0.02,
                                                    seed=1), tmp_path / "dt.h5"))
