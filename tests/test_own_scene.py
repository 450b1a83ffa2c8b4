"""``docs/own_scene.md``'s example, run as written (a new process, fewer steps and trajectories): a scene of the
user's own registered at run time is generated, trained from Python through ``make_trainer`` (its run under the
``default_root_dir`` given), evaluated and reloaded from its checkpoint in a process that registers it again;
``register_system`` refuses what is no scene and a shipped scene's name."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from lnn_torch.errors import InputError
from lnn_torch.systems import SYSTEMS, DoublePendulum, register_system

DOC = Path(__file__).resolve().parents[1] / "docs" / "own_scene.md"


def example() -> str:
    return re.search(r"```python\n(.*?)```", DOC.read_text(), re.S).group(1)


@pytest.mark.slow
def test_the_documented_scene_trains_evaluates_and_reloads(tmp_path):
    code = example().replace("STEPS = 6000", "STEPS = 300").replace("num_trajectories=200", "num_trajectories=40")
    assert "STEPS = 300" in code and "num_trajectories=40" in code
    run = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    error = float(re.search(r"held-out acceleration error ([\d.]+) %", run.stdout).group(1))
    assert error < 50  # 300 steps: far from trained, but a model of this scene's accelerations
    checkpoints = list((tmp_path / "runs" / "cart_pendulum").rglob("last.ckpt"))
    assert len(checkpoints) == 1 and not (tmp_path / "lightning_logs").exists()
    # a new process: the class defined (and registered) again, then the checkpoint loads and answers in SI
    definition = code.split("torch.set_num_threads(1)")[0]
    again = definition + (f"import lnn_torch\nm = lnn_torch.load_model({str(checkpoints[0])!r})\n"
                          "print(m.system.name, tuple(m.acceleration(torch.zeros(3, 2), torch.zeros(3, 2), "
                          "torch.tensor([[1.0, 0.3, 0.5]] * 3)).shape))\n")
    run = subprocess.run([sys.executable, "-c", again], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0 and run.stdout.strip().endswith("cart_pendulum (3, 2)"), run.stderr[-3000:]


def test_register_system_refuses_what_is_no_scene_and_a_shipped_name():
    with pytest.raises(InputError, match="is not a System subclass with a name"):
        register_system(dict)

    class Clash(DoublePendulum):
        pass

    with pytest.raises(InputError, match=r"scene 'double_pendulum' exists already \(DoublePendulum\)"):
        register_system(Clash)
    assert SYSTEMS["double_pendulum"] is DoublePendulum
