"""Robot descriptions shipped with the package (each with its licence) and their dynamics through an
established rigid-body engine (MuJoCo, ``lnn_torch.robots.mujoco_arm``; the optional dependency
``pip install 'lnn-torch[robots]'``)."""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
DESCRIPTIONS = {"franka_panda": HERE / "franka_panda" / "panda_arm.xml"}


def description_path(name: str | Path) -> Path:
    """The MJCF file of a shipped description (``franka_panda``) or of a path."""
    if str(name) in DESCRIPTIONS:
        return DESCRIPTIONS[str(name)]
    path = Path(name)
    if not path.exists():
        from ..errors import InputError

        raise InputError(f"robot description {name} is neither a shipped one ({', '.join(DESCRIPTIONS)}) nor a file")
    return path
