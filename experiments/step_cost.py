"""Physics step cost per env, for before/after comparisons of engine changes.

    python experiments/step_cost.py ant,hopper,...   # prints {env: microseconds per env-step} as JSON

jax.jit(jax.vmap(physics.step)) at batch 256 from each env's reset states, zero controls; the best of
5 repeats of 10 steps. Run it from two checkouts alternately (PYTHONPATH=<checkout>) for a ratio.
"""

import json
import sys
import time

import jax
import jax.numpy as jnp

from fastrl import envs, physics

out = {}
for name in sys.argv[1].split(","):
    env = envs.make(name)
    m = env.model
    keys = jax.random.split(jax.random.PRNGKey(0), 256)
    s = jax.vmap(env.reset)(keys)
    d = s.data
    f = jax.jit(jax.vmap(lambda d, u, m=m: physics.step(m, d, u)))
    u = jnp.zeros((256, m.nu))
    d = f(d, u)
    jax.block_until_ready(d.qpos)
    best = 1e9
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(10):
            d = f(d, u)
        jax.block_until_ready(d.qpos)
        best = min(best, (time.perf_counter() - t) / 10)
    out[name] = best * 1e6 / 256
print(json.dumps(out))
