"""The GPU path: the same physics on a CUDA device as on the CPU. Skipped where torch sees no CUDA
device (CI has none); ``benchmarks/benchmark_gpu.py`` times this path (``results/gpu/README.md``).

On the GPU, in float64: the fast structured solve equals the readable references (torch.func and the
generic Hessian solve), the shipped models give the CPU's accelerations, torques and rollouts, a
training step gives the CPU's loss and gradients, the compiled dynamics equal the eager ones, and
``lnn-torch fit`` trains with ``--trainer.accelerator=gpu``."""

import numpy as np
import pytest
import torch

from lnn_torch import load_pretrained
from lnn_torch.networks import build_model
from lnn_torch.systems import get_system

from .helpers import (
    assert_fast_path_is_the_references,
    cli_in_process,
    normalized_batch,
    perturbed,
    tiny_fit_args,
)

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
CUDA = torch.device("cuda")


def _close(got: torch.Tensor, want: torch.Tensor, rel: float) -> None:
    """``got`` (any device) equals ``want`` to ``rel`` of ``want``'s largest entry."""
    got, want = got.detach().cpu(), want.detach()
    err = float((got - want).abs().max() / want.abs().max())
    assert err <= rel, f"relative difference {err:.3g} > {rel:g}"


@pytest.mark.parametrize("scene", ["double_pendulum", "chain_pendulum", "robot_arm"])
@pytest.mark.parametrize("variant", ["film_lnn", "delan"])
def test_the_fast_path_on_cuda_is_the_references_and_the_cpus(scene, variant):
    if scene == "robot_arm":
        pytest.importorskip("mujoco")
    system = get_system(scene)
    _fast_path_on_cuda(perturbed(build_model(variant, system, hidden_dims=(32, 32)).double()), system, 0)


def test_the_planar_chain_grey_box_on_cuda_is_the_references_and_the_cpus():
    """The grey-box chain (kinetic and potential parts ``chain``, absolute link angles) on the GPU."""
    system = get_system("double_pendulum")
    model = perturbed(build_model("film_lnn", system, kinetic={"chain": {"links": [[1, 0], [0, 1]]}},
                                  potential="chain", hidden_dims=(32, 32)).double())
    _fast_path_on_cuda(model, system, 4)


def _fast_path_on_cuda(model, system, seed: int) -> None:
    """On the GPU the model's fast solve is its references' and the CPU's, to 1e-10 (float64)."""
    qn, qdn, pn = normalized_batch(model, system, np.random.default_rng(seed), 256)
    cpu = model.acceleration_norm(qn, qdn, pn)
    model.to(CUDA)
    qn, qdn, pn = qn.to(CUDA), qdn.to(CUDA), pn.to(CUDA)
    assert_fast_path_is_the_references(model, system, qn, qdn, pn)
    _close(model.acceleration_norm(qn, qdn, pn), cpu, 1e-10)


@pytest.mark.parametrize("name", ["double_pendulum", "robot_arm_film_lnn", "robot_arm_grey_box"])
def test_the_shipped_models_on_cuda_give_the_cpus_dynamics(name):
    """Accelerations and an RK4 rollout at the scene's sampled states and parameters: float64 to 1e-10,
    float32 to 1e-4."""
    if name.startswith("robot_arm"):
        pytest.importorskip("mujoco")
    module = load_pretrained(name)
    model, system = module.model.double(), module.system
    rng = np.random.default_rng(1)
    q, qd = (torch.tensor(x) for x in system.sample_state(rng, 512))
    params = torch.tensor(system.sample_params(rng, 512))
    tau = torch.tensor(rng.uniform(-2.0, 2.0, (512, system.num_inputs))) if system.num_inputs else None
    with torch.no_grad():
        want = model.acceleration(q, qd, params, tau)
        held = None if tau is None else tau[:16, None].expand(-1, 50, -1)  # (B, steps, inputs)
        want_roll = model.rollout(q[:16], qd[:16], params[:16], 0.005, 50, tau=held)
        gpu = model.to(CUDA)
        args = [x if x is None else x.to(CUDA) for x in (q, qd, params, tau)]
        _close(gpu.acceleration(*args), want, 1e-10)
        short = [x[:16] for x in args[:3]]
        on_gpu = None if held is None else held.to(CUDA)
        for got, ref in zip(gpu.rollout(*short, 0.005, 50, tau=on_gpu), want_roll, strict=True):
            _close(got, ref, 1e-10)
        _close(gpu.float().acceleration(*(x if x is None else x.float() for x in args)), want, 1e-4)


def test_a_training_step_on_cuda_gives_the_cpus_loss_and_gradients():
    from lnn_torch import LNNModule
    from lnn_torch.training.training_pass import TrainingPass

    system = get_system("double_pendulum")
    rng = np.random.default_rng(2)
    q, qd = (torch.tensor(x) for x in system.sample_state(rng, 512))
    params = torch.tensor(system.sample_params(rng, 512))
    batch = {"q": q.reshape(64, 8, 2), "qd": qd.reshape(64, 8, 2),
             "qdd": system.acceleration(q, qd, params).reshape(64, 8, 2), "params": params.reshape(64, 8, 4)}
    torch.manual_seed(0)
    module = LNNModule(variant="film_lnn", hidden_dims=[32, 32], val_rollouts=0).double()
    perturbed(module.model, 0.05)
    results = []
    for device in ("cpu", "cuda"):
        module.to(device)
        module.zero_grad(set_to_none=True)
        fn = TrainingPass(module.training_terms, False).function(0, module.device)
        loss, _ = module.batch_loss({k: v.to(device) for k, v in batch.items()}, fn)
        loss.backward()
        results.append((loss.detach().cpu(), [p.grad.detach().cpu().clone() for p in module.parameters()]))
    (loss_cpu, grads_cpu), (loss_gpu, grads_gpu) = results
    _close(loss_gpu, loss_cpu.reshape(1), 1e-10)
    for g_gpu, g_cpu in zip(grads_gpu, grads_cpu, strict=True):
        assert (g_gpu - g_cpu).abs().max() <= 1e-9 * max(float(g_cpu.abs().max()), 1e-12)


@pytest.mark.slow
def test_compiled_dynamics_on_cuda_equal_the_eager_ones():
    model = load_pretrained("double_pendulum").model.to(CUDA)
    system = get_system("double_pendulum")
    rng = np.random.default_rng(3)
    q, qd = (torch.tensor(x, dtype=torch.float32, device=CUDA) for x in system.sample_state(rng, 4096))
    params = torch.tensor(system.sample_params(rng, 4096), dtype=torch.float32, device=CUDA)
    with torch.no_grad():
        eager = model.acceleration(q, qd, params).cpu()
        model.compile_dynamics()
        compiled = model.acceleration(q, qd, params)
    _close(compiled, eager, 1e-4)


@pytest.mark.slow
def test_fit_trains_on_the_gpu_with_the_cli(tmp_path):
    out = cli_in_process("fit", *tiny_fit_args(tmp_path / "d.h5", "--model.hidden_dims=[16,16]",
                                               "--model.val_rollout_seconds=0.5", "--trainer.accelerator=gpu",
                                               "--trainer.devices=1", "--trainer.max_steps=30",
                                               "--data.steps_per_epoch=10", "--trainer.check_val_every_n_epoch=1"),
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    last = torch.load(tmp_path / "lightning_logs" / "version_0" / "checkpoints" / "last.ckpt", weights_only=False)
    assert last["global_step"] == 30
    assert "validation: acc. rel. L2 error" in out.stdout


@pytest.mark.slow
@pytest.mark.parametrize("name, scene, duration", [("double_pendulum", "double_pendulum", 2.0),
                                                   ("robot_arm_film_lnn", "robot_arm", 1.0)])
def test_the_evaluation_on_cuda_is_the_cpus(name, scene, duration, tmp_path):
    """``evaluate_model``, the model and the trajectories on the GPU: the same scalars as on the CPU
    (float64), in the sections validation computes and those that make their own tensors."""
    from lnn_torch.data import DatasetSpec, generate_dataset, read_dataset
    from lnn_torch.evaluation import evaluate_model

    if scene == "robot_arm":
        pytest.importorskip("mujoco")
    path = generate_dataset(DatasetSpec(scene=scene, num_trajectories=4, duration=duration, seed=9), tmp_path / "d.h5")
    data = read_dataset(path).trajectories("train")
    module = load_pretrained(name)
    model, system = module.model.double(), module.system
    results = []
    for device in ("cpu", "cuda"):
        results.append(evaluate_model(model.to(device), system, data.to(device), horizon=duration,
                                      sections=("accelerations", "rollouts", "energy", "torques", "horizons", "ood")))
    cpu, gpu = results
    assert gpu["acc_rel_err"]["total"] == pytest.approx(cpu["acc_rel_err"]["total"], rel=1e-6)
    assert gpu["divergence_time@0.1"]["model"]["median"] == pytest.approx(
        cpu["divergence_time@0.1"]["model"]["median"], rel=1e-6)
    assert sorted(gpu.get("skipped", {})) == sorted(cpu.get("skipped", {}))
