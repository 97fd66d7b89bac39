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


_PROGRAM = """
import hashlib, jax
from fastrl import envs, physics
from fastrl.physics import factor
env = envs.make("humanoid")
d = env.reset(jax.random.PRNGKey(0)).data
text = jax.jit(lambda d: physics.step(env.model, d)).lower(d).as_text()
chain = tuple(tuple(range(k - 1, -1, -1)) for k in range(23))
digest = hashlib.sha256(text.encode()).hexdigest()
print(jax.device_count(), factor.dense_solver(chain), "lapack" in text.lower(), digest)
"""


def test_the_step_program_does_not_depend_on_the_device_count():
    # LAPACK's Cholesky in a program on 2 XLA:CPU devices deadlocked the Humanoid's PPO chunk
    # (every thread idle), so on CPU the dense solve is always the column-wise one, and the
    # Humanoid's step (a dense 23-dof Hessian) is the same program on 1 device as on 2.
    out = []
    for n in (1, 2):
        env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={n}", PYTHONPATH=str(ROOT))
        run = subprocess.run([sys.executable, "-c", _PROGRAM], env=env, cwd=ROOT, capture_output=True,
                             text=True, timeout=300, check=True)  # fmt: skip
        out.append(run.stdout.split())
    assert [o[:3] for o in out] == [["1", "columns", "False"], ["2", "columns", "False"]]
    assert out[0][3] == out[1][3]
