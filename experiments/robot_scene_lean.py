"""How lean can each robot task's scene be stepped? Contact slots and solver iterations, measured.

    python -m experiments.robot_scene_lean                      # every robot task (~10 min)
    python -m experiments.robot_scene_lean --envs humanoid_joystick

For each task of ``fastrl/envs/robots/``, from 16 of its reset states under uniform random
actions (servo targets held for ``frame_skip`` physics steps, ``--steps`` control steps):

* MuJoCo C on the scene as written (float64): the most contacts it keeps at once (``ncon``,
  beside fastrl's contact slots ``nconmax``) and how often its Newton solve runs to the scene's
  ``iterations`` (``solver_niter``), the evidence for both settings.
* fastrl variants of the scene: as the env steps it (MuJoCo's solver and the scene's
  iterations; the Leap hand's scene with MJX's broad-phase caps), fewer Newton iterations, half
  the contact slots, and the Leap hand's scene without the caps.
  Each: physics control steps/s at batch 256 (float32, one jitted scan of 10 control steps,
  best of 2) and the largest
  ``|qpos|`` difference from MuJoCo C's run (float64, each of the 16 starts), so a variant's
  speed is read beside what it costs in agreement.

Writes ``experiments/results/robot_scene_lean.{json,md}``; a run's rows replace the earlier rows
of its envs there.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import fastrl
from experiments import results
from experiments.robot_throughput import SCENES, TASKS
from fastrl import envs, physics
from fastrl.physics.collision_driver import contact_layout

NOMINAL = {"friction": 0.0, "mass": 0.0, "gain": 0.0}
STARTS = 16
TIMED_STEPS = 10  # control steps per timed call


def variants(env) -> list[tuple[str, dict]]:
    """(label, ``load_mjcf`` keywords) of the scene variants measured for ``env``."""
    m = env.model
    out = [("as the env steps it", {})]
    if m.solver_iterations > 1:
        out.append(("1 Newton iteration", {"solver_iterations": 1}))
    half = (m.solver_iterations + 1) // 2
    if 1 < half < m.solver_iterations:
        out.append((f"{half} Newton iterations", {"solver_iterations": half}))
    if contact_layout(m).size > m.nconmax // 2 > 0:
        out.append((f"{m.nconmax // 2} contact slots", {"nconmax": m.nconmax // 2}))
    if env.mjx_caps:
        if env.nconmax is not None:  # the env sets its own slots: beside them, the scene's
            out.append(("the scene's contact slots", {"nconmax": None}))
        uncapped = type(env)(randomization=NOMINAL, mjx_caps=False).model.nconmax
        out.append(("without MJX's caps, the loader's contact slots", {"mjx_caps": False, "nconmax": None}))
        out.append(("without MJX's caps, the env's contact slots", {"mjx_caps": False, "nconmax": uncapped}))
        if 1 < half < m.solver_iterations:  # against MuJoCo C's own contacts: the iterations alone
            label = f"without MJX's caps, the env's contact slots, {half} Newton iterations"
            out.append((label, {"mjx_caps": False, "nconmax": uncapped, "solver_iterations": half}))
    return out


def _starts_and_controls(env, steps: int, seed: int = 0):
    """16 nominal reset states and (steps, 16, nu) servo targets of uniform random actions."""
    start = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(seed), STARTS))
    actions = jax.random.uniform(
        jax.random.PRNGKey(seed + 1), (steps, STARTS, env.action_size), minval=-1, maxval=1
    )
    ctrl = jax.vmap(jax.vmap(env._control), in_axes=(0, None))(actions, start.task)
    return (
        np.asarray(start.data.qpos, np.float64),
        np.asarray(start.data.qvel, np.float64),
        np.asarray(ctrl, np.float64),
    )


def in_mujoco(env, qpos, qvel, ctrl) -> dict:
    """MuJoCo C's runs: qpos after every control step (steps, starts, nq), its most contacts and
    how often its solve used every iteration."""
    mj = mujoco.MjModel.from_xml_path(str(env.asset_path))
    traj, ncon, capped, total = [], 0, 0, 0
    for i in range(qpos.shape[0]):
        md = mujoco.MjData(mj)
        md.qpos[:], md.qvel[:] = qpos[i], qvel[i]
        rows = []
        for t in range(ctrl.shape[0]):
            md.ctrl[:] = ctrl[t, i]
            for _ in range(env.frame_skip):
                mujoco.mj_step(mj, md)
                ncon = max(ncon, md.ncon)
                capped += int(md.solver_niter[0] >= mj.opt.iterations)
                total += 1
            rows.append(md.qpos.copy())
        traj.append(rows)
    return {"qpos": np.transpose(np.asarray(traj), (1, 0, 2)), "max_ncon": ncon,
            "iterations": int(mj.opt.iterations), "at_iteration_cap": capped / total}  # fmt: skip


def _rollout(model, frame_skip: int):
    def run(qpos, qvel, ctrl):  # one env: (steps, nq) qpos after each control step
        data = physics.forward(model, physics.make_data(model, qpos=qpos, qvel=qvel))

        def control_step(d, c):
            d = jax.lax.fori_loop(0, frame_skip, lambda _, x: physics.step(model, x, c), d)
            return d, d.qpos

        return jax.lax.scan(control_step, data, ctrl)[1]

    return run


def measure_variant(env, kwargs: dict, qpos, qvel, ctrl, reference, batch: int) -> dict:
    load = {"linesearch": env.linesearch, "mjx_caps": env.mjx_caps, "nconmax": env.nconmax, **kwargs}
    with jax.enable_x64(True):
        model = physics.load_mjcf(env.asset_path, **load)
        run = jax.jit(jax.vmap(_rollout(model, env.frame_skip), in_axes=(0, 0, 1)))
        ours = np.asarray(run(jnp.asarray(qpos), jnp.asarray(qvel), jnp.asarray(ctrl)))
    error = float(np.abs(np.transpose(ours, (1, 0, 2)) - reference).max())
    model = physics.load_mjcf(env.asset_path, **load)  # float32, as trained
    reps = -(-batch // STARTS)
    q, v, c = (jnp.asarray(np.repeat(x, reps, axis=ax), jnp.float32)
               for x, ax in ((qpos, 0), (qvel, 0), (ctrl[:TIMED_STEPS], 1)))  # fmt: skip
    run = jax.jit(jax.vmap(_rollout(model, env.frame_skip), in_axes=(0, 0, 1)))
    t0 = time.perf_counter()
    jax.block_until_ready(run(q, v, c))
    compile_s = time.perf_counter() - t0
    best = np.inf
    for _ in range(2):
        t0 = time.perf_counter()
        jax.block_until_ready(run(q, v, c))
        best = min(best, time.perf_counter() - t0)
    return {"nconmax": int(model.nconmax), "iterations": int(model.solver_iterations),
            "control_steps_per_s": q.shape[0] * c.shape[0] / best, "compile_s": compile_s,
            "max_qpos_error": error}  # fmt: skip


def measure(name: str, steps: int, batch: int) -> dict:
    env = envs.make(name, randomization=NOMINAL)
    qpos, qvel, ctrl = _starts_and_controls(env, steps)
    mj = in_mujoco(env, qpos, qvel, ctrl)
    row = {"env": name, "scene": SCENES[name], "steps": steps, "frame_skip": env.frame_skip,
           "mujoco": {k: v for k, v in mj.items() if k != "qpos"}, "variants": []}  # fmt: skip
    for label, kwargs in variants(env):
        out = measure_variant(env, kwargs, qpos, qvel, ctrl, mj["qpos"], batch)
        row["variants"].append({"variant": label, **out})
        print(name, label, out, flush=True)
    return row


def markdown(rows: list[dict], batch: int, commands: list[str]) -> str:
    lines = [
        "# Robot task scenes: contact slots and Newton iterations, measured", "",
        "Commands, each later one's rows replacing the earlier rows of its envs: "
        + "; ".join(f"`{c}`" for c in commands)
        + f". {STARTS} reset states per task, uniform random actions held over each control step. "
        "MuJoCo C: the scene as written, float64. fastrl: physics only, control steps/s "
        f"at batch {batch} (float32, {TIMED_STEPS} control steps, best of 2), and the largest |qpos| "
        "difference from MuJoCo C's run over "
        "the same starts and servo targets (float64).", "",
        "| env | control steps | MuJoCo C: most contacts | MuJoCo C: steps at its iteration cap | variant "
        "| contact slots | Newton iterations | control steps/s | max qpos error |",
        "| --- | ---: | ---: | ---: | --- | ---: | ---: | ---: | ---: |",
    ]  # fmt: skip
    for r in rows:
        mj = r["mujoco"]
        for i, v in enumerate(r["variants"]):
            head = (f"{r['env']} | {r['steps']} | {mj['max_ncon']} | {100 * mj['at_iteration_cap']:.0f}% "
                    f"(of {mj['iterations']})") if i == 0 else " | | |"  # fmt: skip
            lines.append(f"| {head} | {v['variant']} | {v['nconmax']} | {v['iterations']} "
                         f"| {v['control_steps_per_s']:,.0f} | {v['max_qpos_error']:.1e} |")  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--envs", nargs="*", default=TASKS, help=f"robot tasks (default: {' '.join(TASKS)})")
    parser.add_argument("--steps", type=int, default=50, help="control steps per run")
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--out", default=results.RESULTS, help="results folder")
    args = parser.parse_args()
    rows = [measure(name, args.steps, args.batch) for name in args.envs]
    # each run's rows replace the earlier rows of its envs in the saved record
    path = pathlib.Path(args.out) / "robot_scene_lean.json"
    before = json.loads(path.read_text()) if path.exists() else {"rows": [], "meta": {}}
    rows = sorted([r for r in before["rows"] if r["env"] not in args.envs] + rows, key=lambda r: r["env"])
    commands = [*before["meta"].get("commands", []), results.command()]
    meta = {"machine": results.machine(), "jax": jax.__version__, "mujoco": mujoco.__version__}
    page = markdown(rows, args.batch, commands)
    results.save(args.out, "robot_scene_lean", {"meta": {**meta, "commands": commands}, "rows": rows}, page)
    print(page)


if __name__ == "__main__":
    fastrl.use_recommended_xla_flags()
    main()
