"""Tools whose parameters the recordings leave unknown, identified at import (``lnn-torch import``).

A robot arm's recordings name the tool each carried (``parameters.values: {run: tool}``) and declare what
is known of it (``parameters.tools: {tool: {mass: 1.2}}``: the mass; ``{mass, com}``; ``{}``: nothing; a
list: everything). The unknown entries are identified here, before the file is written, so that every
model conditions on them as on known ones (``lnn_torch.identification.payload.identify_tools``):

* jointly with the arm, on the training and validation entries: the arm's base parameters and its
  drive's linear friction (``viscous+coulomb+offset`` where the import models friction, else viscous)
  beside each tool's columns; recordings without the tool (or with a known one) tell the two apart;
* where they cannot (every such entry carries the tool), against the description as written with the drive's
  friction fitted beside the tool, said so: provisional values (the tool takes up what the description gets
  wrong about the arm);
* a tool that only held-out (test) entries carry: from those entries, against the arm identified
  above (or by least squares on the entries with known payloads; else the description), said so: its
  held-out error is then not independent of the fit, and its intervals take that arm as exact.

Accelerations for the fit are estimated per entry with ``tool_targets`` (default: a 10 Hz fourth-order
Butterworth of the measured velocities, as the shipped arm configurations train with); standard errors
are cluster-robust over blocks of one cutoff period's half (the filtered residuals' correlation); more
than ``TOOL_ROWS`` samples in all are thinned to every k-th (the report's ``stride``). The
report (values, standard errors, 95 % intervals, the entries used, what they were identified against)
is the file's provenance ``tools``.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError

TOOL_TARGETS = {"method": "butterworth", "cutoff": 10.0, "order": 4, "use_measured_velocity": True}
# the samples the tool fit takes at most (about 1 GB of regressors for a 7-joint arm): longer recordings are
# thinned to every k-th sample (the targets are filtered far below the sampling rate; the standard errors'
# blocks shrink with them), so that a long log does not exhaust memory
TOOL_ROWS = 60_000


def correlation_block(targets: dict, dt: float) -> int:
    """Samples per cluster of the standard errors: half a cutoff period (Butterworth), the window
    (Savitzky-Golay), else one."""
    if targets["method"] == "butterworth":
        return max(1, int(math.ceil(0.5 / (float(targets["cutoff"]) * dt))))
    if targets["method"] == "savgol":
        return int(targets["window"])
    return 1


def identify_at_import(system, spec, tools: dict, tool_of: dict, stems, entries, splits, arrays, dt: float):
    """``(params (N, P), report)``: the entries' parameters with every unknown tool entry identified (module
    docstring), and what was identified how."""
    from ..identification.arm_comparison import arm_chain, description_model
    from ..identification.payload import ToolsUndetermined, identify_tools
    from . import derivatives

    chain = arm_chain(system)
    targets = derivatives.settings(spec.tool_targets or TOOL_TARGETS)
    block = correlation_block(targets, dt)
    windows = arrays.get("windows")
    # each entry's samples (start, end) in its recording: its window, else the whole recording
    spans = ([(0, int(L)) for L in arrays["lengths"]] if windows is None
             else [(int(a), int(b)) for a, b in windows])
    stride = max(1, math.ceil(sum(b - a for a, b in spans) / TOOL_ROWS))
    block = max(1, math.ceil(block / stride))
    drive = {"forms": "viscous+coulomb+offset" if spec.friction else "viscous",
             "coulomb_velocity": spec.coulomb_velocity}
    params = arrays["params"].copy()
    data = []
    for k, (i, _, _, name) in enumerate(entries):
        L = int(arrays["lengths"][k])
        q, tau = arrays["q"][k, :L], arrays["tau"][k, :L]
        qd = arrays["qd"][k, :L] if spec.velocities else None
        qd_e, qdd_e = derivatives.estimate(q, dt, targets, qd)
        a, b = spans[k]
        carried = tool_of.get(stems[i])
        data.append((name, q[a:b:stride], qd_e[a:b:stride], qdd_e[a:b:stride], tau[a:b:stride],
                     carried if carried else params[k]))
    split_of = {int(k): s for s, idx in splits.items() for k in idx}
    fitting = [k for k in range(len(entries)) if split_of.get(k) in ("train", "val")]
    pending = {t: tool for t, tool in tools.items() if tool.unknown}
    seen = {data[k][5] for k in fitting if isinstance(data[k][5], str)}
    reports, values = [], {}
    description = description_model(system)

    def against_description(q, qd, qdd):
        return description.inverse(q, qd, qdd)

    arm = None
    first = {t: tool for t, tool in pending.items() if t in seen}
    known = {t: tool for t, tool in tools.items() if not tool.unknown}
    if first:
        rows = [data[k] for k in fitting]
        try:
            fit = identify_tools(chain, rows, known | first, drive=drive, block=block,
                                 against="the arm, identified with them by least squares on the training and "
                                         "validation entries")
            arm = fit.arm
        except ToolsUndetermined:  # every fitting entry carries a tool the arm cannot be told from
            carrying = [r for r in rows if isinstance(r[5], str) and r[5] in first]
            fit = identify_tools(chain, carrying, known | first, arm=against_description, block=block, drive=drive,
                                 friction=True,
                                 against="the description as written, the drive's friction fitted beside the tool "
                                         "(every training and validation entry carries the tool: it cannot be told "
                                         "from the arm's last link)")
        reports.append(fit.report() | {"held_out": False})
        values.update({t: fit.values[t] for t in first})
    rest = {t: tool for t, tool in pending.items() if t not in seen}
    free = [data[k] for k in fitting if not (isinstance(data[k][5], str) and data[k][5] in pending)]
    if rest and arm is None and free:  # the arm from the fitting entries with known payloads alone
        try:
            arm = identify_tools(chain, free, known, drive=drive, block=block).arm
        except InputError:
            arm = None
    if rest:
        rows = [d for d in data if isinstance(d[5], str) and d[5] in rest]
        if arm is not None:
            label = "the arm identified on the training and validation entries (held-out entries used)"
            fit = identify_tools(chain, rows, known | rest, arm=lambda q, qd, qdd: arm.inverse(q, qd, qdd), block=block,
                                 against=label)
        else:
            fit = identify_tools(chain, rows, known | rest, arm=against_description, block=block, drive=drive,
                                 friction=True, against="the description as written, the drive's friction fitted "
                                                        "beside the tool (held-out entries used)")
        reports.append(fit.report() | {"held_out": True})
        values.update({t: fit.values[t] for t in rest})
    for k, d in enumerate(data):
        if isinstance(d[5], str):
            row = values.get(d[5], tools[d[5]].known_row())
            if not np.isfinite(row).all():
                raise InputError(f"import: tool {d[5]!r} could not be identified (non-finite values)")
            params[k] = row
    report = {"targets": targets, "drive": drive, "fits": reports, "stride": stride,
              "entries": {d[0]: d[5] for d in data if isinstance(d[5], str)}}
    return params, report


def _provisional(fit: dict) -> str:
    """For a tool fitted against the description as written (no trained arm to fit it against), that its values
    are provisional and where better ones come from; else nothing."""
    if not fit["against"].startswith("the description"):
        return ""
    return ("; against the description as written the tool also takes up what the description gets wrong about the "
            "arm (its links' masses and inertias), which these entries cannot tell apart and its intervals do not "
            "hold: provisional values; identify it against a trained model: lnn-torch identify CHECKPOINT DATA "
            "(lnn-torch export --tool DATA NAME writes that)")


def tool_lines(report: dict) -> list[str]:
    """The identified tools, a line per tool: each entry's value with its 95 % interval, what it was
    identified against and from how many entries."""
    lines = []
    for fit in report.get("fits", []):
        for name, tool in fit["tools"].items():
            if not any("std" in p for p in tool["parameters"].values()):
                continue
            parts = []
            for key, p in tool["parameters"].items():
                scale, unit = (1e3, "mm") if p["unit"] == "m" else (1.0, p["unit"])
                if "std" in p:
                    half = (p["interval95"][1] - p["interval95"][0]) / 2
                    parts.append(f"{key} {scale * p['value']:.4g} +- {scale * half:.2g} {unit}")
                else:
                    parts.append(f"{key} {scale * p['value']:.4g} {unit} (known)")
            point = len(tool["parameters"]) == 4  # mass and centre of mass: the payloads' four values
            count = len(tool["recordings"])
            lines.append(f"tool {name} ({tool['declared']}; {count} entr{'y' if count == 1 else 'ies'}; against "
                         f"{fit['against']}): " + ", ".join(parts) + " (95 %)"
                         + (f"; every {ordinal(report['stride'])} sample (long recordings)"
                            if report.get("stride", 1) > 1 else "")
                         + "; the intervals hold the torque noise, not what the fit leaves out: "
                         + ("a point tool's own inertia (to identify it, name ten payload values in the import "
                            "config, parameters: names: [mass, cx, cy, cz, ixx, iyy, izz, ixy, ixz, iyz]) and "
                            if point else "")
                         + "friction the drive model lacks (e.g. growing with the load) shift the values by more"
                         + _provisional(fit))
    return lines


def ordinal(k: int) -> str:
    """``2`` -> ``2nd``, ``11`` -> ``11th``, ``23`` -> ``23rd``."""
    suffix = "th" if 10 <= k % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")
    return f"{k}{suffix}"
