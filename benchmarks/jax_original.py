"""Harness around the ORIGINAL JAX FiLM-LNN (matteocorbetta/lagrangian-film-nn), for timing and
accuracy comparisons in one process with lnn_torch (``benchmarks/cost_accuracy_front.py``).

This file is our own code; it contains no code of the original (which has no licence: it may be run,
not copied). It imports the original's modules from the directory named by the environment variable
``LNN_JAX_ORIGINAL_SRC`` (default ``../jax_original/src_checkout/src`` beside the project): the
``src`` folder of a checkout of the repository at 39b6fde, with ``from __future__ import annotations``
prepended to each module so that it imports on Python 3.11, and jax 0.9.1, jaxlib 0.9.1, equinox
0.13.6, optax 0.2.7 installed (its lock file's versions; jax 0.10 removed an argument its data
generator uses). Set-up, outside the project::

    git clone https://github.com/matteocorbetta/lagrangian-film-nn ../jax_original/src_checkout
    cd ../jax_original/src_checkout && git checkout 39b6fde
    for f in $(git ls-files '*.py'); do [ -s $f ] && sed -i '1i from __future__ import annotations' $f; done
    pip install jax==0.9.1 jaxlib==0.9.1 equinox==0.13.6 optax==0.2.7 jaxtyping h5py

It calls the original's own functions:

* ``lnn.LagrangianNN``          (model; its ``__call__`` does the Euler-Lagrange solve)
* ``train_utils.load_model``    (equinox ``tree_deserialise_leaves`` of the released .eqx)
* ``train.train_step``          (its jitted training step: Huber + var(H) loss, AdamW)
* the released normalisation statistics from ``models/<name>.npz`` ('norm_stats')

Usage (caller process, before anything initialises the JAX backend)::

    import sys; sys.path.insert(0, "benchmarks")
    import jax_original as harness                      # sets single-threaded XLA flags if jax not yet initialised
    m = harness.load("float32")          # or "float64"
    qdd = m.accel(q, qd, params)         # numpy (N,2) rad/s^2 from SI q (N,2) rad, qd (N,2) rad/s,
                                         # params (N,4) or (4,) = (m1, m2, l1, l2) in kg, kg, m, m
    step = harness.train_step_fn()       # one original train_step per call
    loss = step(q, qd, qdd, params)      # a 512-point chunk of ONE trajectory, SI units
    harness.param_count()                # 36680

Conventions: absolute angles from the downward vertical, params order
(m1, m2, l1, l2), gravity 9.806 in the original's generator.
"""
from __future__ import annotations

import importlib
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ORIG_SRC = os.path.abspath(os.environ.get("LNN_JAX_ORIGINAL_SRC",
                                          os.path.join(HERE, "..", "..", "jax_original", "src_checkout", "src")))
MODEL_NAME = "model_T512_20260317_133032"
MODEL_BASE = os.path.join(ORIG_SRC, "models", MODEL_NAME)

SINGLE_THREAD_FLAGS = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"


def _set_single_thread_flags() -> None:
    """Ask XLA:CPU for one thread (only effective before the JAX backend is initialised) and hold the
    process to one CPU core (Linux). The flags alone do not hold this jaxlib to one core: a batch-4096
    call of the original used 1.8 cores on an idle 2-core machine (18 ms against 32 ms on one core), so
    a "one thread" comparison pins the whole process, the lnn_torch side included."""
    if os.environ.get("JAX_HARNESS_THREADS", "1") != "1":
        return
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_multi_thread_eigen" not in flags:
        os.environ["XLA_FLAGS"] = (flags + " " + SINGLE_THREAD_FLAGS).strip()
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})


_set_single_thread_flags()

import numpy as np  # noqa: E402

_ORIG = None  # cached namespace of the original's modules


def _import_original():
    """Import the original's modules (top-level names lnn, losses, train, train_utils, data)."""
    global _ORIG
    if _ORIG is not None:
        return _ORIG
    for name in ("lnn", "losses", "train", "train_utils", "data", "simulate"):
        mod = sys.modules.get(name)
        if mod is not None and not os.path.abspath(getattr(mod, "__file__", "") or "").startswith(ORIG_SRC):
            raise ImportError(f"a different top-level module '{name}' is already imported ({mod!r}); "
                              "the original repository needs that name")
    if ORIG_SRC not in sys.path:
        sys.path.insert(0, ORIG_SRC)
    import jax

    x64_before = jax.config.jax_enable_x64
    import equinox as eqx
    import lnn
    import losses
    import optax
    import train
    import train_utils  # NB: imports data.doublependulum, which does config.update('jax_enable_x64', True)

    # the original's package `data`, imported by name: its import statement would sort differently
    # wherever a data/ folder of datasets sits beside this project
    doublependulum = importlib.import_module("data.doublependulum")

    # undo the global side effect of the original's import; each call below chooses its precision
    # with the jax.enable_x64(...) context manager instead
    jax.config.update("jax_enable_x64", x64_before)

    class _NS:
        pass

    ns = _NS()
    ns.jax, ns.eqx, ns.optax = jax, eqx, optax
    ns.lnn, ns.losses, ns.train_utils, ns.train, ns.doublependulum = lnn, losses, train_utils, train, doublependulum
    _ORIG = ns
    return ns


def _norm_stats(dtype) -> dict:
    z = np.load(MODEL_BASE + ".npz", allow_pickle=True)  # 'norm_stats' is a pickled dict
    ns = z["norm_stats"].item()
    return {k: np.asarray(v, dtype=dtype) for k, v in ns.items()}


def _new_model(o, key_seed: int = 123):
    """Architecture exactly as in the original's train.py / inference.py."""
    key = o.jax.random.PRNGKey(key_seed)
    model_key, _train_key = o.jax.random.split(key)
    return o.lnn.LagrangianNN(pos_dim=2, vel_dim=2, param_dim=4, hidden_dim=128, n_hidden=2, key=model_key)


def _cast(o, model, dtype):
    return o.jax.tree_util.tree_map(
        lambda a: o.jax.numpy.asarray(a, dtype=dtype) if o.eqx.is_array(a) else a, model)


def _load_released(o, dtype):
    with o.jax.enable_x64(True):  # the .eqx file stores float64 leaves
        model = _new_model(o)
        import contextlib
        import io
        with contextlib.redirect_stdout(io.StringIO()):  # load_model prints a line
            model = o.train_utils.load_model(model, MODEL_BASE)
    with o.jax.enable_x64(dtype == np.float64):
        return _cast(o, model, dtype)


def _dtype(dtype):
    dt = np.dtype(dtype)
    if dt not in (np.float32, np.float64):
        raise ValueError("dtype must be float32 or float64")
    return dt.type


class OriginalModel:
    """Released original model; SI in, SI out."""

    def __init__(self, dtype="float32"):
        o = _import_original()
        self._o = o
        self.dtype = _dtype(dtype)
        self.x64 = self.dtype == np.float64
        jax, jnp, eqx = o.jax, o.jax.numpy, o.eqx
        self.norm_stats = _norm_stats(self.dtype)
        self.model = _load_released(o, self.dtype)
        dyn, static = eqx.partition(self.model, eqx.is_array)
        self._dyn = dyn
        with jax.enable_x64(self.x64):
            ns = {k: jnp.asarray(v) for k, v in self.norm_stats.items()}

        def _accel(dyn, q, qd, p):
            model = eqx.combine(dyn, static)
            # the original's normalisation (simulate.rk4_step / inference.test_ood):
            # angles raw (X_mean[:2] = 0, X_std[:2] = 1), velocities and parameters z-scored,
            # output de-normalised with dXdt_std / dXdt_mean
            qd_n = (qd - ns["X_mean"][2:4]) / ns["X_std"][2:4]
            p_n = (p - ns["X_mean"][4:]) / ns["X_std"][4:]
            qdd_n = jax.vmap(model)(q, qd_n, p_n)
            return qdd_n * ns["dXdt_std"] + ns["dXdt_mean"]

        self._accel_jit = jax.jit(_accel)

    def to_device(self, *arrays):
        """numpy -> jax arrays in this model's dtype (to time without host conversion)."""
        jnp = self._o.jax.numpy
        with self._o.jax.enable_x64(self.x64):
            return tuple(jnp.asarray(np.asarray(a, dtype=self.dtype)) for a in arrays)

    def accel_device(self, q, qd, params):
        """jax arrays in, jax array out (asynchronous: call .block_until_ready() to time)."""
        with self._o.jax.enable_x64(self.x64):
            return self._accel_jit(self._dyn, q, qd, params)

    def accel_traced(self, q, qd, params):
        """The jitted acceleration on jax arrays in the caller's precision (no ``enable_x64`` context): to
        call inside another jitted function, e.g. an integrator step."""
        return self._accel_jit(self._dyn, q, qd, params)

    def accel(self, q, qd, params) -> np.ndarray:
        """SI numpy in -> SI numpy out. q (N,2) rad, qd (N,2) rad/s, params (N,4) or (4,)
        = (m1, m2, l1, l2); returns (N,2) rad/s^2 in self.dtype. One compilation per distinct N."""
        q = np.asarray(q, dtype=self.dtype)
        qd = np.asarray(qd, dtype=self.dtype)
        p = np.asarray(params, dtype=self.dtype)
        if p.ndim == 1:
            p = np.broadcast_to(p, (q.shape[0], 4))
        with self._o.jax.enable_x64(self.x64):
            out = self._accel_jit(self._dyn, q, qd, np.ascontiguousarray(p))
            return np.asarray(out)


_LOADED = {}


def load(dtype="float32") -> OriginalModel:
    dt = _dtype(dtype)
    if dt not in _LOADED:
        _LOADED[dt] = OriginalModel(dt)
    return _LOADED[dt]


class OriginalTrainStep:
    """Runs the original's own ``train.train_step`` (eqx.filter_jit) on one chunk per call.

    Optimizer exactly as in the original's training_loop: clip_by_global_norm(1.0) then
    adamw(cosine_decay_schedule(3e-3, 50000, alpha=0.01)). The model starts from the
    original's fresh initialisation (PRNGKey(123) split, as train.py) unless init='released'.
    Inputs are normalised with the released norm_stats (norm='released') or with statistics of
    the first chunk seen (norm='first_chunk'); the targets are normalised the same way the
    original normalises dXdt. The original's energy term (variance of H over the batch) assumes
    each chunk is a contiguous piece of ONE trajectory.
    """

    def __init__(self, dtype="float32", init="scratch", norm="released",
                 lr=3e-3, steps=50000):
        o = _import_original()
        self._o = o
        self.dtype = _dtype(dtype)
        self.x64 = self.dtype == np.float64
        jax = o.jax
        if init == "released":
            self.model = _load_released(o, self.dtype)
        elif init == "scratch":
            with jax.enable_x64(self.x64):
                self.model = _cast(o, _new_model(o), self.dtype)
        else:
            raise ValueError("init must be 'scratch' or 'released'")
        self.norm = norm
        self.norm_stats = _norm_stats(self.dtype) if norm == "released" else None
        with jax.enable_x64(self.x64):
            scheduler = o.optax.cosine_decay_schedule(init_value=lr, decay_steps=steps, alpha=0.01)
            # the SAME optimizer object must be passed every call: train_step is eqx.filter_jit
            # and treats it as static (a new object means a recompilation)
            self.optimizer = o.optax.chain(o.optax.clip_by_global_norm(1.0),
                                           o.optax.adamw(learning_rate=scheduler))
            self.opt_state = self.optimizer.init(o.eqx.filter(self.model, o.eqx.is_array))
        self.losses = []

    def normalise(self, q, qd, qdd, params):
        """SI chunk -> (x (N,8), y (N,2)) in the original's normalised training format."""
        dt = self.dtype
        q, qd, qdd = (np.asarray(a, dtype=dt) for a in (q, qd, qdd))
        p = np.asarray(params, dtype=dt)
        if p.ndim == 1:
            p = np.broadcast_to(p, (q.shape[0], 4))
        X = np.concatenate([q, qd, p], axis=1)
        if self.norm_stats is None:  # first-chunk statistics, same recipe as train_utils.normalize_data
            X_mean, X_std = X.mean(0), X.std(0)
            X_mean[:2], X_std[:2] = 0.0, 1.0
            X_std = np.where(X_std == 0, 1.0, X_std).astype(dt)
            self.norm_stats = {"X_mean": X_mean.astype(dt), "X_std": X_std,
                               "dXdt_mean": qdd.mean(0).astype(dt), "dXdt_std": qdd.std(0).astype(dt)}
        ns = self.norm_stats
        x = (X - ns["X_mean"]) / ns["X_std"]
        y = (qdd - ns["dXdt_mean"]) / ns["dXdt_std"]
        return x.astype(dt), y.astype(dt)

    def to_device(self, x, y):
        jnp = self._o.jax.numpy
        with self._o.jax.enable_x64(self.x64):
            return jnp.asarray(x), jnp.asarray(y)

    def step_normalised(self, x, y) -> float:
        """One original train_step on already-normalised x (N,8), y (N,2); returns the loss."""
        o = self._o
        with o.jax.enable_x64(self.x64):
            self.model, self.opt_state, loss = o.train.train_step(
                self.model, self.opt_state, x, y, self.optimizer, 2)
            loss = float(loss)  # blocks
        self.losses.append(loss)
        return loss

    def __call__(self, q, qd, qdd, params) -> float:
        x, y = self.normalise(q, qd, qdd, params)
        return self.step_normalised(*self.to_device(x, y))

    def loss(self, q, qd, qdd, params) -> float:
        """The original's compute_loss (Huber on normalised qdd + var of normalised H), no update."""
        x, y = self.to_device(*self.normalise(q, qd, qdd, params))
        with self._o.jax.enable_x64(self.x64):
            return float(self._o.train.compute_loss(self.model, x, y, split_size=2))


def train_step_fn(dtype="float32", init="scratch", norm="released") -> OriginalTrainStep:
    """A callable ``step(q, qd, qdd, params) -> loss`` running one original training step."""
    return OriginalTrainStep(dtype=dtype, init=init, norm=norm)


def param_count() -> int:
    o = _import_original()
    with o.jax.enable_x64(True):
        model = _new_model(o)
    leaves = o.jax.tree_util.tree_leaves(o.eqx.filter(model, o.eqx.is_array))
    return int(sum(leaf.size for leaf in leaves))
