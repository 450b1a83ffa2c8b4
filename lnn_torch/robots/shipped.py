"""The robot descriptions shipped with the package (each with its licence beside it) and the
manufacturers' joint limits a description does not carry."""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
DESCRIPTIONS = {"franka_panda": HERE / "franka_panda" / "panda_arm.xml"}
# the manufacturer's joint limits, which a description (MJCF) does not carry: joint velocity (rad/s) and
# torque (N m) per joint; the Panda's from Franka Emika's datasheet ("Robot and interface
# specifications": qd_max 2.1750 (joints 1-4), 2.6100 (5-7); tau_max 87 (1-4), 12 (5-7))
LIMITS = {"franka_panda": {"velocity": (2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61),
                           "torque": (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)}}


def description_path(name: str | Path) -> Path:
    """The MJCF file of a shipped description (``franka_panda``) or of a path."""
    if str(name) in DESCRIPTIONS:
        return DESCRIPTIONS[str(name)]
    path = Path(name)
    if not path.exists():
        from ..errors import InputError

        raise InputError(f"robot description {name}: no such file, and not a shipped one ({', '.join(DESCRIPTIONS)}); "
                         "a dataset or checkpoint names the description file it was made from by its path")
    return path
