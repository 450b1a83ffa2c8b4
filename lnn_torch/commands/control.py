"""``lnn-torch control``: design a controller on a model, run it in closed loop on a plant standing in
for the hardware, and report how it did.

    lnn-torch control pretrained:real_double_pendulum -c configs/control/real_double_pendulum_swingup.yaml
    lnn-torch control pretrained:double_pendulum_control -c configs/control/double_pendulum_lqr.yaml
    lnn-torch control plant -c configs/control/real_double_pendulum_swingup.yaml   # designed on the plant itself

``CHECKPOINT`` (a path or ``pretrained:NAME``) is the model the controller is designed on; ``plant``
designs it on the plant itself (the comparison a learned model has to meet). The scenario (YAML):

* ``plant``: ``{identified: FILE}`` (an identified rigid-body arm, ``lnn_torch.identification.two_link``),
  ``{scene: NAME, scene_config: {...}, params: [...], actuation: full | [true, false] ...}`` or
  ``{robot: DESCRIPTION, params: [payload]}``: a robot description's arm simulated by MuJoCo
  (``lnn_torch.robots.mujoco_arm``; a shipped name, an MJCF or URDF path, ``{source, remove, armature,
  damping, ...}`` as ``lnn-torch import`` takes it, or ``model``: the description the model was trained
  with, e.g. a measured arm's; ``params``: the payload at its flange, default none), or ``{model: design |
  CHECKPOINT, params: [...]}``: a learned model as the plant (``design``: the model the controller is
  designed on, which checks the controller and the model's plant view alone);
* ``controller``: ``{kind: swingup | reach | lqr, goal: [q...], seconds, kp, kd, Q, R, catch}``
  (``lnn_torch.control.controllers``: swing-up and reach = computed-torque tracking of a minimum-jerk
  path from the start to ``goal``, then LQR holding it, named for a pendulum's swing-up and an arm's
  reach; lqr = LQR about ``goal`` from starts near it);
* ``episodes``, ``duration`` (s), ``control_hz``, ``substeps`` (RK4 steps of the plant per control
  period), ``limits: {torque: [...]}`` (N m; one number: every input's), ``noise: {angle, velocity}``
  (standard deviations, rad and rad/s), ``delay`` (control periods), ``start: {q: [...], spread}``
  (uniform offsets, rad, at rest), ``success: {tolerance, hold}`` (within ``tolerance`` rad of the goal
  for the last ``hold`` s, no longer than ``duration``; default 1 s or the whole episode), ``seed``;
  ``calibration_seconds`` (default 1): a model learned without inputs knows its Lagrangian only up to a
  scale, calibrated from this long a recording of the plant driven by random torques
  (``lnn_torch.control.calibrate_on``) and reported. Every key is checked: one unknown, or a value of the
  wrong kind, is refused naming it.

Writes ``control.json``, ``report.md``, ``episode.png`` (angles and torques of the first episode)
and ``episode.gif`` (its animation) to ``--output-dir`` and prints the report.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import torch

from ..errors import InputError, as_number, is_number
from .parser import CommandParser

# the controllers that track a path to the goal (computed torque, then LQR), and what the report calls the path
PATHS = {"swingup": "swing-up", "reach": "reach"}
DEFAULTS = {"episodes": 100, "duration": 5.0, "control_hz": 500.0, "substeps": 2, "limits": {}, "noise": {},
            "delay": 0, "start": {}, "success": {}, "seed": 0}
# s within the tolerance at the end of an episode that count as success (success.hold; at most the episode)
DEFAULT_HOLD = 1.0
# every key a scenario may hold, per mapping (a key misspelt was ignored: `torques` ran without a torque limit)
KEYS = {"": (*DEFAULTS, "plant", "controller", "calibration_seconds"),
        "plant": ("identified", "robot", "model", "scene", "scene_config", "params", "actuation"),
        "controller": ("kind", "goal", "seconds", "kp", "kd", "Q", "R", "catch"),
        "limits": ("torque",), "noise": ("angle", "velocity"), "start": ("q", "spread"),
        "success": ("tolerance", "hold")}
# the numbers of a scenario: (mapping, key) -> (what it must be, its test)
_POSITIVE, _NONNEGATIVE = ("a number > 0", lambda x: x > 0), ("a number >= 0", lambda x: x >= 0)
NUMBERS = {("", "duration"): _POSITIVE, ("", "control_hz"): _POSITIVE, ("", "calibration_seconds"): _POSITIVE,
           ("controller", "seconds"): _POSITIVE, ("controller", "kp"): _NONNEGATIVE,
           ("controller", "kd"): _NONNEGATIVE, ("controller", "catch"): _POSITIVE,
           ("noise", "angle"): _NONNEGATIVE, ("noise", "velocity"): _NONNEGATIVE,
           ("start", "spread"): _NONNEGATIVE, ("success", "tolerance"): _POSITIVE, ("success", "hold"): _POSITIVE}
INTEGERS = {"episodes": 1, "substeps": 1, "delay": 0, "seed": 0}  # the smallest each may be
LISTS = {("controller", "goal"): None, ("start", "q"): None, ("controller", "Q"): 0.0, ("controller", "R"): 1e-300,
         ("limits", "torque"): 1e-300}  # lists of numbers (Q, R and the limit also one number), each >= this


def check_scenario(scenario, where: str) -> None:
    """Refuse, in one line naming the key, what a scenario cannot mean: a key no mapping has (``KEYS``), a mapping
    that is none, a number that is none or out of range (``NUMBERS``, ``INTEGERS``), a list that is not of
    numbers (``LISTS``), a hold longer than the episode."""
    if not isinstance(scenario, dict):
        raise InputError(f"{where}: a scenario is a mapping of settings, got {type(scenario).__name__}")
    for section, keys in KEYS.items():
        mapping = scenario if not section else scenario.get(section, {})
        if not isinstance(mapping, dict):
            raise InputError(f"{where}: {section} must be a mapping ({', '.join(keys)}), got {mapping!r}")
        unknown = [k for k in mapping if k not in keys]
        if unknown:
            name = f"{section}." if section else ""
            raise InputError(f"{where}: unknown key {name}{unknown[0]} (the keys{f' of {section}' if section else ''}: "
                             f"{', '.join(keys)})")

    def value(section, key):
        mapping = scenario if not section else scenario.get(section, {})
        return mapping.get(key)

    for (section, key), (what, ok) in NUMBERS.items():
        x = value(section, key)
        if isinstance(x, str) and x != as_number(x):  # (a number given as text)
            x = (scenario if not section else scenario[section])[key] = as_number(x)
        if x is not None and not (is_number(x, finite=True) and ok(x)):
            raise InputError(f"{where}: {section + '.' if section else ''}{key} must be {what}, got {x!r}")
    for key, least in INTEGERS.items():
        x = value("", key)
        if x is not None and not (is_number(x) and isinstance(x, int) and x >= least):
            raise InputError(f"{where}: {key} must be a whole number >= {least}, got {x!r}")
    for (section, key), least in LISTS.items():
        x = value(section, key)
        if x is None:
            continue
        items = [x] if least is not None and not isinstance(x, list) else x
        if key in ("Q", "R") and isinstance(items, list) and items and all(isinstance(v, list) for v in items):
            # a full weight matrix: its entries finite, of any sign off the diagonal (its symmetry and definiteness
            # are the LQR's to check: controllers._weights)
            items = [v for row in items for v in row]
            if all(is_number(v, finite=True) for v in items):
                continue
        if not isinstance(items, list) or not items or not all(is_number(v, finite=True) for v in items) or (
                least is not None and not all(v >= least for v in items)):
            kind = "a list of numbers" + (" (or one number)" if least is not None else "") + (
                "" if least is None else " >= 0" if least == 0.0 else " > 0")
            raise InputError(f"{where}: {section}.{key} must be {kind}, got {x!r}")
    hold, duration = value("success", "hold"), value("", "duration") or DEFAULTS["duration"]
    if hold is not None and hold > duration:
        raise InputError(f"{where}: success.hold ({hold} s) is longer than an episode (duration {duration} s)")


def _parser() -> argparse.ArgumentParser:
    ap = CommandParser(prog="lnn-torch control", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoint", metavar="CHECKPOINT",
                    help="the model the controller is designed on: a .ckpt, pretrained:NAME, or 'plant'")
    ap.add_argument("--config", "-c", required=True, help="the scenario (YAML)")
    ap.add_argument("--episodes", type=int, default=None, help="override the scenario's episode count")
    ap.add_argument("--output-dir", "-o", default=None, help="default: control/<scenario name>")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    ap.add_argument("--no-animation", action="store_true", help="skip episode.gif")
    return ap


def build_plant(spec: dict, where: str, design=None):
    """The plant of a scenario's ``plant`` mapping, its parameters ``(1, P)`` (or None) and what it
    simulates (``design``: the model, for ``robot: model``)."""
    from ..control import plant_of
    from ..identification.two_link import RigidArmModel
    from ..systems import get_system

    if "identified" in spec:
        arm = RigidArmModel.from_yaml(_data_path(spec["identified"], where))
        return plant_of(arm), None, arm
    if "robot" in spec:
        from ..robots.mujoco_arm import MujocoArm

        arm = MujocoArm(_robot_description(spec["robot"], design, where))
        params = torch.tensor([spec.get("params", [0.0] * 4)], dtype=torch.float64)
        if params.shape != (1, 4) or not torch.isfinite(params).all() or params[0, 0] < 0:
            raise InputError(f"{where}: plant.params of a robot is its payload: (mass >= 0 kg, cx, cy, cz m), got "
                             f"{spec.get('params')}")
        return plant_of(arm), params, arm
    if "model" in spec:
        model = _plant_model(spec["model"], design, where)
        plant = plant_of(model)
        params = None
        if plant.num_params:
            if "params" not in spec:
                raise InputError(f"{where}: plant.params is missing (the plant's model is conditioned on "
                                 f"{plant.num_params} parameters)")
            params = torch.tensor([spec["params"]], dtype=torch.float64)
            rest = torch.zeros(1, plant.dof, dtype=torch.float64)
            getattr(model, "model", model).check_inputs(rest, rest, params, inputs=False)
        return plant, params, model
    if "scene" in spec:
        system = get_system(spec["scene"], **spec.get("scene_config", {}))
        if "params" not in spec:
            raise InputError(f"{where}: plant.params is missing ({', '.join(system.param_names)})")
        params = torch.tensor([spec["params"]], dtype=torch.float64)
        system.check_params(params)
        return plant_of(system, actuation=spec.get("actuation")), params, system
    raise InputError(f"{where}: plant needs 'identified: FILE', 'scene: NAME' with params, 'robot: DESCRIPTION' or "
                     "'model: design | CHECKPOINT'")


def _plant_model(value, design, where: str):
    """A scenario's ``plant.model``: the model the controller is designed on (``design``) or a checkpoint."""
    from ..training.checkpoints import load_model

    if value == "design":
        if design is None:
            raise InputError(f"{where}: plant.model 'design' is the model the controller is designed on; with the "
                             "design 'plant' there is none (give a checkpoint)")
        return design
    return load_model(str(value))


def _robot_description(value, design, where: str):
    """A scenario's ``plant.robot``: the description itself, or (``model``) the one the model was trained
    with (its spatial part's, else its scene's: a measured arm's import records it)."""
    from ..robots.description import ArmDescription

    if value != "model":
        return ArmDescription.of(value)
    if design is None:
        raise InputError(f"{where}: plant.robot 'model' is the description of the model the controller is designed "
                         "on; with the design 'plant' there is none (give the description, e.g. {source: "
                         "franka_panda, remove: [hand]})")
    network = getattr(design, "model", design)
    found = next((m.description for m in network.modules() if isinstance(getattr(m, "description", None),
                                                                           ArmDescription)), None)
    if found is None and getattr(getattr(network, "scene", None), "robot_description", None):
        found = ArmDescription.of(network.scene.robot_description)
    if found is None:
        raise InputError(f"{where}: plant.robot 'model': the model was trained with no robot description (give one)")
    return found


def _data_path(name: str, where: str) -> Path:
    """A file named in a scenario: relative to the current folder, or (``lnn_torch/...``) to the
    installed package, so the shipped scenarios work from any folder."""
    path = Path(name)
    if path.exists():
        return path
    package = Path(__file__).resolve().parents[1]
    if path.parts and path.parts[0] == "lnn_torch" and (package.parent / path).exists():
        return package.parent / path
    raise InputError(f"{where}: file {name} does not exist")


def _controller(kind, plant, q0, goal, params, ctrl, dt):
    from ..control import LQR, SwingUp

    weights = {k: ctrl[k] for k in ("Q", "R") if k in ctrl}
    if kind in PATHS:
        return SwingUp(plant, q0, goal, params, seconds=float(ctrl.get("seconds", 2.0)), kp=float(ctrl.get("kp", 60.0)),
                       kd=float(ctrl.get("kd", 16.0)), dt=dt, catch=float(ctrl.get("catch", 0.1)), **weights)
    if kind == "lqr":
        return LQR(plant, goal, params, dt=dt, **weights)
    raise InputError(f"controller.kind must be swingup, reach or lqr, got {kind!r}")


def run_scenario(scenario: dict, design, where: str = "scenario", episodes: int | None = None) -> dict:
    """Run a scenario with the controller designed on ``design`` (a model, or None: the plant).
    Returns the metrics and the episodes' arrays (``_episodes``)."""
    from ..control import calibrate_on, closed_loop, plant_of, wrap

    check_scenario(scenario, where)
    s = {**DEFAULTS, **scenario}
    for key in ("plant", "controller"):
        if key not in s:
            raise InputError(f"{where}: '{key}' is missing")
    plant, params, truth = build_plant(s["plant"], where, design)
    design_plant, scale = plant, None
    if design is not None:
        design_plant = plant_of(design, actuation=s["plant"].get("actuation"))
        network = getattr(design, "model", design)
        if getattr(network, "scene", None) is not None and network.scene.num_inputs == 0:
            # learned without inputs: its Lagrangian's scale, per N m, from a recording of the plant
            scale = calibrate_on(plant, design_plant, params, float(s.get("calibration_seconds", 1.0)), int(s["seed"]))
            design_plant = plant_of(design, actuation=s["plant"].get("actuation"), torque_scale=scale)
    if design is not None and design_plant.dof != plant.dof:
        raise InputError(f"{where}: the model has {design_plant.dof} coordinates, the plant {plant.dof}")
    if episodes is not None and episodes < 1:
        raise InputError(f"--episodes must be 1 or more, got {episodes}")
    n, N = plant.dof, int(s["episodes"] if episodes is None else episodes)
    gen = torch.Generator().manual_seed(int(s["seed"]))
    ctrl = s["controller"]
    goal1 = torch.tensor([ctrl.get("goal", [math.pi] + [0.0] * (n - 1))], dtype=torch.float64)
    if goal1.shape != (1, n):
        raise InputError(f"{where}: controller.goal needs {n} values, got {goal1.tolist()[0]}")
    kind = ctrl.get("kind", "swingup")
    start = s["start"]
    centre = torch.tensor([start.get("q", [0.0] * n if kind in PATHS else goal1[0].tolist())], dtype=torch.float64)
    if centre.shape != (1, n):
        raise InputError(f"{where}: start.q needs {n} values, got {centre.tolist()[0]}")
    spread = float(start.get("spread", 0.05))
    q0 = centre + spread * (2 * torch.rand(N, n, generator=gen, dtype=torch.float64) - 1)
    goal = goal1.expand(N, -1)
    p_design = None
    if design is not None and design_plant.num_params:
        p_design = params.expand(N, -1) if params is not None else None
        if p_design is None:
            raise InputError(f"{where}: the model is conditioned on {design_plant.num_params} parameters; give "
                             "plant.params")
    p_plant = None if params is None else params.expand(N, -1)
    dt = 1.0 / float(s["control_hz"])
    controller = _controller(kind, design_plant, q0, goal, p_design if design is not None else p_plant, ctrl, dt)
    noise = s["noise"]
    std = (float(noise.get("angle", 0.0)), float(noise.get("velocity", 0.0))) if noise else None
    started = time.perf_counter()
    limit = s["limits"].get("torque")
    if limit is not None and not isinstance(limit, list):  # one number: every input's
        limit = [limit] * plant.num_inputs
    ep = closed_loop(plant, controller, q0, torch.zeros_like(q0), p_plant, float(s["duration"]), dt,
                     int(s["substeps"]), limit, std, int(s["delay"]), int(s["seed"]))
    seconds = time.perf_counter() - started
    tol = float(s["success"].get("tolerance", 0.05))
    hold = float(s["success"].get("hold", min(DEFAULT_HOLD, float(s["duration"]))))
    err = wrap(ep["q"] - goal[:, None], plant.angle_mask).abs().amax(-1)  # (N, T)
    err = torch.nan_to_num(err, nan=math.inf)
    k_hold = max(1, int(round(hold / dt)))
    success = (err[:, -k_hold:] < tol).all(-1)
    inside = err < tol
    # the first time from which the error stays within the tolerance to the end
    outside_after = torch.flip(torch.cumsum(torch.flip((~inside).int(), [1]), 1), [1]) > 0
    first = (~outside_after).int().argmax(-1).double() * dt
    reach = first[success]
    out = {"episodes": N, "success_rate": float(success.double().mean()),
           "time_to_goal_s": {"median": float(reach.median()) if len(reach) else None,
                              "q25": float(reach.quantile(0.25)) if len(reach) else None,
                              "q75": float(reach.quantile(0.75)) if len(reach) else None},
           "torque_rms": float(ep["u"].pow(2).mean().sqrt()), "torque_max": float(ep["u"].abs().max()),
           "final_error_rad_median": float(err[:, -1].median()), "closed_loop_seconds": seconds,
           "plant": plant.name, "design": "plant" if design is None else design_plant.name, "controller": kind}
    if limit is not None:  # how often the controller asked beyond the limit, and whether the goal needs more
        bound = torch.as_tensor(limit, dtype=torch.float64)  # (one per input: closed_loop checked it)
        # (the control periods in which some input is at its limit)
        out["torque_at_limit_share"] = float((ep["u"].abs() >= bound * (1 - 1e-9)).any(-1).double().mean())
        rest = torch.zeros_like(goal1)
        with torch.no_grad():
            needed = plant.inverse(goal1, rest, rest, None if p_plant is None else p_plant[:1])[0].abs()
        beyond = needed > bound
        if beyond.any():
            k = int((needed / bound).argmax())
            out["goal_beyond_limit"] = {"input": plant.input_names[k] if plant.input_names else str(k),
                                        "holding_torque": float(needed[k]), "limit": float(bound[k])}
    if scale is not None:
        out["torque_scale_calibrated"] = [float(x) for x in scale.reshape(-1)]
    if design is not None:
        out["holding_torque_at_goal"] = _holding_torques(plant, p_plant, design_plant, p_design, goal1)
    if p_design is None and design is not None and params is not None and params.abs().sum() > 0:
        out["unknown_to_the_model"] = {"params": params[0].tolist(), "names": list(_param_names(truth))}
    if kind in PATHS:
        ref = controller.track.ref
        q_ref = torch.stack([ref(k * dt)[0] for k in range(ep["q"].shape[1])], 1)
        swing = int(round(float(ctrl.get("seconds", 2.0)) / dt))
        out["tracking_error_rms_rad"] = float(wrap(ep["q"][:, :swing] - q_ref[:, :swing], plant.angle_mask)
                                              .pow(2).mean().sqrt())
    out["_episodes"], out["_truth"], out["_params"] = ep, truth, params
    return out


def _holding_torques(plant, p_plant, design_plant, p_design, goal) -> dict:
    """The inputs that hold the goal at rest on the plant and on the model the controller is designed on
    (N m; least squares, ``Plant.inverse``), and their largest difference: a model's error where the
    controller's feedback has to make up for it."""
    rest = torch.zeros_like(goal)
    with torch.no_grad():
        u_plant = plant.inverse(goal, rest, rest, None if p_plant is None else p_plant[:1])[0]
        u_model = design_plant.inverse(goal, rest, rest, None if p_design is None else p_design[:1])[0]
    diff = (u_model - u_plant).abs()
    k = int(diff.argmax())
    return {"plant": u_plant.tolist(), "model": u_model.tolist(), "largest_difference": float(diff[k]),
            "input": plant.input_names[k] if plant.input_names else str(k)}


def _param_names(truth) -> tuple[str, ...]:
    """The names of a plant's parameters (a scene's; an arm's payload)."""
    return tuple(getattr(truth, "param_names", ("payload_mass", "payload_x", "payload_y", "payload_z")))


def _figures(result: dict, out: Path, goal, animate: bool) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ep = result["_episodes"]
    t, q, u = ep["t"], ep["q"][0], ep["u"][0]
    fig, axes = plt.subplots(2, 1, figsize=(7, 4.8), sharex=True)
    for i in range(q.shape[1]):
        line = axes[0].plot(t, q[:, i], label=f"q{i + 1}")[0]
        axes[0].axhline(float(goal[i]), color=line.get_color(), ls=":", lw=0.8)
    axes[0].set_ylabel("angle [rad]")
    axes[0].legend(loc="upper left", fontsize=8)
    for i in range(u.shape[1]):
        axes[1].step(t[:-1], u[:, i], where="post", label=f"tau{i + 1}")
    axes[1].set_ylabel("torque [N m]")
    axes[1].set_xlabel("t [s]")
    axes[1].legend(loc="upper left", fontsize=8)
    fig.suptitle(f"{result['controller']} designed on {result['design']}, run on {result['plant']}: episode 1",
                 fontsize=10)
    fig.tight_layout()
    paths = [out / "episode.png"]
    fig.savefig(paths[0], dpi=110)
    plt.close(fig)
    if animate:
        xy = _positions(result, q)
        if xy is not None:
            paths.append(_animation(xy, float(t[1] - t[0]), out / "episode.gif", result))
    return paths


def _positions(result, q):
    """Joint and tip positions ``(T, links, 2)`` of an arm plant (None where it is not drawn)."""
    truth, params = result["_truth"], result["_params"]
    if hasattr(truth, "positions"):
        p = None if params is None else params.expand(q.shape[0], -1)
        return truth.positions(q, p)
    return None


def _animation(xy, dt: float, path: Path, result: dict) -> Path:
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation, PillowWriter

    stride = max(1, int(round(1 / (25 * dt))))  # 25 frames per second
    frames = xy[::stride]
    reach = 1.1 * float(xy.abs().max())
    fig, ax = plt.subplots(figsize=(3.6, 3.6))
    ax.set_xlim(-reach, reach), ax.set_ylim(-reach, reach), ax.set_aspect("equal")
    ax.set_xticks([]), ax.set_yticks([])
    line, = ax.plot([], [], "k-o", ms=4)
    label = ax.set_title("", fontsize=9)

    def draw(k):
        chain = torch.cat([torch.zeros(1, 2, dtype=frames.dtype), frames[k]])
        line.set_data(chain[:, 0], chain[:, 1])
        label.set_text(f"{result['controller']} on {result['plant']}, t = {k * stride * dt:.2f} s")
        return line, label

    FuncAnimation(fig, draw, frames=len(frames), blit=False).save(path, writer=PillowWriter(fps=25))
    plt.close(fig)
    return path


def main(argv: list[str]) -> int:
    from ..perf import configure_cpu, quiet_compile_logs
    from ..training.checkpoints import load_model
    from .config_files import read_config

    args = _parser().parse_args(argv)
    configure_cpu(args.threads)
    quiet_compile_logs()
    scenario = read_config(args.config, "scenario")
    design = None if args.checkpoint == "plant" else load_model(args.checkpoint)
    result = run_scenario(scenario, design, str(args.config), args.episodes)
    out = Path(args.output_dir or Path("control") / Path(args.config).stem)
    out.mkdir(parents=True, exist_ok=True)
    clean = {k: v for k, v in result.items() if not k.startswith("_")}
    clean.update({"checkpoint": args.checkpoint, "scenario": str(args.config)})
    (out / "control.json").write_text(json.dumps(clean, indent=2) + "\n")
    goal = scenario["controller"].get("goal", [math.pi] + [0.0] * (result["_episodes"]["q"].shape[-1] - 1))
    figures = _figures(result, out, goal, not args.no_animation)
    ttg = clean["time_to_goal_s"]
    lines = [f"# {clean['controller']} designed on {clean['design']}, run on {clean['plant']}", "",
             f"`lnn-torch control {args.checkpoint} -c {args.config}`: {clean['episodes']} episodes.", "",
             "| metric | value |", "|---|---|",
             f"| success (within tolerance of the goal at the end) | {100 * clean['success_rate']:.1f} % |",
             "| time to the goal, s: median [q25, q75] of the successes | "
             + ("-" if ttg["median"] is None else f"{ttg['median']:.2f} [{ttg['q25']:.2f}, {ttg['q75']:.2f}]") + " |",
             f"| torque RMS / max, N m | {clean['torque_rms']:.3g} / {clean['torque_max']:.3g} |",
             f"| final angle error, median, rad | {clean['final_error_rad_median']:.2g} |"]
    if "tracking_error_rms_rad" in clean:
        lines.append(f"| tracking error along the {PATHS[clean['controller']]} path, RMS, rad | "
                     f"{clean['tracking_error_rms_rad']:.3g} |")
    if "torque_at_limit_share" in clean:
        lines.append(f"| control periods with a torque at its limit | {100 * clean['torque_at_limit_share']:.1f} % |")
    if "holding_torque_at_goal" in clean:
        hold = clean["holding_torque_at_goal"]
        lines.append(f"| holding torque at the goal, model against plant: largest difference, N m | "
                     f"{hold['largest_difference']:.3g} ({hold['input']}) |")
    lines += ["", f"Closed loop: {clean['closed_loop_seconds']:.1f} s of computation."]
    if "goal_beyond_limit" in clean:
        b = clean["goal_beyond_limit"]
        lines += ["", f"The goal cannot be held within the limits: at rest there the plant needs "
                      f"{b['holding_torque']:.3g} N m on {b['input']}, its limit is {b['limit']:.3g} N m."]
    if "unknown_to_the_model" in clean:
        unknown = clean["unknown_to_the_model"]
        values = ", ".join(f"{n} = {v:g}" for n, v in zip(unknown["names"], unknown["params"], strict=True))
        lines += ["", f"The plant's parameters ({values}) are unknown to the model: it conditions on no "
                      "parameters (learned from recordings without them), so the feedback makes up for them."]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print("wrote " + ", ".join(str(p) for p in [out / "control.json", out / "report.md", *figures]))
    return 0
