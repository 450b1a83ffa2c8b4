"""``lnn-torch export``: a trained model's dynamics as standalone programs for a control loop.

Writes, per function the model has, a ``torch.export`` program (``NAME.pt2``; and ``NAME.onnx``,
``NAME.aoti.pt2`` where asked) with a dynamic batch and SI units, the normaliser and the scene's
constants baked in, and ``export.json`` describing each: inputs and output (names, shapes, dtype,
units), the scene's conventions, the trusted parameter range and the versions that wrote them.

* ``forward_dynamics``: ``(q, qd, params[, tau]) -> qdd`` (``tau``: the inputs of an actuated scene);
* ``inverse_dynamics``: ``(q, qd, qdd, params) -> tau``;
* ``mass_matrix``: ``(q, params) -> M``;
* ``bias_force``: ``(q, qd, params) -> n``; ``gravity_force``: ``(q, params) -> n(q, 0)``;
* ``friction_force``: ``(q, qd, params) -> Q_f``;

with ``M qdd + n = B tau + Q_f``: ``n`` the Coriolis, centrifugal and gravity forces (no friction),
``Q_f`` the learned friction (``lnn_torch.networks.rigid_body`` states the convention). Inverse dynamics
and the forces need a structured model (film_lnn, delan) of a scene with inputs (friction_force: and
friction); the mass matrix a structured model. Variants whose accelerations need autograd (lnn, hnn) cannot
be exported. ONNX needs the optional packages onnx and onnxscript (``pip install 'lnn-torch[export]'``);
``aoti`` compiles each program to native code with AOTInductor (a C++ compiler, 10-20 s per
function on one thread). ``lnn_torch.export.programs`` has the details.

    lnn-torch export pretrained:double_pendulum -o exported
    lnn-torch export lightning_logs/version_0/checkpoints/last.ckpt --format pt2 onnx --dtype float64

In Python: ``torch.export.load("exported/forward_dynamics.pt2").module()(q, qd, params)``.

``--format mjcf`` or ``urdf`` hands an arm's grey box (kinetic part ``spatial``) back as its robot
description: the description it was built from with the identified link masses, centres of mass,
inertias, joint armature, damping and friction loss (and ``--payload``, the load at the flange, or
``--tool DATA NAME``, a tool of an imported dataset identified against the model as ``identify`` does),
nothing else changed; MuJoCo loaded from it has the model's rigid-body dynamics. What the format cannot express
(Coulomb smoothing, friction offset, Stribeck, a learned residual, URDF's armature) is printed and
kept in ``OUT.json`` beside it (``lnn_torch.export.description``). A URDF-described arm written as ``mjcf``
is its URDF write-back converted by MuJoCo, with the armature. ``-o`` names the file (``.xml``, ``.urdf``) or a
folder:

    lnn-torch export lightning_logs/version_0/checkpoints/last.ckpt --format mjcf -o panda_identified.xml
"""

from __future__ import annotations

import argparse

from .parser import CommandParser


def _parser() -> argparse.ArgumentParser:
    from ..export.description import FORMATS as DESCRIPTION_FORMATS
    from ..export.programs import DTYPES, FORMATS, FUNCTIONS
    from ..pretrained import available

    ap = CommandParser(prog="lnn-torch export", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", metavar="CHECKPOINT",
                    help="a .ckpt written by lnn-torch fit, or pretrained:NAME for a shipped model "
                         f"({', '.join(available()) or 'none'})")
    ap.add_argument("--output-dir", "-o", default=None,
                    help="default: export/NAME for pretrained:NAME, else <checkpoint folder>/../export; with only "
                         "mjcf or urdf it may name the file (.xml, .urdf)")
    formats = FORMATS + DESCRIPTION_FORMATS
    ap.add_argument("--format", nargs="+", default=["pt2"], choices=formats, dest="formats", metavar="FORMAT",
                    help=f"one or more of {', '.join(formats)} (default pt2); mjcf, urdf: the identified arm as its "
                         "robot description (a grey box built from one)")
    ap.add_argument("--payload", nargs="+", type=float, default=None, metavar="VALUE",
                    help="mjcf, urdf: the load at the flange written as the body 'payload' (and the model "
                         "evaluated with it): mass cx cy cz [Ixx Iyy Izz Ixy Ixz Iyz] (kg, m, kg m^2; flange frame, "
                         "inertia about its centre of mass)")
    ap.add_argument("--tool", nargs=2, default=None, metavar=("DATA", "NAME"),
                    help="mjcf, urdf: instead of --payload, the tool NAME of DATA (.h5) identified against the model "
                         "as lnn-torch identify does (as declared where the import knew all of it)")
    ap.add_argument("--functions", nargs="+", default=None, choices=FUNCTIONS, metavar="FUNCTION",
                    help=f"among {', '.join(FUNCTIONS)} (default: every one the model has)")
    ap.add_argument("--dtype", default=None, choices=sorted(DTYPES),
                    help="the programs' dtype (default: the model's own, float32 for the shipped models)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    ap.add_argument("--overwrite", action="store_true", help="replace existing output files")
    return ap


def _signature(entry: dict) -> str:
    def shape(x):
        return "[" + ", ".join(str(d) for d in x["shape"]) + "]"

    args = ", ".join(f"{x['name']}{shape(x)}" for x in entry["inputs"])
    out = entry["output"]
    return f"({args}) -> {out['name']}{shape(out)}"


def _write_descriptions(module, args, out, formats) -> None:
    """``--format mjcf|urdf``: the grey box's robot description with what it identified."""
    from pathlib import Path

    from ..errors import InputError
    from ..export.description import SUFFIXES, refusal, write_description

    why = refusal(module)
    if why is not None:
        raise InputError(why)
    out = Path(out)
    named = out.suffix.lower() in (".xml", ".mjcf", ".urdf")
    if named and len(formats) > 1:
        raise InputError(f"-o {out} names one file; {' and '.join(formats)} need a folder")
    for fmt in formats:
        if named:
            path = out
        else:
            stem = module.model.part("kinetic", "spatial").description.path.stem
            path = out / f"{stem}_identified{SUFFIXES[fmt]}"
        result = write_description(module, path, fmt, payload=args.payload, overwrite=args.overwrite)
        print(f"wrote {result.path} ({fmt}: the identified links' masses, centres of mass and inertias; the joints' "
              + ("armature, " if fmt == "mjcf" else "") + "damping and friction)")
        if result.unexpressed:
            print(f"not expressed in {fmt.upper()} (values in {result.sidecar}):")
            for line in result.unexpressed:
                print(f"  - {line}")
        for note in result.notes:
            print(f"note: {note}")


def tool_row(path: str, name: str, module, checkpoint: str) -> tuple[list[float], str]:
    """The payload row of the tool ``name`` in an imported dataset file, and where it comes from: as declared
    where the import knew all of it, else identified against the model (``module``, loaded from ``checkpoint``)
    as ``lnn-torch identify`` identifies it (from the training and validation recordings that carry it, else from
    those of the split that does): the import's own estimate was made against a classical arm or, for a tool only
    a new log carries, against the description as written."""
    import json

    from ..data import read_dataset
    from ..errors import InputError
    from ..robots.tools import Tool
    from ..training.checkpoint_format import data_hparams
    from ..training.datamodule import TrajectoryDataModule
    from .identify import tools_on_split

    f = read_dataset(path)
    provenance = json.loads(f.attrs["provenance"])
    declared = ((provenance.get("settings") or {}).get("parameters") or {}).get("tools") or {}
    if name not in declared:
        raise InputError(f"{path}: no tool {name!r} (tools: {', '.join(sorted(declared)) or 'none'})")
    width = f.read("params").shape[-1]
    if not Tool.declared(name, declared[name], width).unknown:
        return [float(v) for v in Tool.declared(name, declared[name], width).known_row()], "as declared"
    dm = TrajectoryDataModule(path=str(path), targets=data_hparams(checkpoint).get("targets", "file"))
    carried = (provenance.get("tools") or {}).get("entries", {})
    recordings = json.loads(f.attrs["recordings"])
    for split in ("train", "val", "test"):
        if any(carried.get(recordings[int(k)]) == name for k in f.splits.get(split, [])):
            report, _ = tools_on_split(module, f, dm, split, judging=False)
            tool = report["tools"][name]
            values = [p["value"] for p in tool["parameters"].values()]
            shown = ", ".join(f"{k} {p['value']:.6g} {p['unit']}"
                              + (f" [{p['interval95'][0]:.6g}, {p['interval95'][1]:.6g}]" if "interval95" in p
                                 else " (known)") for k, p in tool["parameters"].items())
            return values, (f"identified against the model from {tool['from']} ({', '.join(tool['recordings'])}): "
                            f"{shown} (95 %)")
    raise InputError(f"{path}: no recording carries tool {name!r}")


def main(argv: list[str]) -> int:
    import json

    from ..export.description import FORMATS as DESCRIPTION_FORMATS
    from ..export.programs import export_model
    from ..perf import configure_cpu, quiet_compile_logs
    from ..training.checkpoint_format import output_dir
    from ..training.checkpoints import load_model

    args = _parser().parse_args(argv)
    configure_cpu(args.threads)
    quiet_compile_logs()
    descriptions = [f for f in args.formats if f in DESCRIPTION_FORMATS]
    programs = [f for f in args.formats if f not in DESCRIPTION_FORMATS]
    if args.payload is not None and len(args.payload) not in (4, 10):
        from ..errors import InputError

        raise InputError(f"--payload takes 4 values (mass cx cy cz) or 10 (and Ixx Iyy Izz Ixy Ixz Iyz), got "
                         f"{len(args.payload)}")
    if args.tool is not None and args.payload is not None:
        from ..errors import InputError

        raise InputError("give --payload or --tool, not both")
    module = load_model(args.checkpoint)
    if args.tool is not None:
        args.payload, how = tool_row(*args.tool, module, args.checkpoint)
        print(f"tool {args.tool[1]} of {args.tool[0]}, {how}")
    out_dir = output_dir(args.checkpoint, args.output_dir, "export")
    if descriptions:
        _write_descriptions(module, args, out_dir, descriptions)
    if not programs:
        return 0
    files = export_model(module, out_dir, functions=args.functions, formats=programs, dtype=args.dtype,
                         source=args.checkpoint, overwrite=args.overwrite)
    meta = json.loads(files[-1].read_text())
    width = max(map(len, meta["functions"]))
    for name, entry in meta["functions"].items():
        print(f"{name:<{width}}  {_signature(entry)}  {meta['dtype']}")
    for name, why in (meta.get("not_in_onnx") or {}).items():
        print(f"note: {name} left out of ONNX (the other formats have it): {why}")
    print("wrote " + ", ".join(str(p) for p in files))
    return 0
