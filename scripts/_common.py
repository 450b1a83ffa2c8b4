"""What the scripts in this folder share: their one helper module (not a script; the others import it,
``python scripts/X.py`` putting this folder on ``sys.path``). A script imports no other script: code two
scripts need is here or in the library.

* The command-line conventions (``lnn_torch.cli``), the same as the package's commands:

  * a folder of results is ``--output-dir`` / ``-o`` (as ``lnn-torch evaluate`` and ``identify``); a
    single file is ``--output`` / ``-o`` (as ``lnn-torch generate``, ``simulate`` and ``import``). An old
    spelling keeps working, hidden from the help, with one line on stderr saying what to use instead;
  * a script ends by printing every path it wrote, on one line: ``wrote PATH, PATH, ...``;
  * the help states each default once: where the option's help does not already say it, and never for
    an option without one (None, False, an empty string).

  They are the library's (``lnn_torch.cli``), as the benchmarks' are; the machine header of a timing is
  ``lnn_torch.perf.machine_header``; a dataset file made from another is ``lnn_torch.data.copy_dataset``.
* The 7-joint arm's held-out table (``scripts/arm_results.py``, ``scripts/arm_perturbed_grey_box.py``):
  ``evaluate_arm``, ``add_row``, ``save_arm_table``.
* The real double pendulum's studies (``scripts/real_pendulum*.py``): the lab's model and least squares
  (``PARAMS``, ``LAB``, ``LEAST_SQUARES``), the acceleration errors per recording (``squared_sums``,
  ``squared_errors``, ``acceleration_report``), and the cross-validation's settings and runs
  (``SETTINGS``, ``CONFIGURATION``, ``setting_arguments``, ``fold_file``, ``run_folder``,
  ``fold_checkpoint``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from lnn_torch.cli import HelpFormatter, add_output_dir, add_output_file, wrote

ROOT = Path(__file__).resolve().parents[1]
__all__ = ["ROOT", "HelpFormatter", "add_output_dir", "add_output_file", "wrote"]  # the conventions, for the scripts


# ---------------------------------------------------------------------------- the 7-joint arm's held-out table
def evaluate_arm(model, system, test, horizon: float) -> dict:
    """A model's row of the arm's held-out table (``lnn_torch.evaluation.evaluate_model``): torque nMSE and
    nRMSE, acceleration error, open-loop time within 0.1 rad, power-balance error."""
    from lnn_torch.evaluation import evaluate_model

    r = evaluate_model(model, system, test, sections=("accelerations", "torques", "rollouts", "energy"),
                       accel_stride=5, horizon=horizon, thresholds=(0.1,))
    return {"acc_rel_err": r["acc_rel_err"]["total"], "torque_nmse": r.get("torque_nmse"),
            "torque_nrmse": r.get("torque_nrmse"), "time_to_0.1": r["divergence_time@0.1"]["model"],
            "power_balance_mean": r["power_balance_error"]["mean"]}


def arm_markdown(result: dict) -> str:
    """The arm's held-out table (Markdown) of ``result`` (its ``rows`` and what they were judged on)."""
    from lnn_torch.evaluation import table_header, table_row

    split = result.get("split", "test").capitalize()
    lines = [f"{split} split of `{result['data']}` ({result['num_test']} trajectories of {result['seconds']:g} s, "
             f"every 5th point for the errors); rollouts with RK4 at the data's dt, driven by the recorded torques, "
             f"from each trajectory's first state, over {result['horizon']:g} s. Command: `{result['command']}`", "",
             *table_header(["model", "torque nMSE, mean over joints", "torque nMSE per joint (1-7)",
                            "acceleration rel. L2", "time within 0.1 rad, median (q25)", "power-balance error, mean"])]
    for name, r in result["rows"].items():
        nmse = r["torque_nmse"]
        if nmse is None:  # a model without inverse dynamics (black-box LNN, direct MLP)
            mean, joints = "n/a", "n/a (no inverse dynamics)"
        else:
            mean = f"**{100 * nmse['mean']:.3g} %**"
            joints = " / ".join(f"{100 * v:.3g}" for k, v in nmse.items() if k != "mean") + " %"
        t = r["time_to_0.1"]
        cap = "≥ " if t["median"] >= result["horizon"] - 1e-9 else ""
        lines.append(table_row([name, mean, joints, f"{100 * r['acc_rel_err']:.3g} %",
                                f"{cap}{t['median']:.2f} s ({t['q25']:.2f})", f"{r['power_balance_mean']:.2e}"]))
    return "\n".join(lines) + "\n"


def add_row(result: dict, name: str, row: dict) -> None:
    """Add a model's row to ``result`` and print it (the torque's root-mean-square errors left out)."""
    result["rows"][name] = row
    print(name, json.dumps({k: v for k, v in row.items() if k != "torque_nrmse"}), flush=True)


def save_arm_table(result: dict, output) -> None:
    """Write the arm's table (Markdown) to ``output`` and its JSON beside it; print the table and the paths."""
    out = Path(output)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(arm_markdown(result))
    out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    print(arm_markdown(result))
    wrote(out, out.with_suffix(".json"))


# ---------------------------------------------------------------------------- the real double pendulum
PARAMS = ROOT / "lnn_torch" / "datasets" / "real_double_pendulum" / "identified_parameters.yml"
LAB = "lab's identified model"
LEAST_SQUARES = {"torque": "least squares of the torques (the lab model's form, on the training recordings)",
                 "acceleration": "least squares of the accelerations (the lab model's form, on the training "
                                 "recordings)"}


def acceleration_report(model, data, coord_names) -> tuple[dict, list[float]]:
    """The pooled acceleration errors (``lnn_torch.evaluation.acceleration_errors``) and the relative L2
    error of each recording over its own length, from one prediction at every point."""
    from lnn_torch.evaluation import acceleration_errors
    from lnn_torch.networks import model_accelerations

    pred = model_accelerations(model, data.q, data.qd, data.params, data.tau)
    per = [math.sqrt(e / r) for e, r in squared_sums(pred, data)]
    return acceleration_errors(pred, data.qdd, coord_names), per


def squared_sums(pred, data) -> list[tuple[float, float]]:
    """Per recording, over its own length: the summed squared acceleration error of ``pred`` and the
    summed squared reference ``data.qdd`` (their ratio's root is the relative L2 error; summed over
    recordings first, the pooled one)."""
    return [(float((pred[b, : int(n)] - data.qdd[b, : int(n)]).pow(2).sum()), float(data.qdd[b, : int(n)].pow(2).sum()))
            for b, n in enumerate(data.lengths)]


def run_folder(work: Path, recording: str, setting: str) -> Path:
    """The folder of a setting's fit on the fold that holds ``recording`` out (its checkpoint:
    ``fold_checkpoint``)."""
    return work / f"fold_{recording}" / f"setting_{list(SETTINGS).index(setting)}"


def fold_checkpoint(work: Path, recording: str, setting: str) -> Path:
    """The last checkpoint of a setting's fit on the fold that holds ``recording`` out."""
    return run_folder(work, recording, setting) / "lightning_logs" / "version_0" / "checkpoints" / "last.ckpt"


def setting_arguments(setting: dict) -> tuple[dict, list[str]]:
    """A setting's ``model.model_options`` and its other command-line overrides of the config: a setting
    is either the options themselves or ``{"model_options": {...}, "args": ["--model.lr=...", ...]}``
    (with ``"beside": NAME``: a force residual trained alone beside the setting NAME as fitted on the same
    fold, which the study fits first: ``--model.init_from`` its run, ``--model.train_only residual_force``)."""
    if "model_options" in setting:
        return setting["model_options"], list(setting.get("args", []))
    return setting, []


def fold_file(source: Path, dest: Path, held_out: int, keep: list[int], test) -> None:
    """A copy of the imported dataset whose training split is ``keep`` and validation split ``held_out``."""
    from lnn_torch.data import copy_dataset

    copy_dataset(source, dest, splits={"train": keep, "val": [held_out], "test": test})


def squared_errors(model, data) -> tuple[float, float]:
    """Summed squared acceleration error and summed squared reference over a split's recordings."""
    from lnn_torch.networks import model_accelerations

    sums = squared_sums(model_accelerations(model, data.q, data.qd, data.params, data.tau), data)
    return sum(e for e, _ in sums), sum(r for _, r in sums)


# the cross-validation's settings (``scripts/real_pendulum_cv.py``; its nested form and the corrections of
# its folds use them too)
CHAIN = {"kinetic": {"chain": {"links": [[1, 0], [1, 1]]}}}
DECAY = ["--model.weight_decay=0.1"]  # on network weights and on a residual beside the chain's gravity
CONFIGURATION = "rigid chain + its gravity + static friction (the configuration)"
SETTINGS = {
    "MLP potential (the default)": {"model_options": {"mass_invariant": [0]}, "args": DECAY},
    "harmonic potential": {"model_options": {"mass_invariant": [0], "potential": "harmonic"}, "args": DECAY},
    "harmonic series + MLP": {"model_options": {"mass_invariant": [0], "potential": ["harmonic", "mlp"]},
                              "args": DECAY},
    "rigid chain + harmonic": {**CHAIN, "potential": "harmonic"},
    "rigid chain + its gravity + harmonic residual": {"model_options": {**CHAIN, "potential": ["chain", "harmonic"]},
                                                      "args": DECAY},
    "rigid chain + its gravity": {**CHAIN, "potential": "chain"},
    CONFIGURATION: {**CHAIN, "potential": "chain", "dissipation": "joint+stiction"},
    "the configuration + learned drive gains": {**CHAIN, "potential": "chain", "dissipation": "joint+stiction",
                                                "learn_input_matrix": "gains"},
    "the configuration + learned input matrix": {**CHAIN, "potential": "chain", "dissipation": "joint+stiction",
                                                 "learn_input_matrix": True},
    "the configuration + force residual (L2 1e-3)": {**CHAIN, "potential": "chain", "dissipation": "joint+stiction",
                                                      "residual_force": {"weight": 1e-3}},
    "the configuration + force residual (L2 1e-2)": {**CHAIN, "potential": "chain", "dissipation": "joint+stiction",
                                                      "residual_force": {"weight": 1e-2}},
    "the configuration + local force residual (L2 1e-3)": {
        **CHAIN, "potential": "chain", "dissipation": "joint+stiction",
        "residual_force": {"local": True, "hidden": [16, 16], "harmonics": 3, "weight": 1e-3}},
    "the configuration + local force residual (L2 1e-2)": {
        **CHAIN, "potential": "chain", "dissipation": "joint+stiction",
        "residual_force": {"local": True, "hidden": [16, 16], "harmonics": 3, "weight": 1e-2}},
    "the configuration + force residual (L2 1e-1)": {**CHAIN, "potential": "chain", "dissipation": "joint+stiction",
                                                      "residual_force": {"weight": 1e-1}},
    "the configuration + local force residual (L2 1e-1)": {
        **CHAIN, "potential": "chain", "dissipation": "joint+stiction",
        "residual_force": {"local": True, "hidden": [16, 16], "harmonics": 3, "weight": 1e-1}},
    "the configuration + local force residual (L2 1)": {
        **CHAIN, "potential": "chain", "dissipation": "joint+stiction",
        "residual_force": {"local": True, "hidden": [16, 16], "harmonics": 3, "weight": 1.0}},
    "a local force residual (L2 1e-2) alone beside the fitted configuration": {
        "model_options": {**CHAIN, "potential": "chain", "dissipation": "joint+stiction",
                          "residual_force": {"local": True, "hidden": [16, 16], "harmonics": 3, "weight": 1e-2}},
        "beside": CONFIGURATION},
    "a force residual (L2 1e-2) alone beside the fitted configuration": {
        "model_options": {**CHAIN, "potential": "chain", "dissipation": "joint+stiction",
                          "residual_force": {"weight": 1e-2}},
        "beside": CONFIGURATION},
    "the configuration, other training batches (data.seed 1)": {
        "model_options": {**CHAIN, "potential": "chain", "dissipation": "joint+stiction"}, "args": ["--data.seed=1"]},
    "the configuration, centres of mass on the links' lines": {
        "kinetic": {"chain": {"links": [[1, 0], [1, 1]], "across": False}}, "potential": "chain",
        "dissipation": "joint+stiction"},
    "the configuration now + local force residual (L2 1)": {
        "kinetic": {"chain": {"links": [[1, 0], [1, 1]], "across": False}}, "potential": "chain",
        "dissipation": "joint+stiction",
        "residual_force": {"local": True, "hidden": [16, 16], "harmonics": 3, "weight": 1.0}},
}
