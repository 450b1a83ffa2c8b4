"""Forward and inverse dynamics of the 7-joint Franka Panda per state: every model variant against MuJoCo.

One process, one CPU thread (``torch.set_num_threads(1)``), batches 1 and 4096, under ``torch.no_grad()``.
Each cell is the median over ``--repeats`` runs of the time of one call divided by the batch (a run
being as many calls in a row as take about 20 ms), after warm-up calls.

The engine is MuJoCo (``lnn_torch.robots.mujoco_arm.MujocoArm("franka_panda")``), which has no batched
call for these: it loops over the states. Four engine rows:

* ``MujocoArm`` wrapper: ``.forward(q, qd, tau, payload)`` / ``.inverse(q, qd, qdd, payload)`` as a user
  calls them (tensors in and out, inputs checked, ``set_payload`` per state);
* raw loop, ``set_payload`` per state: ``mj_forward`` / ``mj_inverse`` over preloaded numpy states, each
  state's payload through ``MujocoArm.set_payload``;
* raw loop, payload written per state: the same with the payload (a point mass) written straight into
  the model's ``body_mass`` and ``body_ipos`` -- the engine's cost for this problem (every state its own
  payload) with the least Python around it, and the reference of the ``x engine`` columns;
* raw loop, one payload: the first state's for all the states, set once before the timed calls (a
  lower bound: the models' states all have their own payload).

The raw loops copy each state in and its result out (into preallocated arrays); they equal the
wrapper's results (checked, and reported).

The models are ``lnn_torch.networks.build_model(variant, ARM, **options)`` on the robot-arm scene of
``tests/test_spatial_part.py`` (payload mass and centre of mass as the four scene parameters, identity
input matrix, joint friction), untrained (the time of a call does not depend on the weights), their
normalisers unfitted, float32 (their default) and the grey box also in float64 (built at float64 default
dtype). Forward dynamics is ``model.acceleration(q, qd, params, tau)``, inverse dynamics
``model.inverse(q, qd, qdd, params)`` (the structured variants; n/a for the others), both as a
user calls them (inputs checked). The grey boxes' friction is set to the description's viscous damping
(Coulomb ~0), as in the tests, so they compute the engine's dynamics: their inverse dynamics is checked
against the engine's. The grey box's inverse dynamics is also timed unchecked (eagerly, and through
``torch.compile`` where ``--no-compile`` is not given and compilation finishes within
``--compile-budget`` seconds a batch size).

States: q uniform within the joint ranges (``MujocoArm.sample_q``), qd, qdd, tau standard normal,
payload mass uniform 0-3 kg, centre of mass x, y uniform in +-0.05 m and z in 0-0.1 m (flange frame).

    python benchmarks/benchmark_arm_dynamics.py         # results/robot_arm/speed.md and speed.json (~4 min)
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import shlex
import signal
import sys
import time
import warnings
from contextlib import contextmanager
from pathlib import Path

# compile in this process: a pool of compile workers would compete for the cores (before torch is imported)
os.environ.setdefault("TORCHINDUCTOR_COMPILE_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402
from timing import (  # noqa: E402
    ROOT,
    CpuShare,
    HelpFormatter,
    add_output_dir,
    calls_per_run,
    in_turn,
    machine,
    machine_header,
    median_ratio,
    run_seconds,
    wrote,
)

from lnn_torch.evaluation import table_row  # noqa: E402
from lnn_torch.networks import INVERSE_DYNAMICS, SceneInfo, build_model, capabilities_of  # noqa: E402
from lnn_torch.perf import compile_fn, configure_cpu  # noqa: E402
from lnn_torch.robots import MujocoArm  # noqa: E402

BATCHES = (1, 4096)

# the scene of tests/test_spatial_part.py
ARM = SceneInfo.of({"name": "robot_arm", "dof": 7, "angle_mask": [True] * 7,
                    "param_names": ["payload_mass", "payload_x", "payload_y", "payload_z"],
                    "param_kinds": ["nonnegative", "real", "real", "real"], "input_matrix": np.eye(7).tolist(),
                    "friction": "joint", "joint_map": np.eye(7).tolist(), "config": {"description": "franka_panda"}})

GREY = {"kinetic": {"spatial": {}}, "potential": {"spatial": {}}, "eps": 0.0}
# label, variant, options, dtype, the description's friction (a grey box: the engine's dynamics)
MODELS = [
    ("grey box (spatial parts)", "film_lnn", GREY, torch.float32, True),
    ("grey box (spatial parts)", "film_lnn", GREY, torch.float64, True),
    ("grey box + MLP residuals 64x64", "film_lnn", {"kinetic": {"spatial": {}, "mlp": {}},
                                                    "potential": {"spatial": {}, "mlp": {}},
                                                    "hidden_dims": (64, 64)}, torch.float32, False),
    ("film_lnn 64x64, FiLM 32", "film_lnn", {"hidden_dims": (64, 64), "film_hidden": 32}, torch.float32, False),
    ("delan 128x128", "delan", {"hidden_dims": (128, 128)}, torch.float32, False),
    ("lnn (black box) 128x128", "lnn", {}, torch.float32, False),
    ("mlp (direct) 128x128", "mlp", {}, torch.float32, False),
]
ENGINE_REFERENCE = "MuJoCo raw loop, payload written per state"


@contextmanager
def default_dtype(dtype):
    old = torch.get_default_dtype()
    torch.set_default_dtype(dtype)
    try:
        yield
    finally:
        torch.set_default_dtype(old)


def sample_states(arm: MujocoArm, n: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    q = arm.sample_q(rng, n)
    qd, qdd, tau = (rng.normal(size=(n, arm.dof)) for _ in range(3))
    payload = np.c_[rng.uniform(0, 3, n), rng.uniform(-0.05, 0.05, (n, 2)), rng.uniform(0, 0.1, n)]
    return {"q": q, "qd": qd, "qdd": qdd, "tau": tau, "payload": payload}


def per_state_us(fn, batch: int, repeats: int) -> float:
    """Median over ``repeats`` runs of one call's time divided by ``batch``, in us; a run is as many
    calls in a row as take about 20 ms (at least one), after warm-up calls (two runs' worth)."""
    gc.collect()
    calls = calls_per_run(fn, 0.02)
    return 1e6 * run_seconds(fn, calls, repeats, warmup_calls=2 * calls) / batch


# ---------------------------------------------------------------------------- the engine
class RawEngine:
    """``mj_forward`` / ``mj_inverse`` over preloaded states; ``payload``: "set_payload" (per state, through
    ``MujocoArm.set_payload``), "direct" (per state, the point mass written into the model's arrays) or
    "once" (the first state's for all, set here: before the timed calls)."""

    def __init__(self, arm: MujocoArm, states: dict, batch: int, payload: str) -> None:
        import mujoco

        self.mujoco, self.arm, self.mode = mujoco, arm, payload
        self.s = {k: np.ascontiguousarray(v[:batch]) for k, v in states.items()}
        self.out = np.zeros((batch, arm.dof))
        if payload == "once":
            arm.set_payload(self.s["payload"][0])

    def _payloads(self):
        return None if self.mode == "once" else self.s["payload"]

    # forward and inverse are written out in full, alike (no helper called per state): the engine is
    # timed with the least Python around it
    def forward(self) -> np.ndarray:
        mj, m, d, i = self.mujoco, self.arm.model, self.arm.data, self.arm.payload_id
        q, qd, tau, out = self.s["q"], self.s["qd"], self.s["tau"], self.out
        payload, set_payload = self._payloads(), self.arm.set_payload
        direct = self.mode == "direct"
        d.qacc[:] = 0.0
        for k in range(len(q)):
            if payload is not None:
                if direct:
                    m.body_mass[i] = payload[k, 0]
                    m.body_ipos[i] = payload[k, 1:4]
                else:
                    set_payload(payload[k])
            d.qpos[:] = q[k]
            d.qvel[:] = qd[k]
            d.qfrc_applied[:] = tau[k]
            mj.mj_forward(m, d)
            out[k] = d.qacc_smooth
        return out

    def inverse(self) -> np.ndarray:
        mj, m, d, i = self.mujoco, self.arm.model, self.arm.data, self.arm.payload_id
        q, qd, qdd, out = self.s["q"], self.s["qd"], self.s["qdd"], self.out
        payload, set_payload = self._payloads(), self.arm.set_payload
        direct = self.mode == "direct"
        d.qfrc_applied[:] = 0.0
        for k in range(len(q)):
            if payload is not None:
                if direct:
                    m.body_mass[i] = payload[k, 0]
                    m.body_ipos[i] = payload[k, 1:4]
                else:
                    set_payload(payload[k])
            d.qpos[:] = q[k]
            d.qvel[:] = qd[k]
            d.qacc[:] = qdd[k]
            mj.mj_inverse(m, d)
            out[k] = d.qfrc_inverse
        return out


def engine_rows(arm: MujocoArm, states: dict, repeats: int, batches) -> tuple[list[dict], dict]:
    """The engine's rows, and the largest difference of each raw loop's results from the wrapper's."""
    t = {k: torch.from_numpy(v) for k, v in states.items()}
    n = max(batches)
    wrapper_fwd = arm.forward(t["q"], t["qd"], t["tau"], t["payload"]).numpy()
    wrapper_inv = arm.inverse(t["q"], t["qd"], t["qdd"], t["payload"]).numpy()
    differences = {}
    for mode in ("set_payload", "direct"):
        engine = RawEngine(arm, states, n, mode)
        differences[mode] = {"forward": float(np.abs(engine.forward() - wrapper_fwd).max()),
                             "inverse": float(np.abs(engine.inverse() - wrapper_inv).max())}
    rows = []
    for b in batches:
        x = {k: v[:b] for k, v in t.items()}
        rows.append({"name": "MuJoCo via MujocoArm (tensors in/out, set_payload per state)", "engine": True,
                     "dtype": "float64", "batch": b,
                     "forward_us": per_state_us(lambda x=x: arm.forward(x["q"], x["qd"], x["tau"], x["payload"]), b,
                                                repeats),
                     "inverse_us": per_state_us(lambda x=x: arm.inverse(x["q"], x["qd"], x["qdd"], x["payload"]), b,
                                                repeats)})
        for mode, name in (("set_payload", "MuJoCo raw loop, set_payload per state"), ("direct", ENGINE_REFERENCE),
                           ("once", "MuJoCo raw loop, one payload for all states")):
            engine = RawEngine(arm, states, b, mode)
            rows.append({"name": name, "engine": True, "dtype": "float64", "batch": b,
                         "forward_us": per_state_us(engine.forward, b, repeats),
                         "inverse_us": per_state_us(engine.inverse, b, repeats)})
        print(f"engine, batch {b}: " + ", ".join(f"{r['name']}: {r['forward_us']:.2f} / {r['inverse_us']:.2f} us"
                                                 for r in rows if r["batch"] == b), file=sys.stderr, flush=True)
    return rows, differences


# ---------------------------------------------------------------------------- the models
def with_description_friction(model, arm: MujocoArm) -> None:
    """Friction = the description's viscous damping, Coulomb ~0 (as tests/test_spatial_part.py)."""
    forces = model.forces
    with torch.no_grad():
        b = arm.damping.to(forces.units.dtype) / forces.units[0]
        bias = torch.cat([b + torch.log(-torch.expm1(-b)), torch.full((arm.dof,), -60.0, dtype=b.dtype)])
        forces.coefficient_net[-1].bias.copy_(bias)


def build(variant: str, options: dict, dtype, friction: bool, arm: MujocoArm):
    torch.manual_seed(0)
    with default_dtype(dtype):  # float64: the spatial parts' raw parameters exactly the description's
        model = build_model(variant, ARM, **options).to(dtype)
    if friction:
        with_description_friction(model, arm)
    return model.eval()


def unchecked_inverse(model):
    """``model.inverse_dynamics`` without the input checks (what ``torch.compile`` gets)."""
    def inverse(q, qd, qdd, params):
        q_n, qd_n, p_n = model.normalize(q, qd, params)
        qdd_n = model.normalizer.accel_to_norm(qdd)
        return model.forces.solve_inputs(model.inverse_dynamics_norm(q_n, qd_n, qdd_n, p_n))

    return inverse


class CompileTimeout(Exception):
    pass


def compiled_rows(model, x_by_batch: dict, repeats: int, budget: float) -> tuple[list[dict], dict]:
    """The grey box's unchecked inverse dynamics, eager and through ``torch.compile`` (``perf.compile_fn``:
    default mode, static shapes, C++ wrapper), per batch; compilation cut off after ``budget`` seconds."""
    eager = unchecked_inverse(model)
    compiled = compile_fn(eager)
    rows, info = [], {"seconds": {}, "failed": None}

    def alarm(*_):
        raise CompileTimeout(f"compilation took longer than {budget:.0f} s")

    for b, x in x_by_batch.items():
        rows.append({"name": "grey box (spatial parts), inverse unchecked, eager", "dtype": "float32", "batch": b,
                     "forward_us": None, "inverse_us": per_state_us(lambda x=x: eager(*x), b, repeats)})
        if budget <= 0 or info["failed"]:
            continue
        old = signal.signal(signal.SIGALRM, alarm)
        signal.setitimer(signal.ITIMER_REAL, budget)
        start = time.perf_counter()
        try:
            out = compiled(*x)
        except Exception as err:  # noqa: BLE001 - any failure of the compiler: the row is skipped, saying why
            info["failed"] = f"{type(err).__name__}: {str(err).splitlines()[0][:200] if str(err) else ''}"
            continue
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, old)
        info["seconds"][b] = time.perf_counter() - start
        info[f"max_abs_difference_from_eager_batch_{b}"] = float((out - eager(*x)).abs().max())
        rows.append({"name": "grey box (spatial parts), inverse unchecked, torch.compile", "dtype": "float32",
                     "batch": b, "forward_us": None, "inverse_us": per_state_us(lambda x=x: compiled(*x), b, repeats)})
        print(f"torch.compile, batch {b}: compiled in {info['seconds'][b]:.0f} s, "
              f"{rows[-1]['inverse_us']:.2f} us/state", file=sys.stderr, flush=True)
    return rows, info


def rel(a: torch.Tensor, b: torch.Tensor) -> float:
    """``max |a - b| / max |b|`` (as tests/test_spatial_part.py)."""
    a, b = a.detach().double(), b.detach().double()
    return float((a - b).abs().max() / b.abs().max())


def correctness(arm: MujocoArm, states: dict, n: int = 256) -> dict:
    """The grey box at float64 default dtype (eps = 0) against the engine: its mass matrix
    (``mass_matrix_norm``, unfitted normaliser: SI) and, with the description's friction, its inverse and
    forward dynamics, on ``n`` states with their payloads."""
    t = {k: torch.from_numpy(v[:n]) for k, v in states.items()}
    model = build("film_lnn", GREY, torch.float64, True, arm)
    with torch.no_grad():
        M = model.mass_matrix_norm(t["q"], model.normalizer.params(t["payload"]))
        return {"states": n,
                "mass_matrix": rel(M, arm.mass_matrix(t["q"], t["payload"])),
                "inverse": rel(model.inverse(t["q"], t["qd"], t["qdd"], t["payload"]),
                               arm.inverse(t["q"], t["qd"], t["qdd"], t["payload"])),
                "forward": rel(model.acceleration(t["q"], t["qd"], t["payload"], t["tau"]),
                               arm.forward(t["q"], t["qd"], t["tau"], t["payload"]))}


def model_rows(arm: MujocoArm, states: dict, repeats: int, batches, compile_budget: float):
    rows, accuracy, compile_info = [], {}, None
    n = max(batches)
    engine_inverse = arm.inverse(*(torch.from_numpy(states[k][:n]) for k in ("q", "qd", "qdd", "payload")))
    for label, variant, options, dtype, friction in MODELS:
        model = build(variant, options, dtype, friction, arm)
        x = {k: torch.from_numpy(v).to(dtype) for k, v in states.items()}
        has_inverse = INVERSE_DYNAMICS in capabilities_of(model)
        for b in batches:
            q, qd, qdd, tau, payload = (x[k][:b] for k in ("q", "qd", "qdd", "tau", "payload"))
            forward = per_state_us(lambda m=model, q=q, qd=qd, p=payload, tau=tau: m.acceleration(q, qd, p, tau), b,
                                   repeats)
            inverse = None
            if has_inverse:
                inverse = per_state_us(lambda m=model, q=q, qd=qd, qdd=qdd, p=payload: m.inverse(
                    q, qd, qdd, p), b, repeats)
            rows.append({"name": label, "variant": variant, "dtype": str(dtype)[6:], "batch": b,
                         "parameters": sum(p.numel() for p in model.parameters()),
                         "forward_us": forward, "inverse_us": inverse})
            print(f"{label} {str(dtype)[6:]}, batch {b}: forward {forward:.2f} us/state, inverse "
                  + ("n/a" if inverse is None else f"{inverse:.2f} us/state"), file=sys.stderr, flush=True)
        if friction:  # a grey box: the engine's inverse dynamics in this dtype
            tau = model.inverse(*(x[k][:n] for k in ("q", "qd", "qdd", "payload")))
            accuracy[str(dtype)[6:]] = rel(tau, engine_inverse)
        if friction and dtype == torch.float32 and compile_budget is not None:
            xb = {b: tuple(x[k][:b] for k in ("q", "qd", "qdd", "payload")) for b in batches}
            extra, compile_info = compiled_rows(model, xb, repeats, compile_budget)
            rows += extra
    return rows, accuracy, compile_info


def grey_box_in_turn(arm: MujocoArm, states: dict, batch: int, repeats: int, rounds: int = 5) -> dict:
    """The grey box's (float32) inverse dynamics and the reference engine loop timed in turn, ``rounds``
    times: the median of the per-round ratios is robust to a load on the machine that changes between
    the rows of the tables."""
    model = build("film_lnn", GREY, torch.float32, True, arm)
    x = [torch.from_numpy(states[k][:batch]).float() for k in ("q", "qd", "qdd", "payload")]
    engine = RawEngine(arm, states, batch, "direct")
    us = in_turn({"grey box": lambda: model.inverse(*x), "engine": engine.inverse}, rounds,
                 lambda fn: per_state_us(fn, batch, repeats))
    return {"rounds": rounds, "repeats": repeats, "grey_box_us": us["grey box"], "engine_us": us["engine"],
            "ratio": median_ratio(us["grey box"], us["engine"])}


# ---------------------------------------------------------------------------- the report
def cell(x) -> str:
    if x is None:
        return "n/a"
    return f"{x:.2f}" if x < 100 else f"{x:.0f}"


def ratio(x, ref) -> str:
    if x is None:
        return "n/a"
    return f"{x / ref:.2f}" if x / ref < 10 else f"{x / ref:.0f}"


def report(result: dict) -> str:
    m, rows = result["machine"], result["rows"]
    lines = ["# Franka Panda arm: forward and inverse dynamics per state, models against MuJoCo", "",
             f"One CPU thread: {machine_header(m)} at the end (at the start "
             f"{', '.join(map(str, result['load_average_at_start'] or []))}). All in one process: "
             f"{result['cpu_seconds']:.0f} s of CPU time in "
             f"{result['seconds']:.0f} s (a share of {result['cpu_seconds'] / result['seconds']:.2f} of a core; 1: a "
             "core to itself, less: other processes took turns on it and the times are that much noisier).", "",
             f"Microseconds per state: the median over {result['repeats']} runs of one call's time divided by the "
             "batch (a run: as many calls in a row as take ~20 ms), after warm-up, under `torch.no_grad()`. "
             f"`x engine`: the row's time over that of the {ENGINE_REFERENCE.replace('MuJoCo ', '')} "
             "(MuJoCo with the least Python around it, every state its own payload, as the models get).", "",
             "Models untrained (the time of a call does not depend on the weights), normalisers unfitted; "
             "forward = `model.acceleration(q, qd, params, tau)`, inverse = `model.inverse(q, qd, qdd, "
             "params)`, both as a user calls them (inputs checked); n/a: the variant has no inverse dynamics."]
    for b in result["batches"]:
        ref = next(r for r in rows if r["batch"] == b and r["name"] == ENGINE_REFERENCE)
        lines += ["", f"## Batch {b}", "",
                  table_row(["model", "dtype", "forward µs/state", "inverse µs/state", "× engine (forward)",
                             "× engine (inverse)"]),
                  table_row(["---", "---", "---:", "---:", "---:", "---:"])]  # the numbers right-aligned
        for r in (r for r in rows if r["batch"] == b):
            name = f"**{r['name']}**" if r["name"] == ENGINE_REFERENCE else r["name"]
            lines.append(table_row([name, r["dtype"], cell(r["forward_us"]), cell(r["inverse_us"]),
                                    ratio(r["forward_us"], ref["forward_us"]),
                                    ratio(r["inverse_us"], ref["inverse_us"])]))
    c, acc, raw = result["correctness"], result["accuracy"], result["raw_loop_differences"]
    lines += ["", "## Correctness", "",
              f"Grey box at float64 default dtype, eps = 0, against MuJoCo on {c['states']} states with their payloads "
              "(max |a - b| / max |b|): mass matrix (`model.mass_matrix_norm` vs `MujocoArm.mass_matrix`) "
              f"{c['mass_matrix']:.1e}; with the description's damping as its friction, inverse dynamics "
              f"{c['inverse']:.1e}, forward dynamics {c['forward']:.1e}. The timed grey boxes' inverse dynamics vs "
              f"the engine's at batch {max(result['batches'])}: "
              + ", ".join(f"{d} {v:.1e}" for d, v in acc.items()) + ". The raw loops equal the wrapper's results "
              "(largest absolute difference: "
              + "; ".join(f"{mode} forward {d['forward']:.0e}, inverse {d['inverse']:.0e}" for mode, d in raw.items())
              + ")."]
    info = result["compile"]
    if info is None:
        lines += ["", "torch.compile: not run (--no-compile)."]
    elif info["failed"]:
        lines += ["", f"torch.compile of the grey box's inverse dynamics: skipped ({info['failed']})."]
    else:
        lines += ["", "torch.compile (`lnn_torch.perf.compile_fn`: default mode, static shapes, C++ wrapper) of the "
                  "grey box's inverse dynamics without the input checks, compilation per batch size: "
                  + ", ".join(f"batch {b} {s:.0f} s" for b, s in info["seconds"].items())
                  + " (less where inductor's on-disk cache already holds the kernels)."]
    t = result["target"]
    lines += ["", "## Target", "",
              f"The grey box's batched inverse dynamics (float32) within 10x of the engine per state at batch "
              f"{t['batch']} on one thread: **{t['verdict']}** — {t['grey_box_us']:.2f} µs/state "
              f"against {t['engine_us']:.2f} µs/state ({t['ratio']:.1f}x; against the MujocoArm wrapper "
              f"{t['ratio_wrapper']:.1f}x, against the raw loop with one payload for all states "
              f"{t['ratio_once']:.1f}x)."
              + f" Timed in turn with the engine ({t['in_turn']['rounds']} rounds, the median of the per-round "
              f"ratios, robust to a changing load): {t['in_turn']['ratio']:.1f}x."
              + (f" Through torch.compile: {t['compiled_us']:.2f} µs/state ({t['compiled_ratio']:.1f}x)."
                 if t.get("compiled_us") else ""),
              "", "Command:", "", f"    {result['command']}", ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--repeats", type=int, default=7, help="timed runs per cell (the median is reported)")
    ap.add_argument("--compile-budget", type=float, default=240.0,
                    help="seconds allowed to compile the grey box's inverse dynamics per batch size")
    ap.add_argument("--no-compile", action="store_true", help="skip the torch.compile row")
    add_output_dir(ap, ROOT / "results" / "robot_arm", "folder of speed.md and speed.json")
    args = ap.parse_args()
    warnings.filterwarnings("ignore", message=r".*torch\.jit\.script.*")  # the black box's (torch 2.13)
    configure_cpu(1)
    torch.set_num_threads(1)
    arm = MujocoArm("franka_panda")
    states = sample_states(arm, max(BATCHES))
    load_at_start, share = machine()["load_average"], CpuShare()
    with share:
        correct = correctness(arm, states)
        print(f"correctness: {correct}", file=sys.stderr, flush=True)
        with torch.no_grad():
            engine, differences = engine_rows(arm, states, args.repeats, BATCHES)
            models, accuracy, compile_info = model_rows(arm, states, args.repeats, BATCHES,
                                                        None if args.no_compile else args.compile_budget)
            turn = grey_box_in_turn(arm, states, max(BATCHES), max(3, args.repeats // 2))
    rows = sorted(engine + models, key=lambda r: r["batch"])  # stable: engine rows first per batch
    b = max(BATCHES)
    pick = lambda name: next(r for r in rows if r["batch"] == b and r["name"] == name)  # noqa: E731
    grey = next(r for r in rows
                if r["batch"] == b and r["name"] == "grey box (spatial parts)" and r["dtype"] == "float32")
    ref = pick(ENGINE_REFERENCE)["inverse_us"]
    target = {"batch": b, "grey_box_us": grey["inverse_us"], "engine_us": ref, "ratio": grey["inverse_us"] / ref,
              "ratio_wrapper": grey["inverse_us"]
              / pick("MuJoCo via MujocoArm (tensors in/out, set_payload per state)")["inverse_us"],
              "ratio_once": grey["inverse_us"] / pick("MuJoCo raw loop, one payload for all states")["inverse_us"]}
    target["in_turn"] = turn
    within = [target["ratio"] <= 10, turn["ratio"] <= 10]
    target["verdict"] = ("met" if all(within) else "not met" if not any(within)
                         else "borderline (the two timings disagree)")
    compiled = [r for r in rows if r["batch"] == b and r["name"].endswith("torch.compile")]
    if compiled:
        target["compiled_us"] = compiled[0]["inverse_us"]
        target["compiled_ratio"] = compiled[0]["inverse_us"] / ref
    command = "OMP_NUM_THREADS=1 python " + " ".join(shlex.quote(a) for a in ["benchmarks/benchmark_arm_dynamics.py",
                                                                               *sys.argv[1:]])
    result = {"machine": machine(), "load_average_at_start": load_at_start, "command": command,
              "batches": list(BATCHES), "repeats": args.repeats, "seconds": round(share.seconds, 1),
              "cpu_seconds": round(share.cpu_seconds, 1), "engine_reference": ENGINE_REFERENCE,
              "rows": rows, "correctness": correct, "accuracy": accuracy, "raw_loop_differences": differences,
              "compile": compile_info, "target": target}
    text = report(result)
    print(text)
    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "speed.md").write_text(text)
    (out / "speed.json").write_text(json.dumps(result, indent=1) + "\n")
    wrote(out / "speed.md", out / "speed.json")


if __name__ == "__main__":
    main()
