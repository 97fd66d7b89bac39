"""How closely can any float32 simulation follow MuJoCo C (float64) on the robot scenes?

    python -m experiments.float32_floor            # every loading scene with a free root (~2 min)
    python -m experiments.float32_floor --scenes g1 apollo
    python -m experiments.float32_floor --quick --out DIR    # one scene, 0.05 s, for CI

``experiments.robot_coverage`` asks fastrl's float32 root to stay within 1 cm of MuJoCo C's over 2 s from
the first keyframe with its ``ctrl`` held. This script measures, with MuJoCo C alone (float64
throughout), what that bar asks of float32 on each scene, so that a miss can be told apart from
an engine error:

    per step   the state (qpos, qvel, warm start) rounded to float32 before every step: the
               rounding a float32 state pays, with float64 arithmetic everywhere else
    once       the state rounded to float32 once, at one time t0, and never again; reported is
               the worst t0 of ``--starts`` evenly spaced ones, with that t0
    1e-9       instead of the rounding, qvel perturbed once by 1e-9 (normal, per dof) at each t0:
               a perturbation 100x below float32's resolution of the state
    mixed      the best case of a mixed-precision design (float64 state, float32 dynamics): the
               state is held and integrated in float64, and each step's forces and accelerations
               are computed at the state rounded to float32 (in float64 arithmetic, so smaller
               than any float32 evaluation's errors). Where it passes 1 cm, keeping the state in
               higher precision alone would not hold a float32 engine to the bar

Each column is the root's largest distance (mm) from the unperturbed trajectory over the
horizon. Where ``once`` passes 1 cm, float32's resolution of the state at that instant alone
parts the trajectories by more than the bar, whatever the arithmetic after it. The growth
factor (``once`` over the 1e-7 relative size of the rounding) tells an unstable motion
(a robot toppling from a held pose: a 1e-9 kick grows too) from a discrete event (a contact
that begins one step earlier or later, a solver exit decided by a tolerance: the 1e-9 kick
stays small while the float32 rounding flips it).

Writes ``experiments/results/float32_floor.{md,json}``.
"""

from __future__ import annotations

import argparse
import pathlib

import mujoco
import numpy as np

from experiments import results
from fastrl.envs.robots import assets

BAR_MM = 10.0


def _initial(mj: mujoco.MjModel) -> mujoco.MjData:
    d = mujoco.MjData(mj)
    if mj.nkey:
        mujoco.mj_resetDataKeyframe(mj, d, 0)
    else:
        mujoco.mj_forward(mj, d)
    return d


def _root(mj: mujoco.MjModel) -> np.ndarray | None:
    free = np.flatnonzero(mj.jnt_type == mujoco.mjtJoint.mjJNT_FREE)
    return None if not free.size else mj.jnt_qposadr[free[0]] + np.arange(3)


def _round(d: mujoco.MjData) -> None:
    for x in (d.qpos, d.qvel, d.qacc_warmstart):
        x[:] = x.astype(np.float32)


def _mixed_step(mj: mujoco.MjModel, d: mujoco.MjData) -> None:
    """One step whose forces see the state rounded to float32 while the state itself is
    integrated in float64: ``mj_step1`` (positions, velocities) and ``mj_step2`` (actuation,
    acceleration, integration) split mj_step; after it the velocity's increment is added to the
    unrounded velocity and the unrounded position advances with it (Euler and implicitfast both
    integrate positions with the new velocity)."""
    if mj.opt.integrator not in (mujoco.mjtIntegrator.mjINT_EULER, mujoco.mjtIntegrator.mjINT_IMPLICITFAST):
        raise ValueError(f"mixed precision is measured for Euler and implicitfast, not {mj.opt.integrator}")
    q, v = d.qpos.copy(), d.qvel.copy()
    _round(d)
    rounded_v = d.qvel.copy()
    mujoco.mj_step1(mj, d)
    mujoco.mj_step2(mj, d)
    d.qvel[:] += v - rounded_v
    d.qpos[:] = q
    mujoco.mj_integratePos(mj, d.qpos, d.qvel, mj.opt.timestep)


def scene(mj: mujoco.MjModel, seconds: float, starts: int) -> dict | None:
    """The three drifts (mm) of one scene, or None without a free root."""
    root = _root(mj)
    if root is None:
        return None
    steps = int(round(seconds / mj.opt.timestep))
    d = _initial(mj)
    saved, ref, ncon = [], np.empty((steps, 3)), np.empty(steps, int)
    for t in range(steps):
        saved.append((d.qpos.copy(), d.qvel.copy(), d.qacc_warmstart.copy(), d.time))
        mujoco.mj_step(mj, d)
        ref[t], ncon[t] = d.qpos[root], d.ncon
    ctrl = d.ctrl.copy()

    def drift(t0: int, perturb, every_step: bool = False, step=mujoco.mj_step) -> float:
        """The root's largest distance (mm) from ``ref`` after ``perturb`` at step t0 (and
        before every later step too with ``every_step``), stepping with ``step``."""
        e = mujoco.MjData(mj)
        e.ctrl[:] = ctrl
        e.qpos[:], e.qvel[:], e.qacc_warmstart[:], e.time = saved[t0]
        worst = 0.0
        for t in range(t0, steps):
            if every_step or t == t0:
                perturb(e)
            step(mj, e)
            worst = max(worst, float(np.linalg.norm(e.qpos[root] - ref[t])))
        return 1e3 * worst

    rng = np.random.default_rng(0)
    t0s = np.linspace(0, steps - 1, starts, dtype=int)
    once = [drift(t0, _round) for t0 in t0s]
    kick = [drift(t0, lambda e: e.qvel.__iadd__(1e-9 * rng.standard_normal(mj.nv))) for t0 in t0s]
    worst = int(np.argmax(once))
    return {
        "steps": steps,
        "root_z_start": float(ref[0, 2]),
        "root_z_min": float(ref[:, 2].min()),
        "contacts_min_max": [int(ncon.min()), int(ncon.max())],
        "per_step_mm": drift(0, _round, every_step=True),
        "once_mm": once[worst],
        "once_t0_s": float(t0s[worst] * mj.opt.timestep),
        "kick_mm": max(kick),
        "mixed_mm": drift(0, lambda e: None, step=_mixed_step),
    }


def markdown(rows: dict, meta: dict) -> str:
    each = [n for n, r in rows.items() if r["per_step_mm"] > BAR_MM]
    once = [n for n, r in rows.items() if r["once_mm"] > BAR_MM]
    floor = sorted(set(each) | set(once))
    mixed = [n for n in floor if rows[n]["mixed_mm"] > BAR_MM]
    out = [
        "# The float32 floor: how far float32 rounding alone moves MuJoCo C's robot roots",
        "",
        f"{meta['date']}, {meta['machine']}; MuJoCo {meta['mujoco']}. Command: `{meta['command']}`.",
        "",
        f"- **{len(rows)} scenes with a free root. In {len(each)}, MuJoCo C with its state rounded to "
        f"float32 before every step parts from its own float64 trajectory by more than {BAR_MM:g} mm "
        f"within {meta['seconds']:g} s; in {len(once)}, one rounding at one instant does.** A float32 "
        "simulation holds its state in float32 every step, so in these scenes no float32 engine can "
        "be held to 1 cm of MuJoCo C's float64 trajectory: " + ", ".join(f"`{n}`" for n in floor) + ".",
        f"- **A float64 state does not lift that floor in {len(mixed)} of these {len(floor)}.** "
        "*mixed* is the best case of a mixed-precision design: the state held and integrated in "
        "float64, each step's dynamics evaluated at the state rounded to float32 (in float64 "
        "arithmetic, so with less error than any float32 evaluation). Over 1 cm in: "
        + (", ".join(f"`{n}`" for n in mixed) or "none")
        + ".",
        "- Columns: root distance (mm) from the unperturbed float64 trajectory, largest over the "
        "horizon. *per step*: state rounded to float32 before every step. *once*: rounded once, at "
        "the worst of the start times (t0 in s). *1e-9*: qvel kicked once by 1e-9 instead, worst "
        "start time. z: the root's height at the start and its lowest (a humanoid whose keyframe "
        "pose is held without a controller falls; the feet-only scenes let the body sink through "
        "the floor). Contacts: fewest and most active contacts over the horizon. *mixed*: from the "
        "start, as above.",
        "",
        "| scene | steps | root z start / min (m) | contacts | per step (mm) | once (mm) | once t0 (s) "
        "| 1e-9 (mm) | mixed (mm) |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for name, r in rows.items():
        lo, hi = r["contacts_min_max"]
        out.append(
            f"| `{name}` | {r['steps']} | {r['root_z_start']:.2f} / {r['root_z_min']:.2f} | {lo}-{hi} | "
            f"{r['per_step_mm']:.3g} | {r['once_mm']:.3g} | {r['once_t0_s']:.2f} | {r['kick_mm']:.2g} | "
            f"{r['mixed_mm']:.3g} |"
        )
    return "\n".join(out) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="*", help="only scenes whose name contains one of these")
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--starts", type=int, default=40, help="start times of the one-off perturbations")
    parser.add_argument("--quick", action="store_true", help="one scene, 0.05 s, 2 start times (CI)")
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS)
    args = parser.parse_args()
    if args.quick:
        args.scenes, args.seconds, args.starts = ["go1/scene_mjx_feetonly_flat"], 0.05, 2
    from fastrl import physics  # which scenes fastrl loads (the ones the 1 cm bar applies to)

    rows = {}
    for name, path in assets.scene_paths().items():
        if args.scenes and not any(k in name for k in args.scenes):
            continue
        mj = mujoco.MjModel.from_xml_path(str(path))
        try:
            physics.model_from_mujoco(mj)
        except physics.UnsupportedFeatureError:
            continue
        row = scene(mj, args.seconds, args.starts)
        if row is not None:
            rows[name] = row
            print(f"{name}: {row}", flush=True)
    meta = {
        "date": results.today(),
        "machine": results.machine(),
        "mujoco": mujoco.__version__,
        "seconds": args.seconds,
        "command": results.command(),
    }
    stem = "float32_floor_quick" if args.quick else "float32_floor"
    results.save(args.out, stem, {"meta": meta, "scenes": rows}, markdown(rows, meta))


if __name__ == "__main__":
    main()
