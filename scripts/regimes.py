"""Each model's accelerations per regime of motion of its scene (``lnn_torch.evaluation.regimes``: for the
double pendulum in distribution, out of the parameter range, high energy over the whole circle), the
same seeded states for every model: which model is right where a user goes.

    python scripts/regimes.py pretrained:double_pendulum pretrained:double_pendulum_control

Writes ``metrics.json`` and ``README.md`` to ``--output-dir``; prints the table.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from _common import HelpFormatter, add_output_dir, wrote


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("models", nargs="+", help="checkpoints or pretrained:<name>, all of one scene")
    ap.add_argument("--states", type=int, default=20000, help="seeded states per regime")
    ap.add_argument("--seed", type=int, default=0, help="the states' seed")
    ap.add_argument("--note", default="", help="a paragraph placed after the table (e.g. how each model was trained)")
    add_output_dir(ap, "results/regimes", "the folder of metrics.json and README.md")
    args = ap.parse_args()
    from lnn_torch import load_model
    from lnn_torch.evaluation import markdown_table, pct, regime_errors

    results, system = {}, None
    for name in args.models:
        module = load_model(name)
        if system is not None and module.system.name != system.name:
            raise SystemExit(f"{name}: scene {module.system.name}, the others' {system.name}")
        system = module.system
        results[name] = regime_errors(module.model, system, num=args.states, seed=args.seed)
    regimes = list(next(iter(results.values())))
    rows = [[name, *(f"{pct(r[g]['acc_rel_err'])} ({pct(r[g]['median'])}; {r[g]['non_finite']})" for g in regimes)]
            for name, r in results.items()]
    table = markdown_table(["model", *regimes], rows)
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps({"settings": vars(args), "scene": system.name,
                                                  "regimes": results}, indent=2) + "\n")
    doc = system.regimes.__doc__ or ""
    command = shlex.join(["python", "scripts/regimes.py", *sys.argv[1:]])
    text = f"""# Accelerations per regime of motion ({system.name})

`{command}`

Pooled relative L2 error of the accelerations against the scene's own, over {args.states} seeded states per
regime (the same for every model); in brackets the per-state median and the count of non-finite predictions.
The regimes: {" ".join(doc.split())}

{table}
{chr(10) + args.note + chr(10) if args.note else ""}"""
    (out / "README.md").write_text(text)
    print(table)
    wrote([out / "metrics.json", out / "README.md"])


if __name__ == "__main__":
    main()
