"""The training data (``lnn_torch.training.datamodule``): chunks, seeded and rank-aware sampling, fixed
evaluation sets, normalisation statistics, the dataset file a spec names, and the ``Trajectories``
container."""

import math

import numpy as np
import pytest
import torch

from lnn_torch.data import Trajectories, read_dataset

from .helpers import SPEC, make_dm


def test_chunks_are_contiguous_pieces_of_training_trajectories(dataset):
    dm = make_dm(dataset)
    dm.setup("fit")
    f = read_dataset(dataset)
    q_all = f.read("q")
    batch = next(iter(dm.train_dataloader()))
    assert batch["q"].shape == (4, 16, 2) and batch["params"].shape == (4, 16, 4)
    train = set(f.splits["train"].tolist())
    for c in range(4):
        chunk = batch["q"][c].double().numpy()
        hits = [(i, s) for i in range(len(q_all)) for s in range(q_all.shape[1] - 15)
                if np.allclose(q_all[i, s : s + 16], chunk, atol=1e-6)]
        assert hits and hits[0][0] in train


def test_chunk_sampling_is_seeded_per_epoch_and_worker_safe(dataset):
    a, b = make_dm(dataset), make_dm(dataset, num_workers=2, in_memory=False)
    for dm in (a, b):
        dm.setup("fit")
    first = [x["q"] for x in a.train_dataloader()]
    second = [x["q"] for x in b.train_dataloader()]
    for x, y in zip(first, second, strict=True):
        torch.testing.assert_close(x, y)
    a.set_epoch(1)
    other = [x["q"] for x in a.train_dataloader()]
    assert not torch.equal(first[0], other[0])


def test_eval_sets_are_fixed_and_use_the_split(dataset):
    """Validation and test yield the whole split once (what evaluate_model consumes), the same at
    every epoch; predict yields every eval_stride-th point of each test trajectory."""
    dm = make_dm(dataset)
    dm.setup("validate")
    f = read_dataset(dataset)
    v1, v2 = list(dm.val_dataloader()), list(dm.val_dataloader())
    assert len(v1) == 1 and v1[0]["accel_stride"] == 20
    torch.testing.assert_close(v1[0]["trajectories"].q, v2[0]["trajectories"].q)
    assert v1[0]["trajectories"].index.tolist() == f.splits["val"].tolist()
    np.testing.assert_array_equal(v1[0]["trajectories"].q.numpy(), f.read("q")[np.sort(f.splits["val"])])
    (test,) = list(dm.test_dataloader())
    assert test["trajectories"].index.tolist() == f.splits["test"].tolist()
    assert torch.cat([x["trajectory"] for x in dm.predict_dataloader()]).tolist() == f.splits["test"].tolist()


def test_normalisation_comes_from_the_training_split_only(dataset):
    dm = make_dm(dataset)
    f = read_dataset(dataset)
    stats = dm.normalization_data()
    np.testing.assert_array_equal(stats["params"].numpy(), f.read("params")[f.splits["train"]])


def test_nan_in_the_training_split_is_refused_naming_the_field(dataset, tmp_path):
    """NaN within a training recording made the normaliser NaN, every training step skipped and the model (all
    its predictions NaN) score 0 % on validation: the training data are refused in one line instead."""
    import shutil

    import h5py

    from lnn_torch.errors import InputError

    copy = tmp_path / "nan.h5"
    shutil.copy(dataset, copy)
    first = int(read_dataset(dataset).splits["train"][0])
    with h5py.File(copy, "r+") as f:
        f["qdd"][first, 10:13] = np.nan
    with pytest.raises(InputError, match=r"nan\.h5: the training split holds NaN or Inf in 'qdd' at 3 of its \d+ "
                                         r"points \(within the recordings' lengths\): mend or drop them") as err:
        make_dm(copy).normalization_data()
    assert "\n" not in str(err.value)


def test_float64_training_reads_float64_data_and_a_fit_without_validation_needs_no_val_split(dataset, tmp_path):
    """--trainer.precision 64 trains on the file's float64 values (a float32 copy rounded them first); a fit with
    validation off (limit_val_batches 0) takes a file without a validation split, one with validation says how."""
    from types import SimpleNamespace

    from lnn_torch.data import DatasetSpec, generate_dataset

    dm = make_dm(dataset)
    dm.trainer = SimpleNamespace(precision="64-true", limit_val_batches=1.0)
    dm.setup("fit")
    assert next(iter(dm.train_dataloader()))["q"].dtype == torch.float64
    plain = make_dm(dataset)
    plain.setup("fit")
    assert next(iter(plain.train_dataloader()))["q"].dtype == torch.float32
    path = generate_dataset(DatasetSpec(num_trajectories=6, duration=0.5, seed=1, split=[1.0, 0.0, 0.0]),
                            tmp_path / "noval.h5")
    alone = make_dm(path)
    alone.trainer = SimpleNamespace(precision="32-true", limit_val_batches=0)
    alone.setup("fit")
    alone.trainer.limit_val_batches = 1.0
    with pytest.raises(ValueError, match=r"empty 'val' split \(a fit validates on it; --trainer.limit_val_batches 0 "
                                         r"trains without validation\)"):
        alone.setup("fit")


def test_a_file_from_another_spec_is_used_with_a_warning(dataset):
    dm = make_dm(dataset, spec=dict(SPEC, num_trajectories=30))
    with pytest.warns(UserWarning, match="num_trajectories: file 20 vs config 30"):
        dm.setup("fit")


def test_missing_file_is_generated(tmp_path):
    dm = make_dm(tmp_path / "new.h5", spec=dict(SPEC, num_trajectories=10, duration=0.5))
    dm.setup("fit")
    assert (tmp_path / "new.h5").exists()


def test_distributed_chunk_sampling_is_rank_aware(dataset):
    """Under DDP, Lightning's DistributedSampler splits the epoch's batches between ranks (each
    item of the training set is a whole batch of chunks)."""
    from torch.utils.data.distributed import DistributedSampler

    dm = make_dm(dataset, steps_per_epoch=6)
    dm.setup("fit")
    ranks = [list(DistributedSampler(dm.train_set, num_replicas=2, rank=r, shuffle=False)) for r in (0, 1)]
    assert set(ranks[0]).isdisjoint(ranks[1]) and len(ranks[0]) + len(ranks[1]) == len(dm.train_set)
    batches = [[dm.train_set[i]["q"] for i in r] for r in ranks]
    for b0 in batches[0]:
        assert all(not torch.equal(b0, b1) for b1 in batches[1])


def test_trajectories_container_checks_its_shapes():
    q = torch.zeros(2, 5, 2)
    with pytest.raises(ValueError, match="shapes differ"):
        Trajectories(q, torch.zeros(2, 4, 2), torch.ones(2, 4), 0.01)
    with pytest.raises(ValueError, match="params must be"):
        Trajectories(q, q, torch.ones(3, 4), 0.01)
    t = Trajectories(q, q, torch.ones(2, 4), 0.01, index=torch.tensor([3, 7]))
    assert len(t.head(1)) == 1 and t.to(torch.float32).index.dtype == torch.long and math.isclose(t.dt, 0.01)
