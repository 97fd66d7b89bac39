"""One Brax physics backend on one of fastrl's MJCF models: trajectories and speed, for
``experiments/speed_accuracy.py``.

Run inside the peer venv (see experiments/peers/setup_peers.sh); speed_accuracy.py calls it as

    .venv-peers/bin/python experiments/peers/brax_speed_accuracy.py --backend generalized \\
        --inputs IN.npz --out OUT.npz

``IN.npz`` holds ``xml`` (the asset's path), ``dt`` (the control step), ``qpos`` (S, nq) and
``qvel`` (S, nv) start states, ``ctrl`` (S, T, nu) controls held over each control step, ``batch``
(speed) and ``name`` (the Brax env of the same name, whose timestep split for this backend is
used). The model is fastrl's asset compiled by MuJoCo with ``fusestatic`` (bodies without joints
merged into their parents, the same rigid bodies: Brax wants one joint per body), slide joints'
``ref`` moved into their bodies' positions (``remove_joint_refs``), and loaded with
``brax.io.mjcf.load_model`` after switching its integrator to Euler and its solver to Newton
(Brax's loader refuses the others; each backend integrates and solves in its own way). Brax's
envs also change some models per backend (the positional Ant's gear, the spring Humanoid's):
not done here, so every backend simulates the asset's own model.

The timestep and solver iterations are the ones Brax's env of the same name uses with this
backend (from ``envs.get_environment(name, backend=...).sys``: ``opt.timestep``, e.g. 0.005 s
for the spring Ant; ``opt.iterations`` and ``opt.ls_iterations``, which MJX runs, e.g. 1 and 4
for the MJX Ant; ``solver_iterations`` and ``solver_maxls``, which the generalized backend runs,
e.g. 4 and 15 for the Ant), and the substeps per control step ``round(dt / timestep)``, as
Brax's env would take them. With the asset's own counts (MuJoCo's default of 100 iterations)
the generalized Ant ran at ~110 control steps/s at batch 64.

``OUT.npz``: ``root`` (S, T, 3) the first body's world position after each control step (Brax's
link 0, MuJoCo's body 1), ``q`` (S, T, nq) Brax's generalized positions, and JSON metadata
(``meta``): control steps/s at ``batch`` (median of at least 3 timed calls of a jitted, vmapped
``lax.scan`` over the T control steps with random controls; ``speed_batch`` says if a smaller
batch had to do, where the sequences' run predicted over ``SLOW_CALL_S`` per call), compile
seconds, the timestep and substeps, and whether any state went non-finite.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import statistics
import sys
import time

import numpy as np

# The jax.device_put_replicated shim (Brax 0.14 + new JAX) before brax is imported.
from brax_ant import install_device_put_replicated_shim

install_device_put_replicated_shim()
with contextlib.redirect_stdout(sys.stderr):
    import brax
    import jax
    import jax.numpy as jnp
    import mujoco
    from brax import envs
    from brax.io import mjcf

BACKENDS = ("mjx", "generalized", "spring", "positional")
SLOW_CALL_S = 60.0


def pipeline_module(backend: str):
    import importlib

    return importlib.import_module(f"brax.{backend}.pipeline")


def remove_joint_refs(spec) -> None:
    """Brax's loader refuses joint ``ref`` (the Hopper's rootz slides from 1.25 m) and joints of
    one body at different anchors. A slide joint's ``ref`` moves into its body's position instead
    (the body sits at the same place for the same qpos), and slide joints take the anchor of their
    body's hinge (a slide's anchor does not enter its motion): the model and every state are
    unchanged."""
    for body in spec.bodies:
        for joint in body.joints:
            if joint.ref == 0:
                continue
            if joint.type != mujoco.mjtJoint.mjJNT_SLIDE:
                raise SystemExit(f"joint {joint.name!r}: ref on a {joint.type.name} joint is not handled")
            axis = np.zeros(3)
            mujoco.mju_rotVecQuat(axis, np.asarray(joint.axis, float), np.asarray(body.quat, float))
            body.pos = np.asarray(body.pos) - joint.ref * axis / np.linalg.norm(axis)
            joint.ref = 0.0
        # Brax also wants one anchor per body; a slide joint's anchor changes nothing physically
        anchors = {tuple(j.pos) for j in body.joints if j.type != mujoco.mjtJoint.mjJNT_SLIDE}
        if len(anchors) == 1:
            for joint in body.joints:
                joint.pos = list(next(iter(anchors)))


def main() -> None:
    fmt = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=fmt)
    parser.add_argument("--backend", choices=BACKENDS, required=True)
    parser.add_argument("--inputs", required=True)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()

    inp = np.load(args.inputs)
    name, dt, batch = str(inp["name"]), float(inp["dt"]), int(inp["batch"])
    qpos0, qvel0, ctrl = inp["qpos"], inp["qvel"], inp["ctrl"]
    with contextlib.redirect_stdout(sys.stderr):
        brax_sys = envs.get_environment(name, backend=args.backend).sys
    timestep = float(brax_sys.opt.timestep)
    solver = {
        key: int(getattr(brax_sys.opt, key[4:]) if key.startswith("opt.") else getattr(brax_sys, key))
        for key in ("opt.iterations", "opt.ls_iterations", "solver_iterations", "solver_maxls")
    }
    substeps = max(1, round(dt / timestep))
    timestep = dt / substeps

    spec = mujoco.MjSpec.from_file(str(inp["xml"]))
    spec.compiler.fusestatic = True  # Brax needs a joint per body: jointless bodies join their parent
    remove_joint_refs(spec)
    mj = spec.compile()
    mj.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
    mj.opt.solver = mujoco.mjtSolver.mjSOL_NEWTON  # Brax's loader refuses PGS (the Humanoid asset's)
    mj.opt.timestep = timestep
    mj.opt.iterations, mj.opt.ls_iterations = solver["opt.iterations"], solver["opt.ls_iterations"]
    sys_ = mjcf.load_model(mj).tree_replace(solver)
    pipe = pipeline_module(args.backend)

    def control_step(state, u):
        def sub(s, _):
            return pipe.step(sys_, s, u), None

        return jax.lax.scan(sub, state, None, length=substeps)[0]

    def rollout(q, qd, us):
        def body(state, u):
            state = control_step(state, u)
            return state, (state.x.pos[0], state.q, _finite(state))

        _, out = jax.lax.scan(body, pipe.init(sys_, q, qd), us)
        return out

    def _finite(state):
        leaves = [x for x in jax.tree.leaves(state) if jnp.issubdtype(jnp.asarray(x).dtype, jnp.inexact)]
        return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in leaves]))

    run = jax.jit(jax.vmap(rollout))
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    with contextlib.redirect_stdout(sys.stderr):
        # accuracy: the given sequences
        acc_args = (f32(qpos0), f32(qvel0), f32(ctrl))
        root, q, finite = jax.block_until_ready(run(*acc_args))
        t0 = time.perf_counter()
        jax.block_until_ready(run(*acc_args))
        per_sequence_s = (time.perf_counter() - t0) / len(qpos0)
        # speed: the batch, start states and controls tiled from the sequences; a smaller batch
        # where one call at the full batch would take over SLOW_CALL_S (the generalized Humanoid)
        while batch > len(qpos0) and per_sequence_s * batch > SLOW_CALL_S:
            batch //= 2
        reps = -(-batch // len(qpos0))
        tile = lambda a: f32(np.concatenate([a] * reps)[:batch])  # noqa: E731
        speed_args = (tile(qpos0), tile(qvel0), tile(ctrl))
        t0 = time.perf_counter()
        compiled = run.lower(*speed_args).compile()
        compile_s = time.perf_counter() - t0
        jax.block_until_ready(compiled(*speed_args))
        times, spent = [], 0.0
        while len(times) < 3 or spent < 1.0:
            t0 = time.perf_counter()
            jax.block_until_ready(compiled(*speed_args))
            times.append(time.perf_counter() - t0)
            spent += times[-1]
            if times[-1] > 3.0:
                break
    wall = statistics.median(times)
    meta = {
        "backend": args.backend,
        "timestep": timestep,
        "substeps": substeps,
        "solver": solver,
        "control_steps_per_s": batch * ctrl.shape[1] / wall,
        "speed_batch": batch,
        "compile_s": compile_s,
        "nonfinite": int((~np.asarray(finite)).any(axis=1).sum()),
        "brax_version": brax.__version__,
        "jax_version": jax.__version__,
    }
    np.savez(args.out, root=np.asarray(root), q=np.asarray(q), meta=json.dumps(meta))
    print(json.dumps(meta))


if __name__ == "__main__":
    main()
