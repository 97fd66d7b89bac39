"""The dense Cholesky solves of large dense Hessians (the Humanoid's 23 dofs and up)."""

import os
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from fastrl.physics import factor

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("n", [14, 17, 23, 31, 40])
def test_column_cholesky_and_solve_match_numpy(n):
    rng = np.random.default_rng(n)
    a = rng.standard_normal((n, n))
    qm, vec = a @ a.T + n * np.eye(n), rng.standard_normal(n)
    with jax.enable_x64(True):
        c = np.asarray(factor._dense_cholesky(qm))
        x = np.asarray(factor._dense_cho_solve(c, vec))
    np.testing.assert_allclose(c, np.linalg.cholesky(qm), rtol=0, atol=1e-12)
    np.testing.assert_allclose(x, np.linalg.solve(qm, vec), rtol=1e-12, atol=1e-12)


_TWO_DEVICES = """
import jax, jax.numpy as jnp
from fastrl import envs, physics
from fastrl.physics import factor
assert jax.device_count() == 2
env = envs.make("humanoid")
d = env.reset(jax.random.PRNGKey(0)).data
text = jax.jit(lambda d: physics.step(env.model, d)).lower(d).as_text()
print(factor.dense_solver(tuple(tuple(range(k - 1, -1, -1)) for k in range(23))), "lapack" in text)
"""


def test_two_devices_keep_lapack_out_of_the_program():
    # LAPACK's Cholesky in a program on 2 XLA:CPU devices deadlocked the Humanoid's PPO chunk
    # (every thread idle); with several devices the dense solve is the column-wise one.
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-c", _TWO_DEVICES], env=env, cwd=ROOT, capture_output=True,
                         text=True, timeout=300, check=True)  # fmt: skip
    assert out.stdout.split() == ["columns", "False"]
    one = factor.dense_solver(tuple(tuple(range(k - 1, -1, -1)) for k in range(23)))
    assert one == ("lapack" if jax.device_count() == 1 else "columns")
