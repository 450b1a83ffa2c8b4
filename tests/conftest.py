import os

# commands the tests run in subprocesses (lnn-torch fit, import, ...) use one thread too: two test
# workers on two cores, each running a two-thread command, would oversubscribe the machine
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402

from lnn_torch.systems import SYSTEMS, get_system  # noqa: E402

torch.set_num_threads(1)  # the tests run small tensors: one thread is faster and steadier

# every scene, the chain at other lengths (N = 1, 2, 5) than its default of 3, and the double
# pendulum with joint damping (a conservative scene's optional dissipation)
SCENES = ([(name, {}) for name in sorted(SYSTEMS) if SYSTEMS[name].closed_form]
          + [("chain_pendulum", {"num_links": n}) for n in (1, 2, 5)]
          + [("double_pendulum", {"joint_damping": (0.3, 0.2)})])
SCENE_IDS = [name + "".join(f"-{k}={v}" for k, v in kw.items()) for name, kw in SCENES]
QUADRATIC = [(n, kw) for n, kw in SCENES if get_system(n, **kw).quadratic_kinetic]
QUADRATIC_IDS = [i for i, (n, kw) in zip(SCENE_IDS, SCENES) if (n, kw) in QUADRATIC]


@pytest.fixture(autouse=True)
def one_torch_thread():
    """Commands run in-process (``main([...])``) set their own thread count; restore one thread after
    each test, so that two test workers never oversubscribe the cores for the rest of a session."""
    yield
    if torch.get_num_threads() != 1:
        torch.set_num_threads(1)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


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
