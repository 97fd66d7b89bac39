"""Brax ``ant`` throughput (control steps/s) for one physics backend, printed as one JSON line.

Run inside the peer venv (see experiments/peers/setup_peers.sh):

    .venv-peers/bin/python experiments/peers/brax_ant.py --backend spring --batch 1024 --steps 100

Builds ``brax.envs.get_environment('ant', backend=...)`` with Brax's default settings for that
backend (spring/positional: timestep 0.005 x 10 frames; generalized/mjx: the XML's 0.01 x 5
frames; so ``dt`` = 0.05 s per control step for all four). It jits ``jax.vmap(env.reset)`` and
one ``lax.scan`` of ``--steps`` ``jax.vmap(env.step)`` calls with fresh uniform random actions in
[-1, 1] drawn inside the program, compiles that program ahead of time (``compile_s``), runs it once
to warm up, then times ``--repeats`` runs and reports the best: ``batch * steps / wall seconds``.
The raw env has no auto-reset: episodes that "terminate" (torso z out of range) keep simulating,
which does not change the cost of a step. ``nonfinite`` is true if any leaf of the final state
(pipeline state, observation, reward, ...) holds a NaN or inf; a NaN/inf reached earlier in the
rollout propagates through the integrator, so the final state catches it.

Everything on stdout except the final JSON line (e.g. MJX's "Failed to import warp" prints while
importing) is sent to stderr.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

BACKENDS = ("mjx", "generalized", "spring", "positional")


def install_device_put_replicated_shim() -> bool:
    """Re-add ``jax.device_put_replicated`` (removed from newer JAX, still called by Brax 0.14).

    Same contract as the removed function: every leaf gets a new leading axis of size
    ``len(devices)``, one identical slice per device (sharded along that axis), which is what
    ``jax.pmap`` and Brax's ``_unpmap`` (``addressable_shards[0].data.squeeze(0)``) expect.
    Returns True if the shim was installed, False if JAX still has the function.
    """
    if hasattr(jax, "device_put_replicated"):
        return False

    def device_put_replicated(x, devices):
        devices = list(devices)
        if not devices:
            raise ValueError("device_put_replicated: `devices` must be a non-empty sequence")
        mesh = jax.sharding.Mesh(np.asarray(devices), ("replica",))
        sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("replica"))

        def put(a):
            a = jnp.asarray(a)
            return jax.device_put(jnp.broadcast_to(a[None], (len(devices), *a.shape)), sharding)

        return jax.tree.map(put, x)

    jax.device_put_replicated = device_put_replicated
    return True


def install_clip_shim() -> bool:
    """Let ``jnp.clip`` take the ``a_min``/``a_max`` keywords again (newer JAX removed them; Brax
    0.14's fluid forces, ``brax/fluid.py``, which its swimmer needs, still pass them). Returns True
    if the shim was installed."""
    import inspect

    if "a_min" in inspect.signature(jnp.clip).parameters:
        return False
    clip = jnp.clip

    def clip_with_old_keywords(x, min=None, max=None, *, a_min=None, a_max=None, **kwargs):  # noqa: A002
        return clip(x, a_min if min is None else min, a_max if max is None else max, **kwargs)

    jnp.clip = clip_with_old_keywords
    return True


class TargetReached(Exception):
    """Raised by a training ``progress_fn`` to end a Brax run at a target return."""


def train_until_target(train, emit, t0: float, **kwargs) -> None:
    """Calls Brax's ``train(**kwargs)`` with its prints sent to stderr; a ``TargetReached``
    raised by its ``progress_fn`` ends the run early. Then emits the final JSON line,
    ``{"event": "done", "status": "done" | "reached", "elapsed_s": seconds since t0}``."""
    status = "done"
    with contextlib.redirect_stdout(sys.stderr):
        try:
            train(**kwargs)
        except TargetReached:
            status = "reached"
    emit({"event": "done", "status": status, "elapsed_s": time.perf_counter() - t0})


SHIMMED = install_device_put_replicated_shim()
CLIP_SHIMMED = install_clip_shim()
with contextlib.redirect_stdout(sys.stderr):
    import brax
    from brax import envs


def state_nonfinite(tree) -> bool:
    leaves = [x for x in jax.tree.leaves(tree) if jnp.issubdtype(jnp.asarray(x).dtype, jnp.inexact)]
    return bool(any(not bool(jnp.all(jnp.isfinite(x))) for x in leaves))


def integrator_name(env) -> str | None:
    """MuJoCo integrator enum name of the env's model (Brax's mjcf loader accepts only Euler)."""
    import mujoco

    value = getattr(env.sys.opt, "integrator", None)
    return None if value is None else mujoco.mjtIntegrator(int(value)).name.removeprefix("mjINT_")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--backend", choices=BACKENDS, default="generalized")
    parser.add_argument("--batch", type=int, default=1024)
    parser.add_argument("--steps", type=int, default=100, help="control steps per timed program (N)")
    parser.add_argument("--repeats", type=int, default=1, help="timed runs after the warm-up; best is kept")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    with contextlib.redirect_stdout(sys.stderr):
        env = envs.get_environment("ant", backend=args.backend)
    batch, steps = args.batch, args.steps

    reset = jax.jit(jax.vmap(env.reset))
    step = jax.vmap(env.step)

    def rollout(state, key):
        def body(s, k):
            a = jax.random.uniform(k, (batch, env.action_size), minval=-1.0, maxval=1.0)
            return step(s, a), None

        return jax.lax.scan(body, state, jax.random.split(key, steps))[0]

    key_reset, key_run = jax.random.split(jax.random.PRNGKey(args.seed))
    with contextlib.redirect_stdout(sys.stderr):
        state0 = jax.block_until_ready(reset(jax.random.split(key_reset, batch)))
        t0 = time.perf_counter()
        compiled = jax.jit(rollout).lower(state0, key_run).compile()
        compile_s = time.perf_counter() - t0
        final = jax.block_until_ready(compiled(state0, key_run))  # warm-up
        best = float("inf")
        for i in range(args.repeats):
            k = jax.random.fold_in(key_run, i + 1)
            t0 = time.perf_counter()
            final = jax.block_until_ready(compiled(state0, k))
            best = min(best, time.perf_counter() - t0)

    out = {
        "peer": "brax",
        "backend": args.backend,
        "batch": batch,
        "control_steps_per_s": batch * steps / best,
        "compile_s": compile_s,
        "dt": float(env.dt),
        "n_frames": int(env._n_frames),
        "nonfinite": state_nonfinite(final),
        "steps": steps,
        "wall_s": best,
        "timestep": float(env.sys.opt.timestep),
        "integrator": integrator_name(env),
        "done_fraction": float(jnp.mean(final.done)),
        "jax_backend": jax.default_backend(),
        "brax_version": brax.__version__,
        "jax_version": jax.__version__,
        "device_put_replicated_shim": SHIMMED,
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
