"""Physics throughput of the contact-free Ant-like model: fastrl vs MuJoCo C, in one run.

    python -m experiments.bench_physics            # full table (a few minutes on 2 cores)
    python -m experiments.bench_physics --quick    # tiny settings, for CI

For each integrator it measures fastrl's physics steps/s at several batch sizes (one jitted
``lax.scan`` over ``--steps`` vmapped steps, best of ``--repeats``), the compile time of that
program, MuJoCo C's ``mj_step`` in a single-threaded Python loop, and ``mujoco.rollout`` with one
and two threads. It then times each pipeline stage in isolation at the largest batch, to show
what limits the speed. Results go to ``experiments/results/physics_throughput.{md,json}``.
"""

from __future__ import annotations

import argparse
import pathlib
import time

import jax
import jax.numpy as jnp
import mujoco
import mujoco.rollout
import numpy as np

import fastrl
from experiments import results
from fastrl import physics
from fastrl.physics import actuation, factor, passive, smooth

MODEL = results.ROOT / "tests" / "assets" / "ant_air.xml"


def _batch(m: physics.Model, batch: int, steps: int, seed: int = 0):
    """Initial data (small random velocities) and fresh random controls for every step."""
    key_v, key_u = jax.random.split(jax.random.PRNGKey(seed))
    qvel = 0.1 * jax.random.normal(key_v, (batch, m.nv))
    data = jax.vmap(lambda v: physics.make_data(m, qvel=v))(qvel)
    ctrl = jax.random.uniform(key_u, (steps, batch, m.nu), minval=-1, maxval=1)
    return data, ctrl


def bench_fastrl(m: physics.Model, batch: int, steps: int, repeats: int) -> dict:
    """Steps/s of ``steps`` batched physics steps in one compiled program, and its compile time."""
    data0, ctrl = _batch(m, batch, steps)

    def run(d, ctrl):
        one = jax.vmap(lambda d, u: physics.step(m, d, u))
        return jax.lax.scan(lambda d, u: (one(d, u), None), d, ctrl)[0]

    t0 = time.perf_counter()
    compiled = jax.jit(run).lower(data0, ctrl).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(data0, ctrl))  # warm-up
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        data = jax.block_until_ready(compiled(data0, ctrl))
        best = min(best, time.perf_counter() - t0)
    assert not bool(jnp.any(data.diverged)), "benchmark state diverged"
    return {"batch": batch, "steps_per_s": batch * steps / best, "compile_s": compile_s}


def bench_mujoco_loop(mj: mujoco.MjModel, seconds: float) -> float:
    """Single-threaded ``mj_step`` from Python: steps/s."""
    md = mujoco.MjData(mj)
    rng = np.random.default_rng(0)
    md.qvel[:] = 0.1 * rng.standard_normal(mj.nv)
    ctrls = rng.uniform(-1, 1, (200, mj.nu))
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        mujoco.mj_resetData(mj, md)  # keep the state in the same regime as fastrl's
        for u in ctrls:
            md.ctrl[:] = u
            mujoco.mj_step(mj, md)
        n += len(ctrls)
    return n / (time.perf_counter() - t0)


def bench_mujoco_rollout(mj: mujoco.MjModel, nthread: int, batch: int, steps: int) -> float:
    """``mujoco.rollout`` (C++ loop, no Python per step) over a batch: steps/s."""
    datas = [mujoco.MjData(mj) for _ in range(nthread)]
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state0 = np.zeros(mujoco.mj_stateSize(mj, spec))
    mujoco.mj_getState(mj, datas[0], state0, spec)
    rng = np.random.default_rng(0)
    init = np.tile(state0, (batch, 1))
    ctrl = rng.uniform(-1, 1, (batch, steps, mj.nu))
    mujoco.rollout.rollout(mj, datas, init[:2], ctrl[:2, :10])  # warm-up
    t0 = time.perf_counter()
    mujoco.rollout.rollout(mj, datas, init, ctrl)
    return batch * steps / (time.perf_counter() - t0)


def _time(f, *args, repeats: int) -> float:
    out = jax.block_until_ready(f(*args))
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(f(*args))
        best = min(best, time.perf_counter() - t0)
    del out
    return best


def profile_stages(m: physics.Model, batch: int, repeats: int) -> dict[str, float]:
    """Microseconds per batched call of each stage, each compiled on its own."""
    data, ctrl = _batch(m, batch, 1)
    data = jax.jit(jax.vmap(lambda d, u: physics.forward(m, d.replace(ctrl=u))))(data, ctrl[0])
    stages = {
        "kinematics": lambda d: smooth.kinematics(m, d),
        "com_pos": lambda d: smooth.com_pos(m, d),
        "crb (mass matrix)": lambda d: smooth.crb(m, d),
        "com_vel": lambda d: smooth.com_vel(m, d),
        "rne (bias forces)": lambda d: smooth.rne(m, d),
        "passive + actuation": lambda d: actuation.actuation(m, passive.passive(m, d)),
        "factor + solve M": lambda d: factor.solve_m(m, factor.factor_m(m, d.qM), d.qfrc_smooth),
        "whole step": lambda d: physics.step(m, d),
    }
    out = {name: 1e6 * _time(jax.jit(jax.vmap(f)), data, repeats=repeats) for name, f in stages.items()}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes, for CI")
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS)
    args = parser.parse_args()
    batches = [8] if args.quick else [1, 64, 1024, 4096]
    steps, repeats = (5, 1) if args.quick else (100, 3)
    mj_seconds = 0.2 if args.quick else 3.0
    rollout_batch, rollout_steps = (8, 10) if args.quick else (256, 200)
    # Quick (CI): Euler only; the two integrators share every code path but the integration step.
    integrators = ("euler",) if args.quick else ("euler", "rk4")

    rows, profiles = [], {}
    for integrator in integrators:
        mj = mujoco.MjModel.from_xml_path(str(MODEL))
        mj.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4 if integrator == "rk4" else 0
        m = physics.model_from_mujoco(mj)
        for b in batches:
            r = bench_fastrl(m, b, steps, repeats)
            rows.append({"integrator": integrator, "engine": "fastrl", **r})
            print(rows[-1], flush=True)
        loop = bench_mujoco_loop(mj, mj_seconds)
        rows.append({"integrator": integrator, "engine": "MuJoCo C mj_step loop (1 thread)", "batch": 1,
                     "steps_per_s": loop, "compile_s": 0.0})  # fmt: skip
        for nthread in (1, 2):
            sps = bench_mujoco_rollout(mj, nthread, rollout_batch, rollout_steps)
            rows.append({"integrator": integrator, "engine": f"MuJoCo C rollout ({nthread} thread)",
                         "batch": rollout_batch, "steps_per_s": sps, "compile_s": 0.0})  # fmt: skip
        for r in rows[-3:]:
            print(r, flush=True)
        profiles[integrator] = profile_stages(m, batches[-1], repeats)
        print(profiles[integrator], flush=True)

    machine = results.machine()
    name = "physics_throughput_quick" if args.quick else "physics_throughput"
    text = markdown(rows, profiles, integrators, batches[-1], machine)
    results.save(args.out, name, {"machine": machine, "rows": rows, "profile_us": profiles}, text)
    print(text)


def markdown(rows: list[dict], profiles: dict, integrators: tuple[str, ...], batch: int, machine: str) -> str:
    """The throughput table (each row against MuJoCo C's 2-thread rollout), then the stage profile."""
    lines = [f"# Physics throughput: contact-free Ant-like model ({MODEL.name}), float32", "",
             f"Machine: {machine}. Command: `python -m experiments.bench_physics`.", "",
             "| integrator | engine | batch | steps/s | compile s | vs MuJoCo rollout 2 threads |",
             "| --- | --- | ---: | ---: | ---: | ---: |"]  # fmt: skip
    for integrator in integrators:
        sub = [r for r in rows if r["integrator"] == integrator]
        ref = next(r["steps_per_s"] for r in sub if r["engine"] == "MuJoCo C rollout (2 thread)")
        for r in sub:
            lines.append(f"| {integrator} | {r['engine']} | {r['batch']} | {r['steps_per_s']:,.0f} | "
                         f"{r['compile_s']:.1f} | {r['steps_per_s'] / ref:.2f}x |")  # fmt: skip
    stages = [[stage, *(f"{profiles[i][stage]:,.0f}" for i in integrators)] for stage in profiles["euler"]]
    lines += ["", f"Stage profile at batch {batch} (us per batched call):", "",
              results.table(["stage", *integrators], stages, align="l" + "r" * len(integrators))]  # fmt: skip
    return "\n".join(lines)


if __name__ == "__main__":
    fastrl.use_recommended_xla_flags()  # the XLA:CPU flags fastrl's command line runs with
    main()
