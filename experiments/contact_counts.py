"""How many contacts each robot scene makes at once in MuJoCo C, beside fastrl's contact slots.

    python -m experiments.contact_counts                  # all 41 scenes (~2 min)
    python -m experiments.contact_counts --scenes 'menagerie/franka_emika_panda/scene$'
    python -m experiments.contact_counts --quick          # Go1 standing, one short run (CI)

For each scene of the EnvPool asset wheels (``fastrl.envs.robots.assets.scene_paths``), MuJoCo C
runs ``--runs`` episodes of ``--steps`` steps from the first keyframe (or ``qpos0``) under uniform
random controls within the actuators' ranges, each held for 10 steps, and records the most
contacts within their margin at once (``mjData.contact.dist < includemargin``). A run that
blows up (MuJoCo's bad-acceleration warning, after which it resets the state) stops there and
is counted. Beside it: fastrl's candidate contacts
and contact slots (``Model.nconmax``) as ``load_mjcf`` builds the scene, the evidence for
``constraint.default_nconmax``'s cap.

Writes ``experiments/results/contact_counts.{json,md}``.
"""

from __future__ import annotations

import argparse
import re

import mujoco
import numpy as np

from experiments import results
from fastrl import physics
from fastrl.envs.robots import assets
from fastrl.physics import collision_driver

QUICK_SCENE = "playground/locomotion/go1/scene_mjx_feetonly_flat_terrain"  # four feet, four candidates


def most_contacts(mj: mujoco.MjModel, runs: int, steps: int, seed: int = 0) -> tuple[int, int]:
    """The most contacts within their margin at once over the runs, and how many runs blew up."""
    rng = np.random.default_rng(seed)
    limited = mj.actuator_ctrllimited.astype(bool)
    most = unstable = 0
    for _ in range(runs):
        d = mujoco.MjData(mj)
        if mj.nkey:
            mujoco.mj_resetDataKeyframe(mj, d, 0)
        for t in range(steps):
            if t % 10 == 0:
                u = rng.uniform(mj.actuator_ctrlrange[:, 0], mj.actuator_ctrlrange[:, 1])
                d.ctrl[:] = np.where(limited, u, d.ctrl)
            mujoco.mj_step(mj, d)
            # MuJoCo resets a diverging state to the model's reference pose and warns
            if d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number or not np.isfinite(d.qpos).all():
                unstable += 1
                break
            c = d.contact[: d.ncon]
            most = max(most, int(np.sum(c.dist < c.includemargin)) if d.ncon else 0)
    return most, unstable


def measure(names: list[str], runs: int, steps: int) -> list[dict]:
    paths = assets.scene_paths()
    rows = []
    for name in names:
        mj = mujoco.MjModel.from_xml_path(str(paths[name]))
        m = physics.load_mjcf(str(paths[name]))
        most, unstable = most_contacts(mj, runs, steps)
        rows.append({"scene": name, "most_contacts": most, "unstable_runs": unstable, "slots": int(m.nconmax),
                     "candidates": int(collision_driver.contact_layout(m).size)})  # fmt: skip
        print(f"{name}: at most {most} contacts ({unstable} runs blew up), {m.nconmax} slots", flush=True)
    return rows


def markdown(rows: list[dict], runs: int, steps: int) -> str:
    head = [
        "# Contacts at once in MuJoCo C, beside fastrl's contact slots", "",
        f"{results.today()}, {results.machine()}. Command: `{results.command()}`. MuJoCo C, {runs} runs of "
        f"{steps} steps per scene from the first keyframe under random controls held 10 steps each; "
        "`most`: the most contacts within their margin at once; `blew up`: runs stopped at a "
        "state that MuJoCo found diverging. `slots`: fastrl's contact slots as `load_mjcf` builds the scene "
        "(`constraint.default_nconmax` unless the scene sets them), `candidates`: its candidate "
        "contacts.", "",
    ]  # fmt: skip
    cells = [(r["scene"], r["most_contacts"], r["unstable_runs"], r["slots"], r["candidates"]) for r in rows]
    return "\n".join(head) + "\n" + results.table(["scene", "most", "blew up", "slots", "candidates"], cells)


def main() -> None:
    raw = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=raw)
    parser.add_argument("--scenes", nargs="*", help="only scenes whose name matches one of these regexes")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--out", default=str(results.RESULTS))
    parser.add_argument("--quick", action="store_true", help=f"{QUICK_SCENE} alone, 1 run of 100 steps")
    args = parser.parse_args()
    if args.quick:
        args.scenes, args.runs, args.steps = [QUICK_SCENE + "$"], 1, 100
    names = sorted(assets.scene_paths())
    if args.scenes:
        names = [n for n in names if any(re.search(p, n) for p in args.scenes)]
        if not names:
            parser.error(f"no scene matches {args.scenes}")
    rows = measure(names, args.runs, args.steps)
    record = {"meta": {"machine": results.machine(), "command": results.command(), "runs": args.runs,
                       "steps": args.steps}, "rows": rows}  # fmt: skip
    results.save(args.out, "contact_counts", record, markdown(rows, args.runs, args.steps))


if __name__ == "__main__":
    main()
