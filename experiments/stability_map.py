"""Stability map: where each env's simulation diverges, over timestep x solver iterations.

    python -m experiments.stability_map                          # all eleven envs, ~2.5 h on 2 cores
    python -m experiments.stability_map --envs ant hopper        # a subset
    python -m experiments.stability_map --envs walker2d --merge  # add envs to the committed map
    python -m experiments.stability_map --integrators euler rk4  # both integrators (twice the cost)
    python -m experiments.stability_map --quick                  # tiny, for CI (~20 s)

Envs: the eleven Gymnasium-suite envs: the contact envs Ant, HalfCheetah, Hopper, Walker2d,
Humanoid, HumanoidStandup (the Humanoid's model, starting lying down) and Pusher, and the
contact-free Swimmer, Reacher, InvertedPendulum and InvertedDoublePendulum (joint limits their only
constraints).

Grid, per env: physics timestep x constraint-solver iterations (1, 2, 3, 5, 8, 16; every env here
has constraint rows, contacts or joint limits, so every one gets that axis). The env's control
step ``dt`` (frame_skip x the asset's timestep) stays fixed: the timestep is ``dt / n`` for n
substeps per control step, n in {2 frame_skip, frame_skip, frame_skip // 2, 2, 1} (the Ant's
0.05 s control step: 0.005, 0.01, 0.025, 0.05 s). Two more columns lie past ``dt``: 2 dt and
4 dt with one physics step per control step, which then lasts the timestep (frame_skip cannot go
below 1). Probes (16 episodes) before the full map found the guard firing within ``dt`` only at
1 iteration (the Ant under Euler at 0.01, 0.025, 0.05 s, the HalfCheetah at 0.005, 0.025, 0.05 s); at
the shipped iterations the divergence within ``dt`` was sinking through the floor (the Ant from
0.025 s, the HalfCheetah from 0.025 s, penetrating 0.2-0.5 m), which the guard does not catch
and is not built to (the state stays finite; MuJoCo C at 100 iterations sinks alike, 0.19 and
0.53 m on the Ant at 0.025 and 0.05 s); the columns past ``dt`` show where the guard fires at the
shipped iterations (the Ant at 0.1 s, the HalfCheetah at 0.1 s, the InvertedDoublePendulum at
0.1 and 0.2 s), and ``tests/physics/test_stability.py`` asserts it does for two of them. The
integrator is the shipped one (``conf/experiment/<env>_ppo.yaml`` over the env's defaults: the
Ant trains with Euler and 5 iterations, the others with their asset's integrator and 8), or those
``--integrators`` names.

Each cell runs a batch of episodes (64; the Humanoid 16, its physics step costs ~35x the Ant's)
of 1000 control steps from the env's own ``reset`` (fixed keys, the same in every cell) under
uniform random actions in the action bounds (the same sequence in every cell), one per control
step, held over its substeps, with no task termination and no auto-reset: the physics
(``fastrl.physics.step``) is stepped directly, as ``Env.step`` does. An episode diverges at the
first control step where

* the guard flags it (``Data.diverged``: a non-finite state or |qpos|, |qvel| > 1e10), or
* a contact penetrates deeper than ``PENETRATION_BOUND``, 0.1 m (any candidate's
  ``Data.contact_dist``, checked at every substep). Soft contacts penetrate under random
  actions even when accurate: MuJoCo C itself, at each asset's timestep with Newton at 100
  iterations, reaches 4-7 cm over 8-16 episodes x 1000 steps (Ant 6.4, HalfCheetah 6.9,
  Walker2d 5.6, Hopper 4.0 cm), and fastrl's shipped Ant 7.8 cm over 64, so 5 cm would flag the
  reference; or
* the state blows up short of the guard: any |qvel| > ``QVEL_BOUND`` (1e3 m/s or rad/s, checked
  at every substep).

Per cell: the fraction of episodes that diverged (by any criterion and by each), the median
first control step of divergence (any criterion, and the guard's) among them, the deepest finite
penetration and the largest finite |qvel|.

Cost (2 cores shared with a training run; one compiled program per env and iteration count,
the timestep and substeps are its runtime arguments): a full Ant cell at the shipped setting
(64 x 1000 control steps x 5 substeps) takes 14 s, at 10 substeps 23 s, after a 28 s compile; a
Humanoid cell (16 x 1000 x 5, RK4) 17-24 s at 5 substeps and 30-130 s at 10 (more with more
iterations), after a 27-32 s compile (2026-11-25, with LAPACK for its dense Hessian). Measured:
Ant 9 min, HalfCheetah 6, Hopper 13, Walker2d 15, Humanoid 17, HumanoidStandup 30 (sharing the
cores with tests), Pusher 8, the other four 2-4 each: about 2 h.

``--merge`` adds the envs it maps to the output JSON's others and lists each run's command and
wall time; ``--from-json`` re-renders the markdown and chart of a saved map without simulating.

Writes ``experiments/results/stability_map.{json,md,png}`` (``_quick`` in quick mode: the
InvertedDoublePendulum, the asset's timestep and 4 dt x 1 and 8 iterations, 4 episodes x 50
steps): the PNG a heatmap per env (x timestep, y iterations, colour = fraction diverged, the
guard's fraction printed, the shipped setting boxed), the MD a table per env and, per env, the
smallest timestep with any divergence and the smallest the guard flags at the shipped
iterations.
"""

from __future__ import annotations

import argparse
import pathlib
import statistics
import textwrap
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import fastrl
from experiments import results
from experiments.shipped import shipped_setting
from fastrl import envs
from fastrl.envs.base import ASSETS
from fastrl.physics import step
from fastrl.physics.forward import has_constraints

ENVS = ("ant", "halfcheetah", "hopper", "walker2d", "humanoid", "humanoidstandup", "pusher",
        "swimmer", "reacher", "inverted_pendulum", "inverted_double_pendulum")  # fmt: skip
QUICK_ENV = "inverted_double_pendulum"
ITERATIONS = (1, 2, 3, 5, 8, 16)
# Episodes per cell; the Humanoid's physics step costs ~35x the Ant's, so it gets fewer.
EPISODES = {"default": 64, "humanoid": 16, "humanoidstandup": 16}
STEPS = 1000
PENETRATION_BOUND = 0.1  # m: a contact deeper than this counts as a divergence (see the docstring)
QVEL_BOUND = 1e3  # m/s or rad/s: any |qvel| beyond this counts as a blow-up
SEED = 0


# ---------------------------------------------------------------- the problem of one env


def columns(dt: float, frame_skip: int, quick: bool = False) -> list[dict]:
    """The timestep axis. Up to the control step ``dt``: timestep dt / n with n substeps per
    control step, n in {2 fs, fs, fs // 2, 2, 1}. Past it (frame_skip cannot drop below 1): 2 dt
    and 4 dt with one physics step per control step, which then lasts the timestep. Quick: the
    asset's timestep (x fs) and 4 dt."""
    if quick:
        within, beyond = [frame_skip], [4]
    else:
        within, beyond = (
            sorted({2 * frame_skip, frame_skip, max(1, frame_skip // 2), 2, 1}, reverse=True),
            [2, 4],
        )
    cols = [{"timestep": dt / n, "substeps": n, "control_step": dt} for n in within]
    return cols + [{"timestep": k * dt, "substeps": 1, "control_step": k * dt} for k in beyond]


def env_task(name: str) -> dict:
    """The env's control step, frame_skip, asset timestep and shipped physics setting."""
    env = envs.make(name, terminate_when_unhealthy=False)
    mj = mujoco.MjModel.from_xml_path(str(ASSETS / env.asset))
    dt = mj.opt.timestep * env.frame_skip  # env.dt without its float32 rounding
    return {
        "name": name, "dt": dt, "frame_skip": env.frame_skip, "asset_timestep": mj.opt.timestep,
        "constrained": has_constraints(env.model), "shipped": shipped_setting(name, dt),
    }  # fmt: skip


def is_shipped(row: dict, shipped: dict) -> bool:
    return not row["beyond_dt"] and all(row[k] == v for k, v in shipped.items())


def remark_shipped(name: str, res: dict) -> None:
    """Marks a saved map's shipped cells and limits from today's configs (a shipped iteration count
    may have changed since the map was measured)."""
    res["shipped"] = shipped_setting(name, res["dt"])
    for r in res["rows"]:
        r["shipped"] = is_shipped(r, res["shipped"])
    res["limits"] = limits(res, res["rows"])


def cell_program(name: str, integrator: str, iterations: int, episodes: int, steps: int):
    """Jitted ``(timestep, substeps) -> per control step flags (steps, episodes) x 3, deepest
    contact distance and largest |qvel| (episodes,)``; one program serves every timestep."""
    env = envs.make(name, terminate_when_unhealthy=False, integrator=integrator, solver_iterations=iterations)
    m = env.model
    lo, hi = (jnp.asarray(b) for b in env.action_bounds)
    keys = jax.vmap(jax.random.fold_in, (None, 0))(jax.random.PRNGKey(SEED), jnp.arange(episodes))
    ctrl_key = jax.random.PRNGKey(SEED + 1)
    has_contacts = m.npair > 0

    def run(timestep, substeps):
        mt = m.replace(timestep=timestep)
        d0 = jax.vmap(env.reset)(keys).data
        big = jnp.full((episodes,), jnp.inf, d0.qvel.dtype)

        def substep(_, carry):
            d, dist, vel = carry
            d = jax.vmap(lambda d: step(mt, d))(d)
            if has_contacts:  # the contact distances of the state this substep started from
                dist = jnp.minimum(dist, jnp.min(d.contact_dist, axis=-1))
            vel = jnp.maximum(vel, jnp.max(jnp.abs(d.qvel), axis=-1))
            return d, dist, vel

        def control_step(carry, t):
            d, dist, vel = carry
            u = jax.random.uniform(jax.random.fold_in(ctrl_key, t), (episodes, m.nu), lo.dtype, lo, hi)
            d, dist_t, vel_t = jax.lax.fori_loop(0, substeps, substep, (d.replace(ctrl=u), big, -big))
            flags = (d.diverged, dist_t < -PENETRATION_BOUND, vel_t > QVEL_BOUND)
            # Running extremes over finite values only (a diverged state turns to NaN).
            dist = jnp.where(jnp.isfinite(dist_t), jnp.minimum(dist, dist_t), dist)
            vel = jnp.where(jnp.isfinite(vel_t), jnp.maximum(vel, vel_t), vel)
            return (d, dist, vel), flags

        (_, dist, vel), flags = jax.lax.scan(control_step, (d0, big, jnp.zeros_like(big)), jnp.arange(steps))
        return flags, dist, vel

    return jax.jit(run)


def _first_steps(flags: np.ndarray) -> list[int]:
    """1-based first flagged control step of every episode flagged at all; flags (steps, episodes)."""
    hit = flags.any(axis=0)
    return (np.argmax(flags, axis=0)[hit] + 1).tolist()


def _median(values: list[int]) -> float | None:
    return float(statistics.median(values)) if values else None


def summarize(flags, dist, vel) -> dict:
    """Fractions diverged (any and each criterion), median first control steps, extremes."""
    guard, pen, fast = (np.asarray(f) for f in flags)  # (steps, episodes)
    any_ = guard | pen | fast
    dist = np.asarray(dist)
    return {
        "diverged": float(any_.any(axis=0).mean()), "guard": float(guard.any(axis=0).mean()),
        "penetration": float(pen.any(axis=0).mean()), "velocity": float(fast.any(axis=0).mean()),
        "median_first_step": _median(_first_steps(any_)),
        "median_first_guard_step": _median(_first_steps(guard)),
        "deepest_penetration": float(-dist.min()) if np.isfinite(dist.min()) else None,
        "max_qvel": float(np.asarray(vel).max()),
    }  # fmt: skip


def map_env(task: dict, plan: dict) -> dict:
    """Every cell of one env: one compiled program per (integrator, iterations)."""
    name, rows = task["name"], []
    iterations = plan["iterations"] if task["constrained"] else [task["shipped"]["solver_iterations"]]
    cols = columns(task["dt"], task["frame_skip"], plan["quick"])
    integrators = plan["integrators"] or [task["shipped"]["integrator"]]
    for integrator in integrators:
        for iters in iterations:
            t0 = time.perf_counter()
            program = cell_program(name, integrator, iters, plan["episodes"], plan["steps"])
            program = program.lower(jnp.float32(task["dt"]), jnp.int32(1)).compile()
            compile_s = time.perf_counter() - t0
            for col in cols:
                t0 = time.perf_counter()
                out = program(jnp.float32(col["timestep"]), jnp.int32(col["substeps"]))
                out = jax.block_until_ready(out)
                wall = time.perf_counter() - t0
                row = {"integrator": integrator, "solver_iterations": iters, **col,
                       "beyond_dt": col["control_step"] > task["dt"], **summarize(*out),
                       "wall_s": wall, "compile_s": compile_s}  # fmt: skip
                row["shipped"] = is_shipped(row, task["shipped"])
                rows.append(row)
                print(f"  {name} {integrator} {row['timestep']:.4g} s x{row['substeps']}, {iters} iters: "
                      f"{row['diverged']:.0%} diverged (guard {row['guard']:.0%}, penetration "
                      f"{row['penetration']:.0%}, |qvel| {row['velocity']:.0%}) in {wall:.1f} s "
                      f"(compiled in {compile_s:.0f} s)", flush=True)  # fmt: skip
    return {**task, "episodes": plan["episodes"], "steps": plan["steps"], "rows": rows,
            "limits": limits(task, rows)}  # fmt: skip


def limits(task: dict, rows: list[dict]) -> dict:
    """Per integrator, at the shipped iterations: the smallest timestep with any divergence and
    the smallest one the guard flags (None: none on the grid). A shipped count the grid lacks is
    judged at the grid's next smaller count (``iterations`` says which), fewer iterations being
    the less stable side."""
    shipped = task["shipped"]["solver_iterations"]
    out = {}
    for integrator in sorted({r["integrator"] for r in rows}):
        counts = sorted({r["solver_iterations"] for r in rows if r["integrator"] == integrator})
        iters = max((c for c in counts if c <= shipped), default=counts[0])
        mine = [r for r in rows if r["integrator"] == integrator and r["solver_iterations"] == iters]
        out[integrator] = {
            key: min((r["timestep"] for r in mine if r[key] > 0), default=None)
            for key in ("diverged", "guard")
        }
        out[integrator]["iterations"] = iters
    return out


# ---------------------------------------------------------------- outputs


def _tick(res: dict, r: dict) -> str:
    if r["beyond_dt"]:
        return f"{r['timestep']:.3g}\n({r['control_step'] / res['dt']:g} dt, x1)"
    return f"{r['timestep']:.3g}\n(x{r['substeps']})"


def chart(maps: dict):
    """One panel per env and integrator: the grid of diverged fractions, the shipped cell boxed."""
    plt = results.pyplot()
    from matplotlib.patches import Rectangle

    panels = [(name, integ) for name, res in maps.items()
              for integ in sorted({r["integrator"] for r in res["rows"]})]  # fmt: skip
    cols = min(len(panels), 3)
    nrows = -(-len(panels) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(5.0 * cols, 4.0 * nrows + 0.6), squeeze=False)
    image = None
    for ax, (name, integ) in zip(axes.flat, panels, strict=False):
        res = maps[name]
        rows = [r for r in res["rows"] if r["integrator"] == integ]
        ts = sorted({r["timestep"] for r in rows})
        its = sorted({r["solver_iterations"] for r in rows})
        grid = np.full((len(its), len(ts)), np.nan)
        guard = np.zeros_like(grid)
        for r in rows:
            i, j = its.index(r["solver_iterations"]), ts.index(r["timestep"])
            grid[i, j], guard[i, j] = r["diverged"], r["guard"]
        image = ax.imshow(grid, origin="lower", cmap="Reds", vmin=0, vmax=1, aspect="auto")
        for (i, j), v in np.ndenumerate(grid):
            if np.isfinite(v):
                text = f"{v:.0%}" + (f"\ng {guard[i, j]:.0%}" if guard[i, j] else "")
                ax.text(j, i, text, ha="center", va="center", fontsize=6.5,
                        color="white" if v > 0.6 else "black")  # fmt: skip
        for r in rows:
            if r["shipped"]:
                j, i = ts.index(r["timestep"]), its.index(r["solver_iterations"])
                ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, ec="tab:blue", lw=2.5))
        beyond = [ts.index(r["timestep"]) for r in rows if r["beyond_dt"]]
        if beyond:
            ax.axvline(min(beyond) - 0.5, color="black", ls="--", lw=1)
        ticks = {r["timestep"]: _tick(res, r) for r in rows}
        ax.set_xticks(range(len(ts)), [ticks[t] for t in ts], fontsize=6.5)
        ax.set_yticks(range(len(its)), [str(i) for i in its], fontsize=7)
        ax.set_xlabel("timestep, s (substeps per control step)", fontsize=8)
        ax.set_ylabel("solver iterations", fontsize=8)
        ax.set_title(
            f"{name} ({integ}), dt {res['dt']:.3g} s, {res['episodes']} x {res['steps']} steps", fontsize=9
        )
    for ax in list(axes.flat)[len(panels) :]:
        ax.axis("off")
    title = (
        "Fraction of random-action episodes that diverge (g: flagged by the guard). Divergence: guard, "
        f"penetration > {PENETRATION_BOUND:g} m or |qvel| > {QVEL_BOUND:g}. Blue box: shipped setting; "
        "right of the dashed line the timestep exceeds the control step dt (one physics step per "
        "control step)."
    )
    fig.suptitle(textwrap.fill(title, 55 * cols), fontsize=9)
    fig.tight_layout(rect=(0, 0, 0.9, 1))
    if image is not None:
        fig.colorbar(image, ax=axes.ravel().tolist(), shrink=0.6, label="fraction diverged")
    return fig


def _pct(x: float) -> str:
    return f"{x:.0%}" if x in (0.0, 1.0) or x >= 0.01 else f"{x:.1%}"


def _where(res: dict, ts: float | None) -> str:
    if ts is None:
        return "none on the grid"
    return f"{ts:.3g} s" + (
        f" ({ts / res['dt']:g} dt)" if ts > res["dt"] * (1 + 1e-9) else f" (x{round(res['dt'] / ts)})"
    )


def _runs_line(runs: list[dict]) -> str:
    """The command(s) that made the map, each with its wall time (merged runs are listed in turn)."""
    done = [f"`{r['command']}` ({r['wall_s'] / 60:.0f} min)" for r in runs]
    return ("Command: " if len(done) == 1 else "Commands, merged in turn: ") + "; ".join(done) + "."


def markdown(maps: dict, machine: str, runs: list[dict]) -> str:
    lines = ["# Stability map: timestep x solver iterations", "",
             f"Machine: {machine}. {_runs_line(runs)}", "",
             "Each cell: episodes of random actions (uniform in the action bounds, one per control "
             "step, held over its substeps) from the env's reset, no task termination, the control "
             "step `dt` fixed (timestep = dt / substeps; the columns past dt take one physics step "
             "per control step, which then lasts the timestep). An episode diverges at the first "
             "control step where the guard flags it (`Data.diverged`: non-finite or |state| > 1e10), "
             f"a contact penetrates deeper than {PENETRATION_BOUND:g} m, or any |qvel| exceeds "
             f"{QVEL_BOUND:g}. Columns: the fraction diverged, by any criterion and by each; the "
             "median first control step of divergence (any criterion, and the guard's) among the "
             "episodes concerned; the deepest finite penetration (m) and the largest finite |qvel|.",
             ""]  # fmt: skip
    lines += ["## Limits at the shipped iterations", "",
              "The smallest timestep on the grid with any divergence, and the smallest the guard flags.", "",
              "| env | dt (s) | shipped | integrator | first divergence | first guard flag |",
              "| --- | ---: | --- | --- | ---: | ---: |"]  # fmt: skip
    for name, res in maps.items():
        s = res["shipped"]
        ship = f"{s['integrator']}, {res['dt'] / s['substeps']:.3g} s x{s['substeps']}, "
        ship += f"{s['solver_iterations']} iters"
        for integ, lim in res["limits"].items():
            at = lim.get("iterations", s["solver_iterations"])
            judged = "" if at == s["solver_iterations"] else f" (not on the grid: at {at} iters)"
            if s["integrator"] not in res["limits"]:  # e.g. an env since shipped with another integrator
                judged = f" (not on the grid: {s['integrator']} not mapped)"
            lines.append(f"| {name} | {res['dt']:.3g} | {ship}{judged} | {integ} "
                         f"| {_where(res, lim['diverged'])} | {_where(res, lim['guard'])} |")  # fmt: skip
    lines.append("")
    for name, res in maps.items():
        s = res["shipped"]
        lines += [f"## {name}", "",
                  f"Control step {res['dt']:.3g} s (asset timestep {res['asset_timestep']:g} x "
                  f"{res['frame_skip']}), {res['episodes']} episodes x {res['steps']} control steps "
                  f"per cell. Shipped: {s['integrator']} x{s['substeps']}, {s['solver_iterations']} "
                  "iterations.", "",
                  "| integrator | timestep (s) | substeps | control step (s) | iters | diverged | guard "
                  "| penetration | \\|qvel\\| | median first step (guard) | deepest pen. (m) "
                  "| max \\|qvel\\| | shipped |",
                  "| --- " + "| ---: " * 11 + "| :---: |"]  # fmt: skip
        for r in res["rows"]:
            first = f"{r['median_first_step']:g}" if r["median_first_step"] is not None else ""
            if r["median_first_guard_step"] is not None:
                first += f" ({r['median_first_guard_step']:g})"
            deep = f"{r['deepest_penetration']:.3g}" if r["deepest_penetration"] is not None else ""
            lines.append(
                f"| {r['integrator']} | {r['timestep']:.4g} | {r['substeps']} | {r['control_step']:.3g} "
                f"| {r['solver_iterations']} | {_pct(r['diverged'])} | {_pct(r['guard'])} "
                f"| {_pct(r['penetration'])} | {_pct(r['velocity'])} | {first} | {deep} "
                f"| {r['max_qvel']:.3g} | {'**shipped**' if r['shipped'] else ''} |"
            )
        lines.append("")
    return "\n".join(lines)


def _ordered(maps: dict) -> dict:
    order = [*ENVS, *sorted(set(maps) - set(ENVS))]
    return {name: maps[name] for name in order if name in maps}


def _runs(saved: dict) -> list[dict]:
    """The runs a saved map came from (older files hold one command and its total wall time)."""
    return saved.get("runs") or [
        {"command": saved["command"], "wall_s": saved["wall_s"], "envs": list(saved["envs"])}
    ]


def rerender(path: pathlib.Path, out: pathlib.Path) -> None:
    """``--from-json``: marks a saved map's shipped cells from today's configs, rewrites the JSON in
    place and the page and chart in ``out``."""
    saved = results.load(path)
    maps = _ordered(saved["envs"])
    for name, res in maps.items():
        remark_shipped(name, res)
    kept_order = {name: maps[name] for name in saved["envs"]}  # a small diff
    results.save(path.parent, path.stem, {**saved, "envs": kept_order})
    results.save(out, path.stem, None, markdown(maps, saved["machine"], _runs(saved)), chart(maps))


def cell_plan(name: str, task: dict, args) -> dict:
    """What one env's map runs: its solver iterations, integrators, episodes and steps."""
    iterations = sorted({1, task["shipped"]["solver_iterations"]}) if args.quick else list(ITERATIONS)
    episodes = args.episodes or (4 if args.quick else EPISODES.get(name, EPISODES["default"]))
    return {"quick": args.quick, "iterations": iterations, "integrators": args.integrators,
            "episodes": episodes, "steps": args.steps or (50 if args.quick else STEPS)}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1 env, 2x2 grid, 4 x 50 steps, for CI")
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS)
    parser.add_argument("--envs", nargs="+", choices=envs.names(), default=None)
    parser.add_argument("--integrators", nargs="+", choices=("euler", "rk4"), default=None,
                        help="default: each env's shipped integrator")  # fmt: skip
    parser.add_argument("--episodes", type=int, default=None, help="per cell (default: EPISODES)")
    parser.add_argument("--steps", type=int, default=None, help=f"control steps per episode ({STEPS})")
    parser.add_argument("--merge", action="store_true", help="keep the other envs already in the output JSON")
    parser.add_argument("--from-json", type=pathlib.Path,
                        help="re-render a saved map, shipped cells marked from today's configs")  # fmt: skip
    args = parser.parse_args()
    if args.from_json:
        return rerender(args.from_json, args.out)
    names = args.envs or ([QUICK_ENV] if args.quick else list(ENVS))
    stem = "stability_map_quick" if args.quick else "stability_map"
    maps, runs = {}, []
    if args.merge and (args.out / f"{stem}.json").exists():
        old = results.load(args.out / f"{stem}.json")
        maps = {k: v for k, v in old["envs"].items() if k not in names}
        runs = _runs(old) if maps else []
        print(f"keeping {', '.join(maps) or 'no envs'} from {args.out / f'{stem}.json'}")
    t0 = time.perf_counter()
    for name in names:
        task = env_task(name)
        maps[name] = map_env(task, cell_plan(name, task, args))
    wall = time.perf_counter() - t0
    maps = _ordered(maps)

    machine = results.machine()
    command = "python -m experiments.stability_map" + (" --quick" if args.quick else "")
    if args.envs:
        command += " --envs " + " ".join(args.envs) + (" --merge" if args.merge else "")
    runs = [*runs, {"command": command, "wall_s": wall, "envs": names}]
    payload = {"machine": machine, "runs": runs, "penetration_bound": PENETRATION_BOUND,
               "qvel_bound": QVEL_BOUND, "envs": maps}  # fmt: skip
    text = markdown(maps, machine, runs)
    results.save(args.out, stem, payload, text, chart(maps))
    print(text)


if __name__ == "__main__":
    fastrl.use_recommended_xla_flags()  # the XLA:CPU flags fastrl's command line runs with
    main()
