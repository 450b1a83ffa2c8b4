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
"""

from __future__ import annotations

import argparse


def _parser() -> argparse.ArgumentParser:
    from ..export.programs import DTYPES, FORMATS, FUNCTIONS
    from ..pretrained import available

    ap = argparse.ArgumentParser(prog="lnn-torch export", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", metavar="CHECKPOINT",
                    help="a .ckpt written by lnn-torch fit, or pretrained:NAME for a shipped model "
                         f"({', '.join(available()) or 'none'})")
    ap.add_argument("--output-dir", "-o", default=None,
                    help="default: export/NAME for pretrained:NAME, else <checkpoint folder>/../export")
    ap.add_argument("--format", nargs="+", default=["pt2"], choices=FORMATS, dest="formats", metavar="FORMAT",
                    help=f"one or more of {', '.join(FORMATS)} (default pt2)")
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


def main(argv: list[str]) -> int:
    import json

    from ..export.programs import export_model
    from ..perf import configure_cpu, quiet_compile_logs
    from ..training.checkpoint_format import output_dir
    from ..training.checkpoints import load_model

    args = _parser().parse_args(argv)
    configure_cpu(args.threads)
    quiet_compile_logs()
    module = load_model(args.checkpoint)
    out_dir = output_dir(args.checkpoint, args.output_dir, "export")
    files = export_model(module, out_dir, functions=args.functions, formats=args.formats, dtype=args.dtype,
                         source=args.checkpoint, overwrite=args.overwrite)
    meta = json.loads(files[-1].read_text())
    width = max(map(len, meta["functions"]))
    for name, entry in meta["functions"].items():
        print(f"{name:<{width}}  {_signature(entry)}  {meta['dtype']}")
    print("wrote " + ", ".join(str(p) for p in files))
    return 0
