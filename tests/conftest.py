import os

os.environ.setdefault("MUJOCO_GL", "disable")

import pytest  # noqa: E402
import torch as th  # noqa: E402

th.set_num_threads(1)

#: tiny sizes for fast tests
TINY = dict(policy_kwargs={"hidden_dim": 32}, batch_size=32, buffer_size=10_000, learning_starts=200)


@pytest.fixture
def tiny() -> dict:
    return {k: (dict(v) if isinstance(v, dict) else v) for k, v in TINY.items()}
