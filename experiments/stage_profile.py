"""Where a real robot's step spends its time, stage by stage, and how much of the scene touches.

    python -m experiments.stage_profile                         # the five robot tasks, three scenes
    python -m experiments.stage_profile --only leap_cube_reorient --batch 256

For each robot task (``fastrl/envs/robots/``) and full-collision Menagerie scene, float32, at
``--batch`` envs (fewer where XLA's plan for the step's scratch memory would exceed 30% of this
machine's memory): the batch is stepped for ``--warmup`` control steps under uniform random
actions (scenes: random controls within their ranges from the first keyframe), so that hands
grasp, feet land and bodies touch. On those states, each stage of the physics step is compiled
alone (``jax.jit(jax.vmap(stage))``, returning only the fields the stage writes) and timed:

    kinematics, com/crb, bias, smooth solve    the smooth dynamics (as ``experiments.compile_time``)
    bounding tests                             every budgeted group's bounding-sphere test
    narrow: <group>                            each pair group of ``collision_driver.pair_groups``
                                               (GJK/EPA groups with their bounding tests and GJK cull)
    contact selection                          the deepest candidates into the contact slots
    constraint rows                            every row, the contact selection included
    solver                                     the Newton iterations (or the fixed-budget solver)
    integrate                                  the integrator on the forward pass's result
    step                                       ``physics.step`` whole
    task                                       tasks: the env step less ``frame_skip`` physics
                                               steps: observation, reward, termination, auto-reset

Times are microseconds per env for one call, the best of ``--repeats`` timings of a few calls.
Stages share nothing, so their sum differs from the step. Beside the times: how many pair
candidates each group tests, how many of them have bounding spheres that overlap and how many
contacts are within their margin, averaged over the batch: the work that could be avoided.

Writes ``experiments/results/stage_profile.{json,md}``; a run's rows replace the earlier rows
of its scenes there. Nothing else should run on the machine (the page gives the load average).
"""

from __future__ import annotations

import argparse
import os
import pathlib
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import fastrl
from experiments import compile_time, results
from fastrl import envs, physics
from fastrl.envs import robots
from fastrl.envs.robots import assets
from fastrl.physics import collision_driver as cd
from fastrl.physics import constraint, noslip
from fastrl.physics.forward import euler, forward, has_constraints, implicitfast, rk4
from fastrl.physics.types import GeomType, Integrator

TASKS = ["leap_cube_reorient", "panda_pick_cube", "humanoid_joystick", "go1_joystick", "go1_joystick_rough"]
SCENES = ["menagerie/franka_emika_panda/scene", "menagerie/aloha/scene", "menagerie/unitree_g1/scene"]
MEMORY_SHARE = 0.3  # of physical memory: the most XLA's plan of the step's scratch may take


def _changed(before, after) -> list:
    """The leaves of ``after`` that are not leaves of ``before``: what a stage wrote."""
    old = {id(x) for x in jax.tree.leaves(before)}
    return [x for x in jax.tree.leaves(after) if id(x) not in old]


def _timed(fn, *args, repeats: int, calls: int = 3) -> float:
    """Seconds per call of the jitted ``fn``: the best of ``repeats`` timings of ``calls`` calls."""
    jax.block_until_ready(fn(*args))
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        for _ in range(calls):
            out = fn(*args)
        jax.block_until_ready(out)
        best = min(best, (time.perf_counter() - t) / calls)
    return best


def group_name(key, idx: np.ndarray) -> str:
    """A pair group as the page names it: its geom types and pair count."""
    if isinstance(key, cd.Convex):
        types = sorted(
            {
                (GeomType(a).name.lower(), GeomType(b).name.lower())
                for a, b in zip(key.types1, key.types2, strict=True)
            }
        )
        label = "GJK " + ", ".join(f"{a}-{b}" for a, b in types) + f" (hulls <= {key.program[0]} verts)"
    else:
        label = "-".join(GeomType(t).name.lower() for t in key[:2])
        label = ("faces " if len(key) > 2 else "") + label
    return f"{label}, {idx.size} pairs"


def stages(m: physics.Model) -> dict:
    """Each stage as a function of the data that ``forward`` leaves."""

    whole = compile_time.stages(m)  # the same stage functions as the compile-time breakdown
    out = {k: whole[k] for k in ("kinematics", "com/crb", "bias", "smooth solve")}
    if has_constraints(m):
        groups = cd.pair_groups(m)
        bounded = [idx for key, idx in groups if cd.is_gjk(key) or cd.compacted(m, key, idx)]
        if bounded:
            out["bounding tests"] = lambda d: [cd._overlap(m, d, idx) for idx in bounded]
        for key, idx in groups:
            out["narrow: " + group_name(key, idx)] = lambda d, key=key, idx=idx: cd.group_contacts(
                m, d, key, idx
            )
        slots = constraint.contact_groups(m)
        if slots:
            out["contact selection"] = lambda d: [constraint.select_contacts(m, d, s, n) for _, s, n in slots]
        out["constraint rows"] = whole["constraint"]
        out["solver"] = whole["solver"]
        if m.noslip_iterations:
            out["noslip"] = lambda d: noslip.solve(m, d)
    integrate = {Integrator.RK4: rk4, Integrator.IMPLICITFAST: implicitfast}.get(m.integrator, euler)
    out["integrate"] = lambda d: integrate(m, d)
    out["step"] = lambda d: physics.step(m, d)
    return out


def _fitting_batch(m: physics.Model, d0: physics.Data, batch: int) -> int:
    """``batch``, or the largest power of two below it whose step fits ``MEMORY_SHARE`` by XLA's plan."""
    budget = MEMORY_SHARE * os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    batched = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch, *x.shape)), d0)
    step = jax.jit(jax.vmap(lambda d: physics.step(m, d))).lower(batched).compile()
    need = step.memory_analysis().temp_size_in_bytes
    if need <= budget:
        return batch
    return 1 << int(np.floor(np.log2(max(1.0, batch * budget / need))))


def task_states(name: str, batch: int, warmup: int, seed: int = 0):
    """A task's env, and its batch's states after ``warmup`` control steps of random actions."""
    env = envs.make(name)
    batch = _fitting_batch(env.model, env.reset(jax.random.PRNGKey(0)).data, batch)
    low, high = (jnp.asarray(b) for b in env.action_bounds)

    @jax.jit
    def run(key):
        state = jax.vmap(env.reset)(jax.random.split(key, batch))

        def body(state, k):
            act = jax.random.uniform(k, (batch, env.action_size), minval=low, maxval=high)
            return jax.vmap(env.step)(state, act), None

        return jax.lax.scan(body, state, jax.random.split(jax.random.fold_in(key, 1), warmup))[0]

    return env, run(jax.random.PRNGKey(seed)), batch


def scene_states(name: str, batch: int, warmup: int, seed: int = 0):
    """A scene's model, and its batch's data after ``warmup`` steps of random controls held for
    10 steps each, from the first keyframe (or the model's reference pose)."""
    path = assets.scene_path(name)
    mj = mujoco.MjModel.from_xml_path(str(path))
    md = mujoco.MjData(mj)
    if mj.nkey:
        mujoco.mj_resetDataKeyframe(mj, md, 0)
    m = physics.load_mjcf(str(path))
    d0 = physics.make_data(m, qpos=md.qpos.copy(), qvel=md.qvel.copy(), ctrl=md.ctrl.copy())
    batch = _fitting_batch(m, d0, batch)
    low, high = (jnp.asarray(mj.actuator_ctrlrange[:, i], jnp.float32) for i in (0, 1))
    limited = jnp.asarray(mj.actuator_ctrllimited.astype(bool))

    @jax.jit
    def run(key):
        d = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch, *x.shape)), d0)
        ctrl = jax.random.uniform(key, (warmup // 10 + 1, batch, m.nu), minval=low, maxval=high)
        ctrl = jnp.where(limited, ctrl, d0.ctrl)

        def body(d, i):
            return jax.vmap(lambda di, u: physics.step(m, di, u))(d, ctrl[i // 10]), None

        return jax.lax.scan(body, d, jnp.arange(warmup))[0]

    return m, run(jax.random.PRNGKey(seed)), batch


def touching(m: physics.Model, d: physics.Data) -> dict:
    """Per group: its pairs, the batch's mean count of pairs whose bounding spheres overlap (where
    the group tests them) and of its contacts within their margin; the candidate contacts, contact
    slots, constraint rows and mean contacts within their margin (``ncon``)."""
    out = {"groups": {}}
    if not has_constraints(m):
        return out
    for key, idx in cd.pair_groups(m):
        group = {"pairs": int(idx.size)}
        if cd.is_gjk(key) or cd.compacted(m, key, idx):
            overlap = jax.jit(jax.vmap(lambda di, idx=idx: jnp.sum(cd._overlap(m, di, idx) >= 0)))(d)
            group["overlapping"] = float(jnp.mean(overlap))

        def within(di, key=key, idx=idx):
            dist, *_, pair, _ = cd.group_contacts(m, di, key, idx)
            return jnp.sum(dist < m.pair_margin[pair])

        group["contacts"] = float(jnp.mean(jax.jit(jax.vmap(within))(d)))
        out["groups"][group_name(key, idx)] = group
    out["candidates"] = int(cd.contact_layout(m).size)
    out["slots"] = int(constraint.contact_slots(m))
    out["ncon"] = float(jnp.mean(d.ncon))
    out["rows"] = int(constraint.sizes(m)[1])
    return out


def profile(m: physics.Model, d: physics.Data, repeats: int) -> dict:
    """Microseconds per env of each stage alone, on the batch ``d`` as ``forward`` leaves it."""
    batch = jax.tree.leaves(d)[0].shape[0]
    d = jax.jit(jax.vmap(lambda di: forward(m, di)))(d)
    times = {}
    for name, fn in stages(m).items():
        run = jax.jit(jax.vmap(lambda di, fn=fn: _changed(di, fn(di))))
        times[name] = _timed(run, d, repeats=repeats) * 1e6 / batch
        print(f"  {name}: {times[name]:.1f} us", flush=True)
    return {"times": times, "touching": touching(m, d)}


def profile_task(name: str, args) -> dict:
    env, state, batch = task_states(name, args.batch, args.warmup)
    print(f"{name}: batch {batch}", flush=True)
    row = {"name": name, "scene": env.scene, "batch": batch, "frame_skip": env.frame_skip}
    row.update(profile(env.model, state.data, args.repeats))
    low, high = (jnp.asarray(b) for b in env.action_bounds)
    act = jax.random.uniform(jax.random.PRNGKey(2), (batch, env.action_size), minval=low, maxval=high)
    env_step = _timed(jax.jit(jax.vmap(env.step)), state, act, repeats=args.repeats) * 1e6 / batch
    row["times"]["task"] = env_step - env.frame_skip * row["times"]["step"]
    row["env_step"] = env_step
    print(f"  env step: {env_step:.1f} us", flush=True)
    return row


def profile_scene(name: str, args) -> dict:
    m, d, batch = scene_states(name, args.batch, args.warmup)
    print(f"{name}: batch {batch}", flush=True)
    row = {"name": name, "scene": name, "batch": batch, "frame_skip": 1}
    row.update(profile(m, d, args.repeats))
    return row


def markdown(rows: list[dict], meta: dict) -> str:
    out = [
        "# Where the robots' step spends its time, stage by stage",
        "",
        f"{meta['date']}, {meta['machine']}; fastrl {meta['fastrl']}. Command: `{meta['command']}`. "
        f"Load average before {meta['load_before']}, after {meta['load_after']} (2 cores).",
        "",
        "Microseconds per env for one call of each stage compiled alone (`jax.jit(jax.vmap(stage))`), "
        "float32, on the batch's states after random actions; `%` is the share of the physics step. "
        "Stages share nothing, so they do not add up to the step exactly. `task`: the env step less "
        "its `frame_skip` physics steps (observation, reward, termination, auto-reset). Beside each "
        "narrow-phase group: its pairs; the mean pairs whose bounding spheres (grown by the margin) "
        "overlap, where the group tests them; and the mean contacts within their margin, over the batch.",
        "",
    ]
    for r in rows:
        t, touch = r["times"], r["touching"]
        step = t["step"]
        out += [f"## {r['name']}", ""]
        if touch.get("candidates") is not None:
            out += [
                f"Scene `{r['scene']}`, batch {r['batch']}, {r['frame_skip']} physics steps per control "
                f"step. {touch['candidates']} candidate contacts, {touch['slots']} contact slots, "
                f"{touch['rows']} constraint rows; contacts within their margin: {touch['ncon']:.1f} "
                "per env on average.",
                "",
            ]
        out += [
            "| stage | us per env | % of step | pairs | overlapping | contacts |",
            "| --- | ---: | ---: | ---: | ---: | ---: |",
        ]
        for name, us in t.items():
            g = touch["groups"].get(name.removeprefix("narrow: "), {})
            counts = [f"{g[k]:.1f}" if k in g else "" for k in ("overlapping", "contacts")]
            share = f"{100 * us / step:.0f}" if name not in ("step", "task") else ""
            out.append(f"| {name} | {us:.1f} | {share} | {g.get('pairs', '')} | {' | '.join(counts)} |")
        if "env_step" in r:
            out.append(f"| env step | {r['env_step']:.1f} | | | | |")
        out.append("")
    return "\n".join(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", help="tasks or scenes to profile (default: all)")
    parser.add_argument("--batch", type=int, default=1024)
    parser.add_argument("--warmup", type=int, default=40, help="control steps before profiling")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default=str(results.RESULTS))
    args = parser.parse_args()
    names = args.only or TASKS + SCENES
    unknown = [n for n in names if n not in TASKS + SCENES and n not in vars(robots) and "/" not in n]
    if unknown:
        parser.error(f"unknown tasks or scenes {unknown}; tasks: {TASKS}, scenes: {SCENES}")
    load_before = os.getloadavg()[0]
    version = results.fastrl_version()
    path = pathlib.Path(args.out) / "stage_profile.json"
    rows = [r for r in results.load(path)["rows"] if r["name"] not in names] if path.exists() else []
    for name in names:  # saved after each, so that a long run keeps what it measured
        rows.append(profile_scene(name, args) if "/" in name else profile_task(name, args))
        meta = {
            "date": results.today(),
            "machine": results.machine(),
            "fastrl": version,
            "command": results.command(),
            "load_before": round(load_before, 2),
            "load_after": round(os.getloadavg()[0], 2),
        }
        results.save(args.out, "stage_profile", {"meta": meta, "rows": rows}, markdown(rows, meta))


if __name__ == "__main__":
    fastrl.use_recommended_xla_flags()
    main()
