import numpy as np
import pytest
import torch

torch.set_num_threads(2)


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
    return q, qd, params
