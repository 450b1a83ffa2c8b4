"""How long a model of the 7-joint arm stays within 0.1 rad open loop, against its acceleration error:
every held-out row of ``scripts/arm_results.py`` (its JSON files) on one plot, and the least-squares line
``t = a + b ln(1 / error)`` through the learned models' rows. The line says what acceleration error an
open-loop time asks for; the grey box's row (which differs from the engine only by the integrator and
the torques held over each sample) tests whether the line holds down to it. ``--physics``: rows of
physics models with known errors (``scripts/arm_perturbed_grey_box.py``), shown and left out of the fit:
whether a model of the exact form with the same acceleration error stays within 0.1 rad as long.

    python scripts/arm_open_loop_vs_error.py results/robot_arm/film_lnn/heldout.json \\
        results/robot_arm/film_lnn/heldout_4000.json -o results/robot_arm/film_lnn/open_loop

Writes ``open_loop.md`` and ``open_loop.png`` to ``--output-dir``.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
from _common import HelpFormatter, add_output_dir, wrote

ROOT = Path(__file__).resolve().parents[1]
TARGETS = (1.0, 1.5, 2.0)  # open-loop times (s) whose acceleration error the line gives


def rows(paths) -> dict:
    """``{name: (acceleration error, median time within 0.1 rad)}`` of every file, the first file's row
    where a name repeats; every file must be of the same test data."""
    out, data = {}, None
    for path in paths:
        d = json.loads(Path(path).read_text())
        if data is not None and (d["data"], d["num_test"]) != data:
            raise SystemExit(f"{path}: another test set ({d['data']}, {d['num_test']}) than {data}")
        data = (d["data"], d["num_test"])
        for name, r in d["rows"].items():
            out.setdefault(name, (r["acc_rel_err"], r["time_to_0.1"]["median"]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("results", nargs="+", help="JSON files of scripts/arm_results.py (the same test data)")
    ap.add_argument("--reference", default="grey box", help="the row of the physics model (left out of the fit)")
    ap.add_argument("--physics", nargs="+", default=[],
                    help="JSON files of physics models' rows (the same test data), left out of the fit")
    add_output_dir(ap, str(ROOT / "results" / "robot_arm" / "film_lnn" / "open_loop"),
                   "the folder of open_loop.md and open_loop.png")
    args = ap.parse_args()
    from lnn_torch.evaluation import table_header, table_row

    files = [*args.results, *args.physics]
    table = rows(files)
    physics = set(rows(args.physics))
    learned = {k: v for k, v in table.items() if k != args.reference and k not in physics}
    if len(learned) < 3:
        raise SystemExit(f"need at least 3 learned rows to fit a line, got {len(learned)}")
    x = np.array([math.log(1 / e) for e, _ in learned.values()])
    t = np.array([s for _, s in learned.values()])
    b, a = np.polyfit(x, t, 1)
    resid = t - (a + b * x)
    command = " ".join(args.results) + (f" --physics {' '.join(args.physics)}" if args.physics else "")
    lines = [f"Held-out rows of {', '.join(f'`{p}`' for p in files)}; "
             f"`python scripts/arm_open_loop_vs_error.py {command}`.", "",
             *table_header(["model", "acceleration rel. L2", "open loop within 0.1 rad, median", "the line's time"])]
    for name, (e, s) in sorted(table.items(), key=lambda kv: -kv[1][0]):
        lines.append(table_row([name, f"{100 * e:.3g} %", f"{s:.2f} s", f"{a + b * math.log(1 / e):.2f} s"]))
    left_out = f" (the {len(physics)} physics models' rows left out)" if physics else ""
    lines += ["", f"The line through the {len(learned)} learned rows{left_out}: "
              f"t = {a:.3f} s + {b:.3f} s x ln(1 / error) "
              f"(residuals' RMS {np.sqrt(np.mean(resid ** 2)):.3f} s): {b * math.log(2):.3f} s more for each "
              "halving of the acceleration error.", "",
              *table_header(["open loop asked for", "acceleration error the line gives"])]
    lines += [table_row([f"{s:.1f} s", f"{100 * math.exp(-(s - a) / b):.2g} %"]) for s in TARGETS]
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "open_loop.md").write_text("\n".join(lines) + "\n")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10.5, 4.5))
    for name, (e, s) in table.items():
        if name not in physics:
            ax.plot(100 * e, s, "s" if name == args.reference else "o", label=name)
    for i, name in enumerate(sorted(physics)):  # one entry in the legend for all of them
        e, s = table[name]
        label = f"the grey box, inertials perturbed ({len(physics)} rows)" if i == 0 else None
        ax.plot(100 * e, s, "x", color="0.3", label=label)
    grid = np.logspace(math.log10(min(e for e, _ in table.values())), math.log10(max(e for e, _ in table.values())))
    ax.plot(100 * grid, a + b * np.log(1 / grid), "k--", lw=1, label="the line (learned rows)")
    ax.set(xscale="log", xlabel="held-out acceleration error, rel. L2 (%)",
           ylabel="open loop within 0.1 rad, median (s)")
    ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    fig.tight_layout()
    fig.savefig(out / "open_loop.png", dpi=110, bbox_inches="tight")
    print("\n".join(lines))
    wrote(out / "open_loop.md", out / "open_loop.png")


if __name__ == "__main__":
    main()
