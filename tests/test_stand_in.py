"""``scripts/stand_in_recordings.py``: a simulated lab's recordings and the import configuration a lab
would write import as written, with the machine's inputs, velocities and noise as asked."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from lnn_torch.data import read_dataset
from lnn_torch.data.importer import ImportSpec, import_recordings

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "stand_in_recordings.py"


def _write(out: Path, *args: str) -> Path:
    run = subprocess.run([sys.executable, str(SCRIPT), "-o", str(out), "--recordings", "4", "--duration", "0.5",
                          *args], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]
    assert f"wrote {out}/import.yaml, {out}/truth.npz" in run.stdout
    return out / "import.yaml"


def _imported(config: Path, out: Path):
    files = sorted(config.parent.glob("run_*.csv"))
    return read_dataset(import_recordings(files, out, ImportSpec(**yaml.safe_load(config.read_text()))))


@pytest.mark.slow
def test_the_stand_in_recordings_import_as_one_machine(tmp_path):
    f = _imported(_write(tmp_path / "full"), tmp_path / "full.h5")
    assert f.measured and f.num_trajectories == 4 and f.num_inputs == 2 and f.dof == 2
    qd = f.trajectories(None).qd
    assert np.isfinite(qd.numpy()).all()  # measured velocities
    assert sum(len(v) for v in f.splits.values()) == 4
    truth = np.load(tmp_path / "full" / "truth.npz")  # the exact signals, for --score
    np.testing.assert_allclose(f.trajectories(None).q.numpy(), truth["q"], rtol=0, atol=1e-8)
    assert truth["qdd"].shape == truth["q"].shape and truth["tau"].shape[-1] == 2
    # the pendubot, positions only and noisy: one input on the first joint, no velocities
    config = _write(tmp_path / "pendubot", "--pendubot", "--positions-only", "--noise", "1e-3")
    assert yaml.safe_load(config.read_text())["input_matrix"] == [[1], [0]]
    g = _imported(config, tmp_path / "pendubot.h5")
    assert g.num_inputs == 1 and np.isnan(g.trajectories(None).qd.numpy()).all()
    # the same simulation without the noise (same seed): the angles differ by about 1e-3 rad
    clean = _imported(_write(tmp_path / "clean", "--pendubot", "--positions-only"), tmp_path / "clean.h5")
    diff = g.trajectories(None).q - clean.trajectories(None).q
    assert 5e-4 < float(diff.std()) < 2e-3
    # nothing is overwritten unasked
    run = subprocess.run([sys.executable, str(SCRIPT), "-o", str(tmp_path / "full"), "--recordings", "2"],
                         capture_output=True, text=True)
    assert run.returncode != 0 and "exists: pass --overwrite" in run.stderr
