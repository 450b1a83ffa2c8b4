import os
import shutil

# commands the tests run in subprocesses (lnn-torch fit, import, ...) use one thread too: two test
# workers on two cores, each running a two-thread command, would oversubscribe the machine
os.environ.setdefault("OMP_NUM_THREADS", "1")
# AOTInductor builds the C++ wrapper of each program (the code that calls its kernels, no arithmetic of its own)
# at -O1 by default: 7-9 s of a program's 12; at -O0 about 5 s. The tests compare programs' numbers, not their
# speed (benchmarks/ measure that with the default; the level is in a program's cache key, fused_aot, so a
# package the tests leave in a cache is never another run's)
os.environ.setdefault("AOT_INDUCTOR_COMPILE_WRAPPER_OPT_LEVEL", "O0")
# what commands cache (``lnn_torch.data.cache``: evaluation splits) goes to a folder of this test
# session, never the user's cache
import tempfile  # noqa: E402

os.environ["LNN_TORCH_CACHE"] = tempfile.mkdtemp(prefix="lnn_torch_test_cache_")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402

from lnn_torch.data import DatasetSpec, generate_dataset  # noqa: E402
from lnn_torch.systems import SYSTEMS, get_system  # noqa: E402

from .helpers import (  # noqa: E402, F401  (tests import them from here too)
    SPEC,
    dop853_reference,
    random_batch,
    random_inputs,
    session_file,  # noqa: E402
)

torch.set_num_threads(1)  # the tests run small tensors: one thread is faster and steadier
# the process settings lnn-torch's commands apply at their entry (denormals flushed, the allocator's
# thresholds raised): the tests run the library as the commands do
from lnn_torch.perf import apply_cpu_defaults  # noqa: E402

apply_cpu_defaults()

# every scene with torch-differentiable closed-form physics (an engine-backed scene, robot_arm, has its
# own tests), the chain at other lengths (N = 1, 2, 5) than its default of 3, and the double pendulum
# with joint damping (a conservative scene's optional dissipation)
SCENES = ([(name, {}) for name in sorted(SYSTEMS) if SYSTEMS[name].closed_form and SYSTEMS[name].differentiable]
          + [("chain_pendulum", {"num_links": n}) for n in (1, 2, 5)]
          + [("double_pendulum", {"joint_damping": (0.3, 0.2)})])
SCENE_IDS = [name + "".join(f"-{k}={v}" for k, v in kw.items()) for name, kw in SCENES]
QUADRATIC = [(n, kw) for n, kw in SCENES if get_system(n, **kw).quadratic_kinetic]
QUADRATIC_IDS = [i for i, (n, kw) in zip(SCENE_IDS, SCENES, strict=True) if (n, kw) in QUADRATIC]


def pytest_collection_modifyitems(config, items):
    """The slow tests first (a stable sort, the same in every xdist worker): with two workers, a
    one-minute test handed out last would keep one worker busy while the other idles at the end."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


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


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A small double-pendulum dataset (``helpers.SPEC``) for the training, data, CLI and compile tests."""
    shared = session_file(tmp_path_factory, "dp.h5", lambda p: generate_dataset(DatasetSpec(**SPEC), p))
    path = tmp_path_factory.mktemp("data") / "dp.h5"
    shutil.copyfile(shared, path)  # each module its own copy, generated once per session
    return path
