"""How many Newton iterations each model needs: the evidence behind the assets' iteration counts.

    python -m experiments.solver_iterations            # ~40 min on 2 cores (the Humanoids most)
    python -m experiments.solver_iterations --quick    # tiny, for CI

For every Gymnasium-suite asset, two measurements along random-action rollouts (controls uniform
in the actuator ranges, held over the env's frame skip, a fresh start every 1000 control steps):

* MuJoCo C with its Newton solver (100 iterations, tolerance 1e-8, warm-started as always): the
  fraction of physics steps that converged within k iterations (``mjData.solver_niter``).
* fastrl's own Newton solver: the relative difference ``max|qacc_k - qacc_32| / (max|qacc_32| +
  1)`` between k and 32 iterations from the same states (64 rollouts of 300 control steps), for
  k from MuJoCo's first passing count up to the first that passes (each k is one compile).

The rule the assets follow (their ``fastrl_solver_iterations`` custom numeric): the smallest k at
which MuJoCo converged in at least 99.99% of the steps and no step of fastrl's check is off by
more than 1e-4; none such keeps the default 8. Writes
``experiments/results/solver_iterations.{md,json}``.
"""

from __future__ import annotations

import argparse
import pathlib

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import fastrl
from experiments import results
from fastrl import physics
from fastrl.physics import io

ASSETS = results.ROOT / "fastrl" / "assets"
FRAME_SKIP = {
    "ant": 5, "half_cheetah": 5, "hopper": 4, "walker2d": 4, "humanoid": 5, "humanoidstandup": 5,
    "pusher": 5, "reacher": 2, "swimmer": 4, "inverted_pendulum": 2, "inverted_double_pendulum": 5,
}  # fmt: skip
KS = (1, 2, 3, 4, 5, 6, 7, 8)


def mujoco_iterations(name: str, control_steps: int) -> np.ndarray:
    """Newton iterations MuJoCo C took at every physics step of a random-action rollout."""
    m = mujoco.MjModel.from_xml_path(str(ASSETS / f"{name}.xml"))
    m.opt.solver, m.opt.iterations, m.opt.tolerance = mujoco.mjtSolver.mjSOL_NEWTON, 100, 1e-8
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    lo, hi = m.actuator_ctrlrange.T
    out = []
    for t in range(control_steps):
        d.ctrl[:] = rng.uniform(lo, hi)
        for _ in range(FRAME_SKIP[name]):
            mujoco.mj_step(m, d)
            out.append(d.solver_niter[0])
        if t % 1000 == 999:
            mujoco.mj_resetData(m, d)
            d.qpos[:] += rng.uniform(-0.01, 0.01, m.nq)
    return np.asarray(out)


def fastrl_differences(name: str, k: int, batch: int, control_steps: int) -> np.ndarray:
    """(steps,) relative qacc differences between k and 32 Newton iterations along rollouts."""
    path = ASSETS / f"{name}.xml"
    ref = physics.load_mjcf(path, solver_iterations=32)
    model = physics.load_mjcf(path, solver_iterations=k)
    key = jax.random.PRNGKey(0)
    lo, hi = np.asarray(ref.actuator_ctrlrange).T
    ctrl = jax.random.uniform(key, (control_steps, batch, ref.nu), minval=lo, maxval=hi)
    noise = jax.random.uniform(key, (batch, ref.nq), minval=-0.01, maxval=0.01)
    data = jax.vmap(lambda n: physics.make_data(ref, qpos=ref.qpos0 + n))(noise)

    def one(d, u):
        d = d.replace(ctrl=u)
        want = physics.forward(ref, d).qacc
        err = jnp.max(jnp.abs(physics.forward(model, d).qacc - want)) / (jnp.max(jnp.abs(want)) + 1.0)
        d = jax.lax.fori_loop(0, FRAME_SKIP[name], lambda _, d: physics.step(ref, d), d)
        return d, err

    run = jax.jit(lambda d: jax.lax.scan(lambda d, u: jax.vmap(one)(d, u), d, ctrl)[1])
    return np.asarray(run(data)).reshape(-1)


def measure(name: str, quick: bool) -> dict:
    """MuJoCo's convergence for every k; fastrl's check from MuJoCo's first k up until one passes."""
    its = mujoco_iterations(name, 200 if quick else 40_000)
    converged = {k: float(np.mean(its <= k)) for k in KS}
    first = next((k for k in KS if converged[k] >= 0.9999), io.DEFAULT_SOLVER_ITERATIONS)
    off, worst, rule = {}, {}, io.DEFAULT_SOLVER_ITERATIONS
    for k in range(first, io.DEFAULT_SOLVER_ITERATIONS + 1):  # one compile per k checked
        diffs = fastrl_differences(name, k, 4 if quick else 64, 10 if quick else 300)
        off[k], worst[k] = float(np.mean(diffs > 1e-4)), float(diffs.max())
        if off[k] == 0:
            rule = k
            break
    shipped = io.asset_solver_iterations(mujoco.MjModel.from_xml_path(str(ASSETS / f"{name}.xml")))
    return {"name": name, "physics_steps": int(its.size), "max_mujoco_iterations": int(its.max()),
            "mujoco_converged": converged, "fastrl_off_1e-4": off, "fastrl_worst": worst,
            "rule": int(rule), "shipped": int(shipped)}  # fmt: skip


def _int_keys(row: dict) -> dict:
    """A row read back from JSON, its per-k dicts keyed by int again (JSON keys are strings)."""
    per_k = ("mujoco_converged", "fastrl_off_1e-4", "fastrl_worst")
    return {**row, **{f: {int(k): v for k, v in row[f].items()} for f in per_k}}


def write(rows: list[dict], out: pathlib.Path, stem: str, command: str) -> None:
    """The rows as JSON and the table as markdown."""
    head = " | ".join(f"<= {k}" for k in KS)
    lines = [
        "# Newton iterations each model needs", "",
        f"Machine: {results.machine()}. Command: `{command}`.", "",
        "MuJoCo C's Newton solver (tolerance 1e-8): the share of physics steps of random-action rollouts "
        "that converged within k iterations; then fastrl's share of steps whose acceleration after k "
        "iterations differs from 32 iterations' by more than 1e-4 (relative). Rule: the smallest k with "
        "MuJoCo at >= 99.99% and fastrl never off by 1e-4 (else 8). Shipped: the asset's "
        "`fastrl_solver_iterations`.", "",
        f"| model | steps | MuJoCo max | {head} | rule | shipped |",
        "| --- | ---: | ---: | " + " | ".join("---:" for _ in KS) + " | ---: | ---: |",
    ]  # fmt: skip
    for r in rows:
        off = r["fastrl_off_1e-4"]
        cells = " | ".join(
            f"{100 * r['mujoco_converged'][k]:.3f}%" + (f" / {100 * off[k]:.3f}%" if k in off else "")
            for k in KS
        )
        lines.append(f"| {r['name']} | {r['physics_steps']:,} | {r['max_mujoco_iterations']} | {cells} | "
                     f"{r['rule']} | {r['shipped']} |")  # fmt: skip
    lines += [
        "",
        "Each cell: MuJoCo converged, then (for the counts fastrl was checked at: from MuJoCo's "
        "first passing count up to the first that passes fastrl's check) fastrl's share off by > 1e-4. "
        "fastrl's check: 64 rollouts x 300 control steps from the asset's qpos0 with small noise.",
    ]
    results.save(out, stem, rows, "\n".join(lines))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="two models, tiny rollouts, for CI")
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS)
    parser.add_argument("--models", nargs="+", choices=sorted(FRAME_SKIP), default=None)
    parser.add_argument("--merge", action="store_true", help="keep the other models' rows in the output JSON")
    args = parser.parse_args()
    names = args.models or (["inverted_pendulum", "hopper"] if args.quick else list(FRAME_SKIP))
    rows = []
    for name in names:
        rows.append(measure(name, args.quick))
        r = rows[-1]
        print(f"{name}: rule {r['rule']}, shipped {r['shipped']}, MuJoCo max {r['max_mujoco_iterations']}")
    stem = "solver_iterations_quick" if args.quick else "solver_iterations"
    command = "python -m experiments.solver_iterations" + (" --quick" if args.quick else "")
    old = args.out / f"{stem}.json"
    if args.merge and old.exists():
        kept = {r["name"]: _int_keys(r) for r in results.load(old)}
        kept.update({r["name"]: r for r in rows})
        rows = [kept[n] for n in FRAME_SKIP if n in kept]
        command += f" (then --models {' '.join(names)} --merge)"
    write(rows, args.out, stem, command)


if __name__ == "__main__":
    fastrl.use_recommended_xla_flags()  # the XLA:CPU flags fastrl's command line runs with
    main()
