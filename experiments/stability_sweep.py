"""Where the Ant's simulation first diverges as the timestep grows, per integrator.

    python -m experiments.stability_sweep           # 64 Ants x 2 s of random actions per setting
    python -m experiments.stability_sweep --quick   # tiny, for CI

For each integrator and timestep it runs a batch of Ants from Gymnasium's start pose under
uniform random actions (held for 0.05 s, as in training) and records the fraction whose
divergence guard (``Data.diverged``: non-finite or |state| > 1e10) fired, and the fraction that
blew up without the guard's help (|qvel| > 1e3 or the torso below the floor by > 0.2 m).
Writes ``experiments/results/stability_sweep.{md,json}``.
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

ANT = results.ROOT / "fastrl" / "assets" / "ant.xml"
QPOS0 = np.array([0, 0, 0.75, 1, 0, 0, 0, 0, 1, 0, -1, 0, -1, 0, 1.0])
TIMESTEPS = [0.001, 0.002, 0.005, 0.01, 0.02, 0.03, 0.04, 0.05]


def run(integrator: str, timestep: float, batch: int, seconds: float, seed: int = 0) -> dict:
    mj = mujoco.MjModel.from_xml_path(str(ANT))
    mj.opt.timestep = timestep
    m = physics.model_from_mujoco(mj, integrator=integrator)
    substeps = max(1, int(round(0.05 / timestep)))
    controls = int(round(seconds / (substeps * timestep)))
    ctrl = jax.random.uniform(jax.random.PRNGKey(seed), (controls, batch, m.nu), minval=-1, maxval=1)
    data = jax.vmap(lambda _: physics.make_data(m, qpos=QPOS0))(jnp.arange(batch))

    def control_step(d, u):
        d = jax.lax.fori_loop(0, substeps, lambda _, d: physics.step(m, d, u), d)
        bad = jnp.any(jnp.abs(d.qvel) > 1e3) | (d.qpos[2] < -0.2)
        return d, bad

    def rollout(d, ctrl):
        d, bad = jax.lax.scan(lambda d, u: jax.vmap(control_step)(d, u), d, ctrl)
        return d.diverged, jnp.any(bad, axis=0)

    diverged, blown = jax.jit(rollout)(data, ctrl)
    return {
        "integrator": integrator, "timestep": timestep, "substeps": substeps, "batch": batch,
        "seconds": seconds, "guard_fraction": float(jnp.mean(diverged)),
        "blowup_fraction": float(jnp.mean(blown | diverged)),
    }  # fmt: skip


def markdown(rows: list[dict], batch: int, seconds: float) -> str:
    """The sweep's table, then each integrator's first timestep with any divergence."""
    table = results.table(
        ["integrator", "timestep", "substeps", "guard fired", "blew up (guard or bound)"],
        [[r["integrator"], str(r["timestep"]), r["substeps"], f"{r['guard_fraction']:.0%}",
          f"{r['blowup_fraction']:.0%}"] for r in rows],
        align="lrrrr",
    )  # fmt: skip
    lines = ["# Ant stability vs timestep (random actions held 0.05 s)", "",
             f"Batch {batch}, {seconds} s each. Command: `python -m experiments.stability_sweep`.", "",
             table]  # fmt: skip
    for integrator in ("euler", "rk4"):
        first = next(
            (r["timestep"] for r in rows if r["integrator"] == integrator and r["blowup_fraction"] > 0), None
        )
        lines.append(
            f"\n{integrator}: first timestep with any divergence: {first if first else 'none in the sweep'}"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS)
    args = parser.parse_args()
    timesteps = [0.05] if args.quick else TIMESTEPS
    batch, seconds = (4, 0.2) if args.quick else (64, 2.0)
    rows = []
    for integrator in ("euler", "rk4"):
        for dt in timesteps:
            rows.append(run(integrator, dt, batch, seconds))
            print(rows[-1], flush=True)
    text = markdown(rows, batch, seconds)
    results.save(args.out, "stability_sweep_quick" if args.quick else "stability_sweep", rows, text)
    print(text)


if __name__ == "__main__":
    fastrl.use_recommended_xla_flags()  # the XLA:CPU flags fastrl's command line runs with
    main()
