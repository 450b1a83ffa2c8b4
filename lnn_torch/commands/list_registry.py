"""``lnn-torch list``: what the package knows, read from its registries: scenes (coordinates,
parameters, inputs), model variants with their options, the parts of the structured models, shipped
models and integrators."""

from __future__ import annotations

import argparse

from .parser import CommandParser


def _parser() -> argparse.ArgumentParser:
    ap = CommandParser(prog="lnn-torch list", description=__doc__)
    ap.add_argument("what", nargs="?", default="all",
                    choices=("all", "scenes", "variants", "parts", "pretrained", "integrators"))
    return ap


def scene_rows() -> list[str]:
    from ..systems import SYSTEMS

    rows = []
    for name, cls in SYSTEMS.items():
        if not cls.closed_form:  # a measured system is as its recordings declare
            rows.append(f"  {name:<26} as recorded (lnn-torch import): coordinates, inputs and friction as declared")
            continue
        scene = cls()
        inputs = f"inputs ({', '.join(scene.input_names)})" if scene.num_inputs else "no inputs"
        friction = ", friction" if getattr(scene, "has_friction", False) else ""
        rows.append(f"  {name:<26} dof {scene.dof}: q = ({', '.join(scene.coord_names)}); params "
                    f"({', '.join(scene.param_names) or 'none'}); {inputs}{friction}")
    return rows


def variant_rows() -> list[str]:
    from ..networks import MODELS, model_options

    rows = []
    for name, cls in MODELS.items():
        opts = ", ".join(f"{k}={v!r}" for k, v in model_options(name).items())
        summary = " ".join((cls.__doc__ or "").split()).replace("``", "").split(". ")[0].split(": ", 1)[-1]
        rows.append(f"  {name:<10} {summary}\n             options: {opts}")
    return rows


def part_rows() -> list[str]:
    from ..networks.parts import KINETIC_PARTS, POTENTIAL_PARTS, SHARED_PART, part_options

    rows = []
    for role, registry in (("kinetic", KINETIC_PARTS), ("potential", POTENTIAL_PARTS),
                           ("shared", {SHARED_PART.name: SHARED_PART})):
        for name, cls in registry.items():
            opts = ", ".join(k for k in part_options(cls) if k != "residual") or "none"
            rows.append(f"  {role:<9} {name:<9} options: {opts}")
    return rows


def main(argv: list[str]) -> int:
    from ..mechanics.integrators import METHODS
    from ..pretrained import available

    what = _parser().parse_args(argv).what
    sections = {
        "scenes": ("scenes (--data.spec.scene, lnn-torch generate --scene)", scene_rows),
        "variants": ("model variants (--model.variant) and their options (--model.model_options)", variant_rows),
        "parts": ("parts of film_lnn and delan (model_options kinetic: / potential: / shared: true)", part_rows),
        "pretrained": ("shipped models (pretrained:NAME)", lambda: [f"  pretrained:{n}" for n in available()]),
        "integrators": ("integrators (--integrator)", lambda: [f"  {n}" for n in METHODS]),
    }
    for key, (title, rows) in sections.items():
        if what in ("all", key):
            print(f"{title}:\n" + "\n".join(rows()) + "\n")
    return 0
