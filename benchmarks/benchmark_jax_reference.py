"""Same-machine speed reference: a JAX re-implementation of the original JAX FiLM-LNN's design.

This is an independent re-implementation, written from the published design description of the JAX
FiLM-LNN that lnn_torch reimplements (no code of it is used), for SPEED COMPARISON ONLY: it is timed
exactly the way ``benchmarks/benchmark_dynamics.py`` times the torch models, on the same states, so that
the two tables can be read side by side. It is not a model to train or to use.

Architecture (36,680 parameters, asserted):

* inputs per sample: angles ``q`` raw -> features ``[sin q1, cos q1, sin q2, cos q2]``; each velocity
  component z-scored separately; params ``(m1, m2, l1, l2)`` z-scored; accelerations z-scored per
  component (the training target);
* FiLM net 4 -> 32 -> 32 -> 4 (softplus) on the normalised params: one SCALAR (gamma, beta) pair for
  each of the 2 hidden layers of the kinetic MLP (per-layer FiLM);
* kinetic MLP 4 -> 128 -> 128 -> 3 (softplus) on the sin/cos features, ``h = gamma_i h + beta_i`` after
  each hidden activation; the 3 outputs fill a lower-triangular 2x2 factor (diagonal through
  softplus), ``M = chol chol^T + 1e-6 I`` and ``T = 1/2 qd_n^T M qd_n`` (``qd_n`` the normalised velocity);
* potential MLP 8 -> 128 -> 128 -> 1 (tanh) on ``[sin/cos features, normalised params]``;
* ``L = T - V``; accelerations by the generic Euler-Lagrange solve per sample, differentiating with
  respect to the raw angles ``q`` and the NORMALISED velocity ``qd_n`` (as the original does):
  ``qdd_n = solve(d2L/dqd_n2, dL/dq - d/dq(dL/dqd_n) qd_n)`` with ``jax.hessian`` / ``jax.jacobian`` /
  ``jax.grad``, ``jax.vmap`` over the batch and ``jax.jit`` over the whole;
* training step (jit): Huber(qdd_pred_n, qdd_true_n; delta 1, mean) + 1.0 x var over the 512-point
  chunk of the model's own ``H = T + V``, its gradient and an Adam update (optax if installed, else
  a hand-written Adam).

Timing conventions of ``benchmark_dynamics.py``: medians after warm-up (jit compilation happens in
a call before the warm-up), one thread, batches 1/512/8192 (1/512 with ``--quick``), float32 and
float64, and the ratio of the B=512 acceleration to the closed-form ``system.acceleration`` of
lnn_torch timed in torch (one thread) in the same run.

One thread for XLA: ``--xla_cpu_multi_thread_eigen=false`` alone does not stop the XLA CPU client
from running on every core (it sizes its intra-op pool from the process's CPU affinity), so the
client is created while the process is pinned to one CPU and the affinity is restored afterwards;
the header reports the process CPU time / wall time measured over the timed JAX calls (1.00 = one
busy thread).

Needs jax next to the project (``pip install jax``; optax is optional, ``pip install optax``)::

    python benchmarks/benchmark_jax_reference.py          # full table
    python benchmarks/benchmark_jax_reference.py --quick  # fewer repeats, no batch 8192
    python benchmarks/benchmark_jax_reference.py --check  # correctness checks only (no timing)
    python benchmarks/benchmark_jax_reference.py --interleaved   # JAX and lnn_torch in turn, same process

``--interleaved`` answers "how fast is lnn_torch against the original here" under the same load:
on a shared machine, timings drift by tens of percent over minutes, so two separate runs can
disagree more than the two codes do. It times, float32, one thread, in round-robin order (per
round, each candidate is called twice and the second call timed, so that the caches hold its data):
512 accelerations and one training step on a 512-point chunk of one trajectory (its points share
one parameter vector) for the JAX reference, lnn_torch's film_lnn eagerly, and film_lnn under
torch.compile; it reports each median and the median per-round ratio to JAX.
"""

from __future__ import annotations

import os

# lnn_torch's torch.compile rows (--interleaved) compile in this process, without a worker pool
os.environ.setdefault("TORCHINDUCTOR_COMPILE_THREADS", "1")
# Before jax is imported: single-threaded Eigen in XLA, float64 available (float32 arrays stay float32).
os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false").strip()
os.environ.setdefault("JAX_PLATFORMS", "cpu")
_ALL_CPUS = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
if _ALL_CPUS:  # the XLA CPU client sizes its thread pool from the affinity at creation: create it on one CPU
    os.sched_setaffinity(0, {min(_ALL_CPUS)})

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.block_until_ready(jnp.zeros(2) + 1)  # creates the CPU client under the one-CPU mask
if _ALL_CPUS:
    os.sched_setaffinity(0, _ALL_CPUS)

import argparse  # noqa: E402
import statistics  # noqa: E402
import warnings  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from timing import CpuShare, HelpFormatter, in_turn, machine_header, median_ratio  # noqa: E402

from lnn_torch.evaluation import markdown_table, table_header, table_row  # noqa: E402
from lnn_torch.networks import build_model  # noqa: E402
from lnn_torch.perf import adamw, compile_fn, configure_cpu, median_seconds  # noqa: E402
from lnn_torch.systems import GRAVITY, get_system  # noqa: E402
from lnn_torch.training import acceleration_loss, energy_variance  # noqa: E402

try:
    import optax
except ImportError:  # optional: a hand-written Adam below does the same update
    optax = None

N_PARAMS = 36_680
EPS = 1e-6  # M = chol chol^T + EPS I
VARIANT = "jax reference (per-layer FiLM, generic solve, jit)"
PATH = "generic (jax.hessian, jit)"


# ---------------------------------------------------------------------------------------------- model
def init_mlp(key, sizes, dtype):
    """Dense layers ``[(W, b), ...]``: W ~ U(+-1/sqrt(fan_in)), b = 0."""
    layers = []
    for fan_in, fan_out in zip(sizes[:-1], sizes[1:], strict=True):
        key, sub = jax.random.split(key)
        bound = 1.0 / np.sqrt(fan_in)
        layers.append((jax.random.uniform(sub, (fan_in, fan_out), dtype, -bound, bound), jnp.zeros(fan_out, dtype)))
    return layers


def init_model(seed: int, dtype):
    k_film, k_kin, k_pot = jax.random.split(jax.random.PRNGKey(seed), 3)
    model = {
        "film": init_mlp(k_film, (4, 32, 32, 4), dtype),  # -> (gamma_1, beta_1, gamma_2, beta_2)
        "kinetic": init_mlp(k_kin, (4, 128, 128, 3), dtype),  # -> 3 Cholesky entries
        "potential": init_mlp(k_pot, (8, 128, 128, 1), dtype),  # -> V
    }
    count = sum(x.size for x in jax.tree_util.tree_leaves(model))
    assert count == N_PARAMS, f"parameter count {count} != {N_PARAMS}"
    return model


def trig_features(q):
    return jnp.stack([jnp.sin(q[0]), jnp.cos(q[0]), jnp.sin(q[1]), jnp.cos(q[1])])


def film(layers, p_n):
    """FiLM net on the normalised params (softplus hidden activation; the design does not name it,
    tanh would cost the same). Returns ``(2, 2)``: row i = (gamma_i, beta_i) of kinetic hidden layer i."""
    h = p_n
    for W, b in layers[:-1]:
        h = jax.nn.softplus(h @ W + b)
    W, b = layers[-1]
    return (h @ W + b).reshape(2, 2)


def mass_matrix(model, q, p_n):
    gb = film(model["film"], p_n)
    h = trig_features(q)
    for i, (W, b) in enumerate(model["kinetic"][:-1]):
        h = jax.nn.softplus(h @ W + b)
        h = gb[i, 0] * h + gb[i, 1]  # per-layer scalar FiLM
    W, b = model["kinetic"][-1]
    c = h @ W + b
    zero = jnp.zeros((), c.dtype)
    chol = jnp.stack([jnp.stack([jax.nn.softplus(c[0]), zero]), jnp.stack([c[1], jax.nn.softplus(c[2])])])
    # The reference notes write M = chol^T chol; chol chol^T is the same positive-definite family at the same cost.
    return chol @ chol.T + EPS * jnp.eye(2, dtype=c.dtype)


def potential(model, q, p_n):
    h = jnp.concatenate([trig_features(q), p_n])
    for W, b in model["potential"][:-1]:
        h = jnp.tanh(h @ W + b)
    W, b = model["potential"][-1]
    return (h @ W + b)[0]


def kinetic_potential(model, q, qd_n, p_n):
    """Per sample: ``(T, V)`` of the normalised Lagrangian, ``q`` (2,) raw, ``qd_n`` (2,), ``p_n`` (4,)."""
    return 0.5 * qd_n @ mass_matrix(model, q, p_n) @ qd_n, potential(model, q, p_n)


def lagrangian(model, q, qd_n, p_n):
    T, V = kinetic_potential(model, q, qd_n, p_n)
    return T - V


def energy(model, q, qd_n, p_n):
    T, V = kinetic_potential(model, q, qd_n, p_n)
    return T + V


# ------------------------------------------------------------------------------------ generic solve
def euler_lagrange(lag, q, qd, p):
    """Generic Euler-Lagrange solve for ONE sample of a scalar ``lag(q, qd, p)``:
    ``qdd = solve(d2L/dqd2, dL/dq - d/dq(dL/dqd) qd)``."""
    hess = jax.hessian(lag, argnums=1)(q, qd, p)
    mixed = jax.jacobian(jax.grad(lag, argnums=1), argnums=0)(q, qd, p)
    force = jax.grad(lag, argnums=0)(q, qd, p)
    return jnp.linalg.solve(hess, force - mixed @ qd)


def model_accel(model, q, qd_n, p_n):
    """Batched normalised accelerations of the model (vmap of the per-sample solve)."""
    return jax.vmap(lambda a, b, c: euler_lagrange(lambda x, y, z: lagrangian(model, x, y, z), a, b, c))(q, qd_n, p_n)


accel_jit = jax.jit(model_accel)


def true_lagrangian(q, qd, p):
    """Double-pendulum Lagrangian in physical units (independent of lnn_torch's formulas)."""
    m1, m2, l1, l2 = p
    t1, t2 = q
    w1, w2 = qd
    T = 0.5 * (m1 + m2) * l1**2 * w1**2 + 0.5 * m2 * l2**2 * w2**2 + m2 * l1 * l2 * w1 * w2 * jnp.cos(t1 - t2)
    V = -(m1 + m2) * GRAVITY * l1 * jnp.cos(t1) - m2 * GRAVITY * l2 * jnp.cos(t2)
    return T - V


# --------------------------------------------------------------------------------------- training
def huber(pred, target, delta: float = 1.0):
    a = jnp.abs(pred - target)
    return jnp.mean(jnp.where(a <= delta, 0.5 * a**2, delta * (a - 0.5 * delta)))


def loss_fn(model, q, qd_n, p_n, target_n):
    """Huber on normalised accelerations + 1.0 x variance over the chunk of the model's H = T + V."""
    pred = model_accel(model, q, qd_n, p_n)
    H = jax.vmap(lambda a, b, c: energy(model, a, b, c))(q, qd_n, p_n)
    return huber(pred, target_n) + 1.0 * jnp.var(H)


def make_adam(lr: float):
    """``(init, update)`` of Adam: optax's if installed, else the same update written out."""
    if optax is not None:
        opt = optax.adam(lr)

        def update(grads, state, params):
            updates, state = opt.update(grads, state, params)
            return optax.apply_updates(params, updates), state

        return opt.init, update
    b1, b2, eps = 0.9, 0.999, 1e-8

    def init(params):
        zeros = jax.tree_util.tree_map(jnp.zeros_like, params)
        return zeros, zeros, jnp.zeros((), jnp.int32)

    def update(grads, state, params):
        m, v, t = state
        t = t + 1
        m = jax.tree_util.tree_map(lambda m_, g: b1 * m_ + (1 - b1) * g, m, grads)
        v = jax.tree_util.tree_map(lambda v_, g: b2 * v_ + (1 - b2) * g * g, v, grads)

        def step(p, m_, v_):
            c1, c2 = 1 - b1 ** t.astype(p.dtype), 1 - b2 ** t.astype(p.dtype)  # bias corrections
            return p - lr * (m_ / c1) / (jnp.sqrt(v_ / c2) + eps)

        params = jax.tree_util.tree_map(step, params, m, v)
        return params, (m, v, t)

    return init, update


def make_train_step(lr: float = 1e-4):
    opt_init, opt_update = make_adam(lr)

    @jax.jit
    def train_step(model, opt_state, q, qd_n, p_n, target_n):
        loss, grads = jax.value_and_grad(loss_fn)(model, q, qd_n, p_n, target_n)
        model, opt_state = opt_update(grads, opt_state, model)
        return model, opt_state, loss

    return opt_init, train_step


# ------------------------------------------------------------------------------------------- data
def sample_data(n: int):
    """The states benchmark_dynamics.py times: the project's sampler with seed 0, float64 numpy."""
    system = get_system("double_pendulum")
    rng = np.random.default_rng(0)
    params = system.sample_params(rng, n)
    q, qd = system.sample_state(rng, n)
    qdd = system.acceleration(torch.tensor(q), torch.tensor(qd), torch.tensor(params)).numpy()
    return system, q, qd, qdd, params


def normalise(q, qd, qdd, params, dtype):
    """z-score velocities, accelerations (per component) and params with statistics of the data; angles raw."""
    z = lambda x: (x - x.mean(0)) / x.std(0)  # noqa: E731
    return tuple(jnp.asarray(x, dtype) for x in (q, z(qd), z(params), z(qdd)))


# ------------------------------------------------------------------------------------------ timing
def jax_median_ms(fn, repeats: int, share: CpuShare, warmup: int = 3) -> float:
    """``fn``'s median time (ms) after one untimed call (jit compiles there, outside the warm-up and the
    CPU-share measurement) and ``warmup`` more; the timed calls' CPU share is added to ``share``."""
    fn()
    with share:
        return 1e3 * median_seconds(fn, repeats, warmup)


def run_benchmark(repeats: int, batches) -> None:
    system, q, qd, qdd, params = sample_data(max(batches))
    share = CpuShare()
    rows = []
    for dtype, tdtype in ((jnp.float32, torch.float32), (jnp.float64, torch.float64)):
        tq, tqd, tp = (torch.tensor(x, dtype=tdtype) for x in (q, qd, params))
        closed = {b: 1e3 * median_seconds(lambda b=b, tq=tq, tqd=tqd, tp=tp: system.acceleration(tq[:b], tqd[:b],
                                                                                                  tp[:b]), repeats, 3)
                  for b in batches}
        name = np.dtype(dtype).name
        rows.append(table_row(["closed form", "analytic", name, *(f"{closed[b]:.3f}" for b in batches), "-", 1]))
        model = init_model(0, dtype)
        qn, qdn, pn, tn = normalise(q, qd, qdd, params, dtype)
        cells = {}
        for b in batches:
            args_b = tuple(jax.block_until_ready(x[:b]) for x in (qn, qdn, pn))  # slices made outside the timing
            cells[b] = jax_median_ms(lambda a=args_b, m=model: accel_jit(m, *a).block_until_ready(), repeats, share)
        opt_init, train_step = make_train_step()
        chunk = tuple(jax.block_until_ready(x[:512]) for x in (qn, qdn, pn, tn))
        state = [model, opt_init(model)]

        def step(state=state, train_step=train_step, chunk=chunk):
            state[0], state[1], loss = train_step(state[0], state[1], *chunk)
            jax.block_until_ready((state[0], loss))

        st = jax_median_ms(step, max(5, repeats // 2), share)
        rows.append(table_row([VARIANT, PATH, name, *(f"{cells[b]:.3f}" for b in batches), f"{st:.2f}",
                               f"{cells[512] / closed[512]:.0f}"]))
    print(f"{machine_header()}; jax {jax.__version__} ({jax.default_backend()}, x64 enabled), XLA_FLAGS="
          f"'{os.environ['XLA_FLAGS']}', XLA client created on 1 CPU, optimizer "
          f"{'optax.adam' if optax else 'hand-written Adam'}, medians of {repeats} after warm-up; "
          f"CPU/wall over the JAX timings {share.share:.2f}")
    print("\n".join(table_header(["variant", "path", "dtype", *(f"accel B={b} (ms)" for b in batches),
                                  "train step, 512-pt chunk (ms)", "accel B=512 / closed form"])))
    for row in rows:
        print(row)


def run_interleaved(rounds: int) -> None:
    """JAX reference, film_lnn eager and film_lnn compiled, float32, timed in turn (see the docstring)."""
    warnings.filterwarnings("ignore", category=FutureWarning, module=r"torch\._inductor")
    B = 512
    system, q, qd, qdd, params = sample_data(B)
    # JAX reference
    model = init_model(0, jnp.float32)
    qn, qdn, pn, tn = normalise(q, qd, qdd, params, jnp.float32)
    jargs = tuple(jax.block_until_ready(x) for x in (qn, qdn, pn))
    # the training chunk: one trajectory's parameter vector on all its points
    jchunk = tuple(jax.block_until_ready(x) for x in (qn, qdn, jnp.broadcast_to(pn[:1], pn.shape), tn))
    opt_init, train_step = make_train_step()
    jstate = [model, opt_init(model)]

    def jax_accel():
        accel_jit(model, *jargs).block_until_ready()

    def jax_step():
        jstate[0], jstate[1], loss = train_step(jstate[0], jstate[1], *jchunk)
        jax.block_until_ready((jstate[0], loss))

    # lnn_torch film_lnn, as in benchmark_dynamics.py
    torch.manual_seed(0)
    tm = build_model("film_lnn", system, hidden_dims=(128, 128))
    tq, tqd, tp = (torch.tensor(x, dtype=torch.float32) for x in (q, qd, params))
    tm.normalizer.fit(tq, tqd, system.acceleration(tq, tqd, tp), tp)
    tqn, tqdn, tpn = tm.normalize(tq, tqd, tp)
    target = tm.normalizer.accel_to_norm(system.acceleration(tq, tqd, tp))
    tpc = tpn[:1].expand(B, -1)
    opt = adamw(tm.parameters(), lr=1e-5)
    fused = lambda a, b, c: tm.acceleration_and_energy_norm(a, b, c, 1)  # noqa: E731
    fused_c = compile_fn(fused)
    accel_c = compile_fn(tm.acceleration_norm)

    def torch_accel(fn):
        def run():
            with torch.no_grad():
                fn(tqn, tqdn, tpn)
        return run

    def torch_step(fn):
        def run():
            opt.zero_grad()
            pred, H, T, V = fn(tqn, tqdn, tpc)
            loss = acceleration_loss(pred, target, tm.normalizer.accel_rms) + 0.1 * energy_variance(
                H.reshape(1, B), T.reshape(1, B), V.reshape(1, B))
            loss.backward()
            opt.step()
        return run

    cands = {
        "accel B=512: jax reference (jit)": jax_accel,
        "accel B=512: film_lnn eager": torch_accel(tm.acceleration_norm),
        "accel B=512: film_lnn torch.compile": torch_accel(accel_c),
        "train step: jax reference (jit)": jax_step,
        "train step: film_lnn eager": torch_step(fused),
        "train step: film_lnn torch.compile": torch_step(fused_c),
    }
    for fn in cands.values():  # compile and warm up
        for _ in range(5):
            fn()
    # per round and candidate one untimed call (the caches then hold this candidate's data, not the previous
    # one's), then one timed call
    times = in_turn(cands, rounds, lambda fn: median_seconds(fn, 1, warmup=1))
    print(f"{machine_header()}; jax {jax.__version__}, one thread each, float32, {rounds} rounds in turn "
          "(per round and "
          "candidate: one untimed call, then one timed call), medians")
    rows = []
    for k, v in times.items():
        ref = times["accel B=512: jax reference (jit)" if k.startswith("accel") else "train step: jax reference (jit)"]
        rows.append([k, f"{1e3 * statistics.median(v):.2f}", f"{median_ratio(v, ref):.2f}"])
    print(markdown_table(["what", "median (ms)", "median per-round ratio to JAX"], rows))


# ------------------------------------------------------------------------------------------ checks
def run_checks() -> None:
    system, q, qd, qdd, params = sample_data(512)
    ok = True

    def report(name: str, value: float, tol: float) -> None:
        nonlocal ok
        passed = bool(np.isfinite(value) and value <= tol)
        ok &= passed
        print(f"{'PASS' if passed else 'FAIL'}  {name}: {value:.3e} (tolerance {tol:.0e})")

    model = init_model(0, jnp.float64)
    print(f"PASS  parameter count: {sum(x.size for x in jax.tree_util.tree_leaves(model))} == {N_PARAMS}")

    qn, qdn, pn, tn = normalise(q, qd, qdd, params, jnp.float64)
    batched = np.asarray(accel_jit(model, qn, qdn, pn))
    loop = np.stack([np.asarray(euler_lagrange(lambda x, y, z: lagrangian(model, x, y, z), qn[i], qdn[i], pn[i]))
                     for i in range(5)])
    report("vmapped jit solve vs per-sample loop (5 samples, float64), max |diff| / max |qdd|",
           np.abs(batched[:5] - loop).max() / np.abs(loop).max(), 1e-10)

    true_fn = jax.jit(jax.vmap(lambda a, b, c: euler_lagrange(true_lagrangian, a, b, c)))
    ours = np.asarray(true_fn(jnp.asarray(q), jnp.asarray(qd), jnp.asarray(params)))
    report("true double-pendulum Lagrangian through the same solve vs lnn_torch system.acceleration "
           "(512 states, float64), max |diff| / max |qdd|", np.abs(ours - qdd).max() / np.abs(qdd).max(), 1e-9)

    d = np.random.default_rng(1).normal(scale=2.0, size=(512, 2))
    ref = torch.nn.functional.huber_loss(torch.tensor(d), torch.zeros(512, 2), delta=1.0).item()
    report("Huber vs torch.nn.functional.huber_loss, |diff|", abs(float(huber(jnp.asarray(d), 0.0)) - ref), 1e-12)

    for dtype in (jnp.float32, jnp.float64):
        m = init_model(0, dtype)
        a = normalise(q, qd, qdd, params, dtype)
        pred = accel_jit(m, *a[:3])
        opt_init, train_step = make_train_step()
        m2, _, loss = train_step(m, opt_init(m), *a)
        good = (pred.dtype == dtype and bool(jnp.isfinite(pred).all()) and bool(jnp.isfinite(loss))
                and all(x.dtype == dtype for x in jax.tree_util.tree_leaves(m2)))
        ok &= good
        print(f"{'PASS' if good else 'FAIL'}  {np.dtype(dtype).name}: accelerations and updated weights keep the "
              f"dtype and are finite (loss {float(loss):.4g})")

    share = CpuShare()
    b512 = tuple(x[:512] for x in (qn, qdn, pn))
    jax_median_ms(lambda: accel_jit(model, *b512).block_until_ready(), 20, share)
    print(f"INFO  process CPU time / wall time over 20 timed B=512 calls: {share.share:.2f} (1.00 = one thread)")
    print("all checks passed" if ok else "SOME CHECKS FAILED")
    if not ok:
        raise SystemExit(1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--repeats", type=int, default=30, help="timed calls per median")
    ap.add_argument("--quick", action="store_true", help="7 repeats, batches 1 and 512 only")
    ap.add_argument("--check", action="store_true", help="run the correctness checks instead of the timings")
    ap.add_argument("--interleaved", type=int, nargs="?", const=300, default=0, metavar="ROUNDS",
                    help="JAX reference and lnn_torch film_lnn timed in turn in this process, ROUNDS rounds (300 "
                         "when ROUNDS is left out; not by default)")
    args = ap.parse_args()
    configure_cpu(1)  # as benchmark_dynamics.py: flush denormals, allocator, one torch thread
    if args.check:
        run_checks()
        return
    if args.interleaved:
        run_interleaved(args.interleaved)
        return
    repeats = 7 if args.quick else args.repeats
    batches = (1, 512) if args.quick else (1, 512, 8192)
    run_benchmark(repeats, batches)


if __name__ == "__main__":
    main()
