"""Helpers shared by several test modules (fixtures live in ``conftest.py``)."""

import contextlib
import io
import os
import subprocess
import sys
from pathlib import Path

import lightning as L
import numpy as np
import torch
from filelock import FileLock

from lnn_torch.mechanics.euler_lagrange import generic_acceleration
from lnn_torch.networks import reference
from lnn_torch.training.datamodule import TrajectoryDataModule

ROOT = Path(__file__).resolve().parents[1]
SPEC = dict(scene="double_pendulum", num_trajectories=20, duration=2.0, dt=0.005, seed=5)


def random_batch(system, rng, n, dtype=torch.float64):
    """Random parameters and states of a scene as torch tensors."""
    params = torch.tensor(system.sample_params(rng, n), dtype=dtype)
    q, qd = system.sample_state(rng, n)
    # widen the state distribution beyond the sampler's so that every term of the dynamics matters
    q = torch.tensor(q * 2.0, dtype=dtype)
    qd = torch.tensor(qd * 5.0, dtype=dtype)
    if system.speed_limit is not None:  # stay inside the valid states (|qd| < c)
        qd = torch.tensor(rng.uniform(-0.97, 0.97, qd.shape), dtype=dtype) * system.speed_limit
    return q, qd, params


def random_inputs(system, rng, n, dtype=torch.float64):
    """Random inputs ``(n, num_inputs)`` of an actuated scene (about +-1 N m), None for an unactuated one."""
    if not system.num_inputs:
        return None
    return torch.tensor(rng.uniform(-1.0, 1.0, (n, system.num_inputs)), dtype=dtype)


def dop853_reference(system, q0, qd0, params, t_eval) -> np.ndarray:
    """One trajectory by scipy's DOP853 at rtol = atol = 1e-12: ``(len(t_eval), 2 dof)`` of (q, qd)."""
    from scipy.integrate import solve_ivp

    dof = system.dof
    p = torch.as_tensor(params, dtype=torch.float64)

    def f(t, y):
        yt = torch.from_numpy(y)
        return np.concatenate([y[dof:], system.acceleration(yt[:dof], yt[dof:], p).numpy()])

    y0 = np.concatenate([np.asarray(q0), np.asarray(qd0)])
    return solve_ivp(f, (0, t_eval[-1]), y0, method="DOP853", rtol=1e-12, atol=1e-12, t_eval=t_eval).y.T


def perturbed(model, scale=0.05, seed=0):
    """Random, non-identity FiLM and weights so that every path of the model matters."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(scale * torch.randn(p.shape, generator=gen, dtype=p.dtype))
    return model


def normalized_batch(model, system, rng, n=64):
    q, qd, params = random_batch(system, rng, n)
    return model.normalize(q, qd, params)


def assert_fast_path_is_the_references(model, system, qn, qdn, pn) -> None:
    """A structured model's fast accelerations equal, to 1e-10 (float64), the readable model's by the
    generic Hessian solve and by torch.func jvp/vjp + LAPACK Cholesky, under the same generalised
    force (random inputs for a scene with inputs)."""
    tau_n = (torch.randn(qn.shape[0], system.num_inputs, dtype=torch.float64).to(qn.device) if system.num_inputs
             else None)
    force = model.force_norm(qn, qdn, pn, tau_n)
    assert (force is None) == (not system.has_forces)
    fast = model.acceleration_norm(qn, qdn, pn, tau_n)
    generic = generic_acceleration(lambda a, b, c: reference.lagrangian(model, a, b, c), qn, qdn, pn, force=force)
    structured = reference.structured_model_acceleration(model, qn, qdn, pn, force)
    scale = generic.abs().max()
    assert (fast - generic).abs().max() <= 1e-10 * scale
    assert (fast - structured).abs().max() <= 1e-10 * scale


def make_dm(path, **kw):
    args = dict(path=str(path), spec=SPEC, chunk_len=16, chunks_per_batch=4, steps_per_epoch=5, eval_stride=20)
    args.update(kw)
    return TrajectoryDataModule(**args)


def quiet_trainer(tmp_path, **kw):
    from lightning.pytorch.loggers import TensorBoardLogger

    args = dict(max_epochs=1, inference_mode=False, enable_progress_bar=False, enable_model_summary=False,
                logger=TensorBoardLogger(str(tmp_path), name="lightning_logs", default_hp_metric=False),
                log_every_n_steps=1, default_root_dir=str(tmp_path), accelerator="cpu", devices=1)
    args.update(kw)
    return L.Trainer(**args)


def tiny_fit_args(data, *extra) -> list[str]:
    """The arguments of a short ``fit`` of the quickstart config on a small generated dataset at ``data`` (20
    trajectories of 2 s), no progress bar, then ``extra``."""
    return ["-c", str(ROOT / "configs" / "quickstart.yaml"), f"--data.path={data}", "--data.spec.num_trajectories=20",
            "--data.spec.duration=2.0", "--trainer.enable_progress_bar=false", *extra]


def run_cli(*args, cwd):
    """``lnn-torch ARGS`` in a new process (what a user's shell runs: entry point, exit code, streams)."""
    return subprocess.run([sys.executable, "-m", "lnn_torch.cli", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=600)


def cli_in_process(*args, cwd) -> subprocess.CompletedProcess:
    """``lnn-torch ARGS`` through ``lnn_torch.cli.main`` in this process, in ``cwd``: the same parsing,
    commands and exit code as ``run_cli`` without a new interpreter importing torch and Lightning for
    each call (seconds each). ``returncode`` is what ``main`` returns (or the code of a ``SystemExit``
    it raises); ``stdout`` and ``stderr`` hold what it printed. Any other exception propagates. The
    process state a command may change (working directory, environment, warning filters, default
    dtype) is restored afterwards."""
    import warnings

    from lnn_torch.cli import main

    out, err, here, env, dtype = io.StringIO(), io.StringIO(), os.getcwd(), dict(os.environ), torch.get_default_dtype()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
            try:
                code = main([str(a) for a in args])
            except SystemExit as exit_:
                code = exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None else 1)
    finally:
        os.chdir(here)
        os.environ.clear()
        os.environ.update(env)
        torch.set_default_dtype(dtype)
    return subprocess.CompletedProcess(list(args), code, out.getvalue(), err.getvalue())


def session_file(tmp_path_factory, name: str, write) -> Path:
    """The file ``name``, written by ``write(path)`` once per test session and shared by the pytest-xdist
    workers (which otherwise each build their own): the first to ask writes it under a lock beside it,
    the others wait and read it. Shared data only: a test that changes a file works on a copy."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the session's folder, above the workers' own
    path = root / name
    with FileLock(f"{path}.lock"):
        if not path.exists():
            part = path.with_name(f"part-{name}")
            write(part)
            os.replace(part, path)
    return path


def session_arrays(tmp_path_factory, name: str, make) -> dict:
    """The arrays of ``make()`` (a dict of numpy arrays), computed once per test session (``session_file``)."""
    def write(path):
        with open(path, "wb") as fh:
            np.savez(fh, **make())

    with np.load(session_file(tmp_path_factory, f"{name}.npz", write)) as z:
        return {k: z[k] for k in z.files}


def save_checkpoint(module, path) -> str:
    """``module`` as a checkpoint that ``load_model`` reads (weights, hyper-parameters, the stamp)."""
    from lnn_torch.training.checkpoint_format import stamp

    ckpt = {"state_dict": module.state_dict(), "hyper_parameters": dict(module.hparams),
            "pytorch-lightning_version": L.__version__}
    stamp(ckpt)
    torch.save(ckpt, path)
    return str(path)
