"""Export a trained checkpoint as a shipped model: ``lnn_torch/pretrained/<name>.ckpt`` + ``<name>.json``.

The exported file keeps what ``LNNModule.load_from_checkpoint`` needs (weights, normalisation
buffers, hyper-parameters, the compiled robot descriptions of description files) and drops the
optimizer and scheduler states. A run that started from another checkpoint (``model.init_from``: a
later training stage) ships without that reference; the card says what it started from
(``--started-from``).

    python scripts/export_pretrained.py lightning_logs/double_pendulum/version_0/checkpoints/last.ckpt \\
        --name double_pendulum --command "lnn-torch fit -c configs/double_pendulum.yaml" \\
        --metrics results/double_pendulum_test.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from _common import HelpFormatter, wrote

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("checkpoint", help="the .ckpt to export")
    ap.add_argument("--name", default="double_pendulum", help="writes lnn_torch/pretrained/NAME.ckpt and NAME.json")
    ap.add_argument("--command", required=True, help="the command that trained the checkpoint")
    ap.add_argument("--metrics", default=None, help="a JSON file of measured test metrics to record")
    ap.add_argument("--note", default="", help="free text for the model card (training time, machine)")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing shipped model of that name")
    ap.add_argument("--started-from", default=None,
                    help="what the run's model.init_from was (a second training stage), for the card; the shipped "
                         "hyper-parameters drop init_from, which names a file or shipped model that is not this one")
    args = ap.parse_args()
    out = ROOT / "lnn_torch" / "pretrained" / f"{args.name}.ckpt"
    if out.exists() and not args.overwrite:
        raise SystemExit(f"{out} exists; pass --overwrite to replace it")
    ckpt = torch.load(args.checkpoint, map_location="cpu", weights_only=False)
    slim = {k: ckpt[k] for k in ("state_dict", "hyper_parameters", "pytorch-lightning_version", "epoch", "global_step",
                                 "lnn_torch", "robot_descriptions")
            if k in ckpt}
    slim["state_dict"] = {k: v.clone() for k, v in slim["state_dict"].items()}
    hparams = dict(slim["hyper_parameters"])
    started_from = hparams.get("init_from")
    if started_from:  # a later stage of training: the shipped model does not depend on its source
        hparams["init_from"] = None
        slim["hyper_parameters"] = hparams
    torch.save(slim, out)
    card = {"name": args.name, "command": args.command, "source_checkpoint": str(args.checkpoint),
            "global_step": ckpt.get("global_step"), "hyper_parameters": hparams,
            **({"started_from": args.started_from or started_from} if started_from else {}),
            "datamodule_hyper_parameters": ckpt.get("datamodule_hyper_parameters", {}), "note": args.note}
    if args.metrics:
        card["test_metrics"] = json.loads(Path(args.metrics).read_text())
    (out.with_suffix(".json")).write_text(json.dumps(card, indent=2, default=str) + "\n")
    print(f"{out.name}: {out.stat().st_size / 1024:.0f} KiB")
    wrote(out, out.with_suffix(".json"))


if __name__ == "__main__":
    main()
