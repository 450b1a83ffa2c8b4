"""How long a model of the 7-joint arm stays within 0.1 rad open loop, against its acceleration error:
every held-out row of ``scripts/arm_results.py`` (its JSON files) on one plot, and the least-squares line
``t = a + b ln(1 / error)`` through the learned models' rows. The line says what acceleration error an
open-loop time asks for; the grey box's row (which differs from the engine only by the integrator and
the torques held over each sample) tests whether the line holds down to it.

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
from _cli import HelpFormatter, add_output_dir, wrote

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
    add_output_dir(ap, str(ROOT / "results" / "robot_arm" / "film_lnn" / "open_loop"),
                   "the folder of open_loop.md and open_loop.png")
    args = ap.parse_args()
    table = rows(args.results)
    learned = {k: v for k, v in table.items() if k != args.reference}
    if len(learned) < 3:
        raise SystemExit(f"need at least 3 learned rows to fit a line, got {len(learned)}")
    x = np.array([math.log(1 / e) for e, _ in learned.values()])
    t = np.array([s for _, s in learned.values()])
    b, a = np.polyfit(x, t, 1)
    resid = t - (a + b * x)
    lines = [f"Held-out rows of {', '.join(f'`{p}`' for p in args.results)}; "
             f"`python scripts/arm_open_loop_vs_error.py {' '.join(args.results)}`.", "",
             "| model | acceleration rel. L2 | open loop within 0.1 rad, median | the line's time |",
             "|---|---|---|---|"]
    for name, (e, s) in sorted(table.items(), key=lambda kv: -kv[1][0]):
        lines.append(f"| {name} | {100 * e:.3g} % | {s:.2f} s | {a + b * math.log(1 / e):.2f} s |")
    lines += ["", f"The line through the {len(learned)} learned rows: t = {a:.3f} s + {b:.3f} s x ln(1 / error) "
              f"(residuals' RMS {np.sqrt(np.mean(resid ** 2)):.3f} s): {b * math.log(2):.3f} s more for each "
              "halving of the acceleration error.", "",
              "| open loop asked for | acceleration error the line gives |", "|---|---|"]
    lines += [f"| {s:.1f} s | {100 * math.exp(-(s - a) / b):.2g} % |" for s in TARGETS]
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "open_loop.md").write_text("\n".join(lines) + "\n")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for name, (e, s) in table.items():
        ax.plot(100 * e, s, "s" if name == args.reference else "o", label=name)
    grid = np.logspace(math.log10(min(e for e, _ in table.values())), math.log10(max(e for e, _ in table.values())))
    ax.plot(100 * grid, a + b * np.log(1 / grid), "k--", lw=1, label="the line (learned rows)")
    ax.set(xscale="log", xlabel="held-out acceleration error, rel. L2 (%)",
           ylabel="open loop within 0.1 rad, median (s)")
    ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(out / "open_loop.png", dpi=110)
    print("\n".join(lines))
    wrote(out / "open_loop.md", out / "open_loop.png")


if __name__ == "__main__":
    main()
