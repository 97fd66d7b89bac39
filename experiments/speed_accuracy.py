"""Speed vs accuracy of fastrl's physics knobs on six models, with MuJoCo C on the same axes.

    python -m experiments.speed_accuracy                         # all six models, ~1 h on 2 cores
    python -m experiments.speed_accuracy --models ant hopper     # a subset
    python -m experiments.speed_accuracy --models ant --merge    # add to the committed models
    python -m experiments.speed_accuracy --quick                 # tiny, for CI
    python -m experiments.speed_accuracy --brax-only             # re-measure Brax's points only
    python -m experiments.speed_accuracy --from-json             # re-mark the shipped settings

Models: the Ant, HalfCheetah, Hopper, Humanoid and HumanoidStandup (the Humanoid's model lying on
its back; contacts) and the InvertedDoublePendulum (no contacts; its cart's joint limit, its only
constraint, is not reached within its horizon). Each keeps its env's control step ``dt``
(frame_skip x the asset's timestep) across all settings, and every setting simulates the same
sequences: start states from the env's ``reset`` with fixed keys, and uniform random controls in
the actuators' ctrlrange, one per control step, held over its substeps.

Swept: fastrl's integrator (euler, rk4) x timestep (dt / substeps, substeps 1, 2, 4, frame_skip
and twice it) x constraint-solver iterations (2, 3, 5, 8; the loader default only for the
contact-free model), in float32, its default, with the env's own line search (``Env.linesearch``:
exact line searches for these models, so the rows time the solver their envs train with; runs
before 2026-11-28 took the loader's default, MuJoCo's line search, and their tables say so); and
MuJoCo C at the same timesteps with the asset's
own integrator and solver options.

Accuracy: error against a converged reference, MuJoCo C in float64 at 1/20 of the asset's
timestep, Newton's solver with 100 iterations and tolerance 1e-12 (line search: 100, 1e-10), RK4
for the contact-free model and the asset's integrator otherwise (RK4, but Euler for the
HalfCheetah; the Humanoid asset's PGS solver gives way to Newton, which reaches the same converged
solution). The error is the RMS over control steps and sequences of the distance between the
root body's world position (body 1, the torso) and the reference's; for the fixed-base pendulum,
whose root never moves, it is the RMS norm of the whole qpos difference (cart metres and hinge
radians together). The same reference at 1/40 of the timestep gives the "floor", the error
between two converged solutions. Contact-rich rollouts under random controls are chaotic: a
finer reference lowers that floor slowly, and over longer horizons not at all (on the Ant, 1/160
against 1/320 of the timestep disagree a sixth as much as 1/20 against 1/320 at 0.25 s, nearly as
much at 1 s), so each model's horizon (``HORIZON_S``) is kept short enough for the floor to sit
an order of magnitude below MuJoCo C's own error at the asset's timestep; it is reported with them.

Speed: control steps/s of the jitted, vmapped control step (a loop of substeps inside) under
``lax.scan`` at batch 1024, after compilation: the median of at least 3 timed calls and 1 s
(a single call once one takes over 3 s). fastrl's work does not depend on the state (a static
number of solver iterations, every contact slot evaluated), so it is timed on one control step of
the batch; MuJoCo C's does, so ``mujoco.rollout`` (2 MjData: 2 threads, persistent pool) is timed
over the whole horizon of the batch, whose first sequences also give its accuracy. The timestep
and the substep count are runtime arguments of one compiled program per (integrator,
iterations), so a model compiles 8 programs (x 2 batch shapes) instead of 40; on the Ant that
program gives bit-identical trajectories and the same speed as one with them baked in.

Brax (where the peer venv exists, ``experiments/peers/setup_peers.sh``): its generalized,
spring and positional backends run the same asset from the same start states
under the same controls (``experiments/peers/brax_speed_accuracy.py``), at the timestep Brax's
env of the same name uses with that backend (e.g. the Ant: 0.01 s x 5 for generalized,
0.005 s x 10 for spring and positional) and Euler integration (Brax's loader takes no other).
Its speed is timed over the whole horizon of the batch, like MuJoCo C's. MJX is left out: it
deadlocked at batch 1024 in this JAX (see ``BRAX_BACKENDS``; ``--brax-backends mjx`` tries it).
``--brax-only`` adds or re-measures Brax's points alone, keeping the other rows of the output
JSON (and its fronts are recomputed with them).

Shipped: the setting ``python -m fastrl.train env=<model>`` trains with, i.e.
``conf/experiment/<model>_ppo.yaml`` over the env's defaults (the Ant: Euler at
0.01 s x 5, 5 iterations; the others: the asset's integrator, timestep and iteration count).
``--from-json`` marks it anew from the current configs in the committed JSON, measuring nothing.

Writes ``experiments/results/speed_accuracy.{md,json,png}``: for each model every setting's
speed and error, whether it is on the Pareto front of all points (no other point, fastrl or
MuJoCo C, is both at least as fast and at least as accurate; errors within 2% plus the floor
count as equal) and on that of fastrl's settings alone (the choice among fastrl's knobs), and
whether it is the shipped one.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import statistics
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import mujoco.rollout
import numpy as np

import fastrl
from experiments import results
from experiments.shipped import shipped_setting
from fastrl import envs, physics
from fastrl.envs.base import ASSETS
from fastrl.runtime.xla_flags import peer_environ

ROOT = results.ROOT
MODELS = ("ant", "halfcheetah", "hopper", "humanoid", "humanoidstandup", "inverted_double_pendulum")
CONTACT_FREE = ("inverted_double_pendulum",)
# Simulated seconds per sequence. Measured on these 16 sequences, the floor against MuJoCo C's own
# error at the asset's timestep (x frame_skip) and half of it (x 2 frame_skip) is, for the Ant,
# 1.5e-3 vs 1.8e-2 and 7e-3 m at 0.3 s (2e-2 vs 7e-2 and 6e-2 at 0.6 s); the HalfCheetah 3e-3 vs
# 1.4e-1 and 3e-2 at 1 s (1.4e-2 vs 3e-1 and 1.1e-1 at 2 s); the Hopper 1.2e-5 vs 1.4e-4 and 9e-5
# at 0.25 s; the Humanoid 1.1e-4 vs 2e-3 and 1e-3 at 0.5 s (2.4e-3 vs 1e-2 and 5e-3 at 1 s);
# HumanoidStandup, lying on the floor, 6.9e-4 vs 3.7e-3 at 0.5 s (5x, not 10x). The pendulum is a
# smooth ODE until its cart reaches the joint limit, which none of 256 sequences does by 0.25 s (4
# by 0.3 s): within 0.2 s its floor is 5e-12 against 9e-7.
HORIZON_S = {
    "ant": 0.3, "halfcheetah": 1.0, "hopper": 0.25, "humanoid": 0.5, "humanoidstandup": 0.5,
    "inverted_double_pendulum": 0.2,
}  # fmt: skip
ITERATIONS = (2, 3, 5, 8)
BATCH = 1024  # speed
SEQUENCES = 16  # accuracy: sequences compared with the reference
PARETO_TOL = 0.02  # errors closer than this (relative) count as equal on the front
REF_DIVISOR = 20  # reference timestep = asset timestep / REF_DIVISOR; the floor's, twice finer
STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS  # time, qpos, qvel, ...: qpos starts at index 1


# ---------------------------------------------------------------- the fixed problem of one model


def make_task(name: str, batch: int, horizon_s: float, seed: int = 0) -> dict:
    """The model's fixed sequences (start states, controls) and its shipped physics setting."""
    env = envs.make(name)
    mj = mujoco.MjModel.from_xml_path(str(ASSETS / env.asset))
    dt = mj.opt.timestep * env.frame_skip  # env.dt, without its float32 rounding
    steps = max(1, round(horizon_s / dt))
    # Sequence i is drawn from its own key, so it does not depend on the batch or the horizon.
    keys = jax.vmap(jax.random.fold_in, (None, 0))(jax.random.PRNGKey(seed), jnp.arange(batch))
    starts = jax.jit(jax.vmap(env.reset))(keys).data
    lo, hi = env.action_bounds
    draw = lambda i: np.random.default_rng((seed, i)).uniform(lo, hi, (steps, env.action_size))
    ctrl = np.stack([draw(i) for i in range(batch)]).astype(np.float32)
    return {
        "name": name, "asset": ASSETS / env.asset, "mj": mj, "frame_skip": env.frame_skip,
        "dt": dt, "steps": steps, "qpos": np.asarray(starts.qpos), "qvel": np.asarray(starts.qvel),
        "ctrl": ctrl, "shipped": shipped_setting(name, dt), "linesearch": env.linesearch,
    }  # fmt: skip


def is_shipped(row: dict, shipped: dict, name: str) -> bool:
    """Whether ``row`` is fastrl at the shipped setting (a contact-free model has no solver, so its
    iteration count does not matter)."""
    keys = [k for k in shipped if not (name in CONTACT_FREE and k == "solver_iterations")]
    return row["engine"] == "fastrl" and all(row[k] == shipped[k] for k in keys)


def substep_grid(frame_skip: int, quick: bool) -> list[int]:
    """Substeps per control step: 1, 2, 4, the env's frame_skip and twice it (quick: 1 and it)."""
    return sorted({1, frame_skip} if quick else {1, 2, 4, frame_skip, 2 * frame_skip})


# ---------------------------------------------------------------- MuJoCo C


def mujoco_model(task: dict, substeps: int) -> mujoco.MjModel:
    """The asset as MuJoCo C runs it (its integrator and solver) at timestep dt / substeps."""
    mj = mujoco.MjModel.from_xml_path(str(task["asset"]))
    mj.opt.timestep = task["dt"] / substeps
    return mj


def reference_model(task: dict, divisor: int) -> mujoco.MjModel:
    """The converged reference: float64, timestep / divisor, Newton to tolerance 1e-12."""
    mj = mujoco.MjModel.from_xml_path(str(task["asset"]))
    mj.opt.timestep /= divisor
    if task["name"] in CONTACT_FREE:
        mj.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    mj.opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
    mj.opt.iterations, mj.opt.tolerance = 100, 1e-12
    mj.opt.ls_iterations, mj.opt.ls_tolerance = 100, 1e-10
    return mj


def mujoco_inputs(mj: mujoco.MjModel, task: dict, substeps: int, batch: int) -> tuple[np.ndarray, np.ndarray]:
    """``mujoco.rollout``'s initial states (batch, nstate) and held controls (batch, nstep, nu)."""
    md = mujoco.MjData(mj)
    init = np.zeros((batch, mujoco.mj_stateSize(mj, STATE)))
    for i in range(batch):
        mujoco.mj_resetData(mj, md)
        md.qpos[:], md.qvel[:] = task["qpos"][i], task["qvel"][i]
        mujoco.mj_getState(mj, md, init[i], STATE)
    return init, np.repeat(task["ctrl"][:batch].astype(np.float64), substeps, axis=1)


def mujoco_rollout(mj: mujoco.MjModel, init: np.ndarray, ctrl: np.ndarray) -> np.ndarray:
    """States after every physics step (batch, nstep, nstate), on 2 threads."""
    datas = [mujoco.MjData(mj) for _ in range(2)]
    return mujoco.rollout.rollout(mj, datas, init, ctrl, persistent_pool=True)[0]


def qpos_per_control_step(
    mj: mujoco.MjModel, state: np.ndarray, substeps: int
) -> tuple[np.ndarray, np.ndarray]:
    """qpos after every control step (batch, steps, nq) and which sequences blew up.

    MuJoCo resets a simulation whose state goes bad (with a warning); the reset shows as the
    recorded time falling back, so it counts as a blow-up, as does a non-finite state.
    """
    expected = mj.opt.timestep * np.arange(1, state.shape[1] + 1)
    time_ok = np.all(np.abs(state[:, :, 0] - expected) <= 1e-6 * expected, axis=1)
    bad = ~np.all(np.isfinite(state), axis=(1, 2)) | ~time_ok
    return state[:, substeps - 1 :: substeps, 1 : 1 + mj.nq], bad


def reference_qpos(task: dict, divisor: int, sequences: int) -> tuple[np.ndarray, mujoco.MjModel]:
    """The reference's qpos after every control step (sequences, steps, nq), and its model."""
    mj = reference_model(task, divisor)
    substeps = task["frame_skip"] * divisor
    state = mujoco_rollout(mj, *mujoco_inputs(mj, task, substeps, sequences))
    qpos, bad = qpos_per_control_step(mj, state, substeps)
    if bad.any():
        raise RuntimeError(f"{task['name']}: the reference blew up in {int(bad.sum())} sequences")
    return qpos, mj


def integrator_name(mj: mujoco.MjModel) -> str:
    return mujoco.mjtIntegrator(mj.opt.integrator).name.removeprefix("mjINT_").lower()


def solver_name(mj: mujoco.MjModel) -> str:
    name = mujoco.mjtSolver(mj.opt.solver).name.removeprefix("mjSOL_")
    return "Newton" if name == "NEWTON" else name


# ---------------------------------------------------------------- fastrl


def fastrl_program(task: dict, integrator: str, iterations: int) -> Callable:
    """Jitted ``(qpos0, qvel0, ctrl, timestep, substeps) -> (qpos per control step, diverged)``,
    batched over the leading axis; ``ctrl`` is (batch, steps, nu), the output qpos likewise."""
    m = physics.model_from_mujoco(
        task["mj"], integrator=integrator, solver_iterations=iterations, linesearch=task["linesearch"]
    )

    def run(qpos0, qvel0, ctrl, timestep, substeps):
        mt = m.replace(timestep=timestep)

        def control_step(d, u):
            return jax.lax.fori_loop(0, substeps, lambda _, d: physics.step(mt, d, u), d)

        def scan_step(d, u):
            d = jax.vmap(control_step)(d, u)
            return d, d.qpos

        d0 = jax.vmap(lambda q, v: physics.make_data(m, qpos=q, qvel=v))(qpos0, qvel0)
        d, qpos = jax.lax.scan(scan_step, d0, jnp.swapaxes(ctrl, 0, 1))
        return jnp.swapaxes(qpos, 0, 1), d.diverged | ~jnp.all(jnp.isfinite(qpos), axis=(0, 2))

    return jax.jit(run)


def _args(task: dict, batch: int, steps: int, substeps: int) -> tuple:
    timestep = jnp.asarray(task["dt"] / substeps, jnp.float32)
    ctrl = task["ctrl"][:batch, :steps]
    return task["qpos"][:batch], task["qvel"][:batch], ctrl, timestep, jnp.int32(substeps)


def median_time(fn: Callable[[], object], runs: int = 3, min_s: float = 1.0, max_s: float = 3.0):
    """Median wall time of ``fn()`` and its last output: at least ``runs`` calls and ``min_s``
    seconds in all, but no new call once ``max_s`` seconds are spent."""
    times, out = [], None
    while not times or (sum(times) < max_s and (len(times) < runs or sum(times) < min_s)):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


# ---------------------------------------------------------------- accuracy


def tracked(mj: mujoco.MjModel, name: str, qpos: np.ndarray) -> np.ndarray:
    """(..., k) what the error measures: body 1's world position, or qpos (fixed base)."""
    if name in CONTACT_FREE:
        return np.asarray(qpos, np.float64)
    md = mujoco.MjData(mj)
    flat = np.asarray(qpos, np.float64).reshape(-1, mj.nq)
    out = np.empty((len(flat), 3))
    for i, q in enumerate(flat):
        md.qpos[:] = q
        mujoco.mj_kinematics(mj, md)
        out[i] = md.xpos[1]
    return out.reshape(*qpos.shape[:-1], 3)


def rms_error(points: np.ndarray, ref: np.ndarray) -> float:
    """RMS over sequences and control steps of the distance between tracked points."""
    return float(np.sqrt(np.mean(np.sum((points - ref) ** 2, axis=-1))))


def pareto(rows: list[dict], floor: float) -> list[bool]:
    """Whether each row is on the Pareto front of ``rows``: a finite error, and no other row at
    least as fast and as accurate, and better in one of the two. Errors within ``PARETO_TOL``
    (relative) plus the floor count as equal, since the reference resolves no finer: the same
    setting in fastrl and MuJoCo C errs alike, and speed alone must decide between them."""
    pts = [(r["control_steps_per_s"], r["error"]) for r in rows if r["error"] is not None]

    def dominated(s: float, e: float) -> bool:
        return any(s2 >= s and e2 <= e * (1 + PARETO_TOL) + floor and (s2 > s or e2 < e) for s2, e2 in pts)

    return [r["error"] is not None and not dominated(r["control_steps_per_s"], r["error"]) for r in rows]


# ---------------------------------------------------------------- one model


def _row(task: dict, ref: np.ndarray, engine: str, setting: dict, sps: float, qpos, bad) -> dict:
    bad = np.asarray(bad)
    error = None if bad.any() else rms_error(tracked(task["mj"], task["name"], qpos), ref)
    row = {"engine": engine, **setting, "timestep": task["dt"] / setting["substeps"],
           "control_steps_per_s": sps, "error": error, "diverged": int(bad.sum())}  # fmt: skip
    row["shipped"] = is_shipped(row, task["shipped"], task["name"])
    print(f"  {label(row)}: {sps:,.0f} control steps/s, error {error}", flush=True)
    return row


def sweep_fastrl(task: dict, ref: np.ndarray, plan: dict) -> list[dict]:
    """Every fastrl setting of ``plan``: one program per (integrator, iterations)."""
    rows = []
    for integrator in plan["integrators"]:
        for iterations in plan["iterations"]:
            program = fastrl_program(task, integrator, iterations)
            t0 = time.perf_counter()
            jax.block_until_ready(program(*_args(task, plan["batch"], plan["speed_steps"], 1)))
            jax.block_until_ready(program(*_args(task, plan["sequences"], task["steps"], 1)))
            compile_s = time.perf_counter() - t0
            print(f"  fastrl {integrator}, {iterations} iters: compiled in {compile_s:.0f} s", flush=True)
            for n in plan["substeps"]:
                speed_args = _args(task, plan["batch"], plan["speed_steps"], n)
                wall, _ = median_time(lambda p=program, a=speed_args: p(*a))
                qpos, bad = program(*_args(task, plan["sequences"], task["steps"], n))
                setting = {"integrator": integrator, "substeps": n, "solver_iterations": iterations}
                sps = plan["batch"] * plan["speed_steps"] / wall
                rows.append(_row(task, ref, "fastrl", setting, sps, np.asarray(qpos), bad))
                rows[-1]["compile_s"] = compile_s
    return rows


def sweep_mujoco(task: dict, ref: np.ndarray, plan: dict) -> list[dict]:
    """MuJoCo C at each timestep of the grid, timed over the whole horizon of the batch."""
    rows = []
    for n in plan["substeps"]:
        mj = mujoco_model(task, n)
        init, ctrl = mujoco_inputs(mj, task, n, plan["batch"])
        mujoco_rollout(mj, init[:2], ctrl[:2, :n])  # warm-up: starts the thread pool
        wall, state = median_time(lambda m=mj, i=init, c=ctrl: mujoco_rollout(m, i, c))
        qpos, bad = qpos_per_control_step(mj, state[: plan["sequences"]], n)
        setting = {"integrator": integrator_name(mj), "substeps": n,
                   "solver_iterations": int(mj.opt.iterations), "solver": solver_name(mj)}  # fmt: skip
        sps = plan["batch"] * task["steps"] / wall
        rows.append(_row(task, ref, "MuJoCo C", setting, sps, qpos, bad))
    return rows


# MJX is left out: at batch 1024 it deadlocks here (jaxlib 0.10.2 in the peer venv), the process
# idle while two threads of jaxlib's batched LAPACK kernels (ParallelBatchMap under its Cholesky)
# wait on each other; with one intra-op thread (XLA_FLAGS intra_op_parallelism_threads=1) one run
# finished and the next hung, so no workaround is kept (its trajectories at batch 16 did complete).
BRAX_BACKENDS = ("generalized", "spring", "positional")
PEERS_PYTHON = ROOT / ".venv-peers" / "bin" / "python"
PEERS_DIR = ROOT / "experiments" / "peers"
# A backend gets this long, then is left out.
BRAX_TIMEOUT_S = 300
BRAX_BLOWUP = 10.0  # m (rad): a tracked point this far from the reference within 1 s has blown up


def sweep_brax(task: dict, ref: np.ndarray, plan: dict) -> list[dict]:
    """Each Brax backend on the same asset, at the timestep Brax's env of the same name uses with
    it (``experiments/peers/brax_speed_accuracy.py`` in the peer venv). A backend that fails is
    reported and left out."""
    import subprocess
    import tempfile

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        inputs = pathlib.Path(tmp) / "in.npz"
        n = plan["sequences"]
        np.savez(inputs, name=task["name"], xml=str(task["asset"]), dt=task["dt"], batch=plan["batch"],
                 qpos=task["qpos"][:n], qvel=task["qvel"][:n], ctrl=task["ctrl"][:n])  # fmt: skip
        for backend in plan["brax"]:
            out = pathlib.Path(tmp) / f"{backend}.npz"
            cmd = [str(PEERS_PYTHON), str(PEERS_DIR / "brax_speed_accuracy.py"),
                   "--backend", backend, "--inputs", str(inputs), "--out", str(out)]  # fmt: skip
            try:
                proc = subprocess.run(
                    cmd,
                    capture_output=True,
                    text=True,
                    cwd=PEERS_DIR,
                    timeout=BRAX_TIMEOUT_S,
                    env=peer_environ(),
                )
            except subprocess.TimeoutExpired:
                print(f"  Brax {backend}: no result within {BRAX_TIMEOUT_S} s, left out", flush=True)
                continue
            if proc.returncode != 0:
                lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and "warn" not in ln.lower()]
                print(f"  Brax {backend}: failed, left out ({lines[-1:]})", flush=True)
                continue
            res = np.load(out)
            meta = json.loads(str(res["meta"]))
            points = np.asarray(res["q"] if task["name"] in CONTACT_FREE else res["root"], np.float64)
            # diverged: non-finite, or (Brax has no divergence guard) over BRAX_BLOWUP from the reference
            far = np.linalg.norm(np.nan_to_num(points - ref, nan=np.inf), axis=-1) > BRAX_BLOWUP
            bad = ~np.isfinite(points).all(axis=(1, 2)) | far.any(axis=1)
            setting = {"integrator": backend, "substeps": meta["substeps"], "solver_iterations": None,
                       "solver": "brax"}  # fmt: skip
            row = {"engine": "Brax", **setting, "timestep": meta["timestep"],
                   "control_steps_per_s": meta["control_steps_per_s"], "compile_s": meta["compile_s"],
                   "error": None if bad.any() else rms_error(points, ref),
                   "diverged": int(bad.sum()), "shipped": False,
                   "brax_version": meta["brax_version"], "speed_batch": meta["speed_batch"]}  # fmt: skip
            print(f"  {label(row)}: {row['control_steps_per_s']:,.0f} control steps/s, error {row['error']}",
                  flush=True)  # fmt: skip
            rows.append(row)
    return rows


def sweep_model(
    task: dict, plan: dict, keep: list[dict] | None = None, brax_rows: list[dict] | None = None
) -> dict:
    """Reference, floor, every setting's speed and error, and the Pareto front of one model.
    ``keep``: rows of an earlier run to reuse instead of sweeping fastrl and MuJoCo C again
    (``--brax-only``); ``brax_rows``: an earlier run's Brax rows to carry instead of running Brax
    (``--merge --no-brax``)."""
    name, mj = task["name"], task["mj"]
    t0 = time.perf_counter()
    ref_q, ref_mj = reference_qpos(task, REF_DIVISOR, plan["sequences"])
    fine_q, _ = reference_qpos(task, 2 * REF_DIVISOR, plan["sequences"])
    ref = tracked(mj, name, ref_q)
    floor = rms_error(tracked(mj, name, fine_q), ref)
    print(f"{name}: reference in {time.perf_counter() - t0:.1f} s, floor {floor:.2e}", flush=True)
    if keep is None:
        rows = sweep_fastrl(task, ref, plan) + sweep_mujoco(task, ref, plan)
    else:
        rows = [r for r in keep if r["engine"] != "Brax"]
    for r in sweep_brax(task, ref, plan):
        rows.append({**r, "added_later": keep is not None, "measured": time.strftime("%Y-%m-%d")})
    rows += [{**r, "added_later": True} for r in brax_rows or []]
    fastrl_rows = [r for r in rows if r["engine"] == "fastrl"]
    for r, on_front in zip(rows, pareto(rows, floor), strict=True):
        r["pareto"] = on_front
    for r, on_front in zip(fastrl_rows, pareto(fastrl_rows, floor), strict=True):
        r["pareto_fastrl"] = on_front
    return {
        "dt": task["dt"], "frame_skip": task["frame_skip"], "horizon_s": task["steps"] * task["dt"],
        "control_steps": task["steps"], "sequences": plan["sequences"], "batch": plan["batch"],
        "floor": floor, "shipped": task["shipped"], "linesearch": task["linesearch"],
        "metric": "qpos (m, rad)" if name in CONTACT_FREE else "root body position (m)",
        "reference": {"integrator": integrator_name(ref_mj),
                      "timestep": ref_mj.opt.timestep, "solver": "Newton", "iterations": 100,
                      "tolerance": 1e-12},
        "rows": rows,
    }  # fmt: skip


# ---------------------------------------------------------------- outputs

SOLVER_TEXT = {
    "exact": "Newton with exact line searches and a fixed iteration count (`linesearch='exact'`)",
    "mujoco": "Newton with MuJoCo's line search and early exit (`linesearch='mujoco'`)",
}


def label(r: dict) -> str:
    if r["engine"] == "Brax":
        small = f" (timed at batch {r['speed_batch']})" if r.get("speed_batch", BATCH) < BATCH else ""
        return f"Brax {r['integrator']} {r['timestep']:.4g}x{r['substeps']}{small}"
    iters = r["solver_iterations"]
    solver = f"{iters} iters" if r["engine"] == "fastrl" else f"{r['solver']} {iters} iters"
    return f"{r['engine']} {r['integrator']} {r['timestep']:.4g}x{r['substeps']}, {solver}"


def chart(measured: dict):
    """One panel per model: control steps/s against error, the fronts and the shipped setting."""
    plt = results.pyplot()
    cols = min(len(measured), 3)
    nrows = -(-len(measured) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(5.2 * cols, 4.3 * nrows), squeeze=False)
    styles = {("fastrl", "euler"): ("o", "tab:blue"), ("fastrl", "rk4"): ("s", "tab:orange"),
              ("MuJoCo C", "euler"): ("^", "black"), ("MuJoCo C", "rk4"): ("v", "black"),
              ("Brax", "mjx"): ("D", "tab:green"), ("Brax", "generalized"): ("P", "tab:purple"),
              ("Brax", "spring"): ("X", "tab:brown"), ("Brax", "positional"): ("*", "tab:pink")}  # fmt: skip
    for ax, (name, res) in zip(axes.flat, measured.items(), strict=False):
        ok = [r for r in res["rows"] if r["error"] is not None]
        for (engine, integrator), (marker, color) in styles.items():
            pts = [(r["control_steps_per_s"], r["error"]) for r in ok
                   if (r["engine"], r["integrator"]) == (engine, integrator)]  # fmt: skip
            if pts:
                ax.scatter(*zip(*pts, strict=True), marker=marker, color=color, s=22, alpha=0.8,
                           label=f"{engine} {integrator}")  # fmt: skip
        for key, style, text in (
            ("pareto", "g-", "Pareto front"),
            ("pareto_fastrl", "m--", "fastrl's front"),
        ):
            front = sorted((r["control_steps_per_s"], r["error"]) for r in ok if r.get(key))
            if front:
                ax.plot(*zip(*front, strict=True), style, lw=1, label=text)
        for r in ok:
            if r["shipped"]:
                ax.scatter([r["control_steps_per_s"]], [r["error"]], s=240, facecolors="none",
                           edgecolors="red", linewidths=1.5, label="fastrl shipped default")  # fmt: skip
        ax.axhline(res["floor"], color="gray", ls=":", lw=1, label="floor (reference vs finer)")
        diverged = len(res["rows"]) - len(ok)
        title = f"{name}: dt {res['dt']:g} s, {res['horizon_s']:g} s" + (
            f", {diverged} settings diverged" if diverged else ""
        )
        ax.set(xscale="log", yscale="log", xlabel=f"control steps / s (batch {res['batch']})",
               ylabel=f"RMS error of {res['metric']}", title=title)  # fmt: skip
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6, framealpha=0.4)  # translucent: points may sit under it
    for ax in list(axes.flat)[len(measured) :]:
        ax.axis("off")
    fig.tight_layout()
    return fig


def markdown(measured: dict, machine: str) -> str:
    lines = ["# Speed vs accuracy: fastrl's physics knobs, MuJoCo C and Brax", "",
             f"Machine: {machine}. Command: `python -m experiments.speed_accuracy`.", "",
             "Error: RMS over control steps and sequences of the distance to a converged MuJoCo C "
             "reference (float64, asset timestep / 20, Newton with 100 iterations and tolerance "
             "1e-12) of the root body's world position (of qpos for the fixed-base pendulum), from "
             "the same start states under the same random controls. Floor: that reference against "
             "one at timestep / 40. Speed: control steps/s at the batch shown (fastrl: the jitted, "
             "vmapped control step in float32; MuJoCo C: `mujoco.rollout` on 2 threads; Brax: "
             "its backend's pipeline step, jitted and vmapped, at the timestep Brax's env of the "
             "same name uses with that backend, Euler). Pareto: "
             "no other setting is at least as fast and as accurate (errors within "
             f"{PARETO_TOL:.0%} plus the floor count as equal), among all settings (front) or "
             "fastrl's alone (fastrl front).", ""]  # fmt: skip
    for name, res in measured.items():
        ship = next((r for r in res["rows"] if r["shipped"]), {})
        where = ", ".join(
            f"**{'on' if ship.get(key) else 'not on'} {text}**"
            for key, text in (("pareto", "the Pareto front"), ("pareto_fastrl", "fastrl's front"))
        )
        s, ref = res["shipped"], res["reference"]
        # runs before the sweep followed the env's line search measured the loader's default
        solver = SOLVER_TEXT[res.get("linesearch", "mujoco")]
        if name in CONTACT_FREE:
            solver = "none (no constraint rows within the horizon)"
        elif "linesearch" not in res:
            solver += " (the loader's default then; the env steps with exact line searches)"
        later = [r for r in res["rows"] if r.get("added_later")]
        lines += [f"## {name}", "",
                  f"Control step {res['dt']:g} s, horizon {res['horizon_s']:g} s ({res['control_steps']} "
                  f"control steps), {res['sequences']} sequences. Metric: {res['metric']}. Reference: "
                  f"MuJoCo C {ref['integrator']} at {ref['timestep']:.3g} s. Floor: {res['floor']:.2e}. "
                  f"Shipped: fastrl {s['integrator']} x{s['substeps']}, {s['solver_iterations']} "
                  f"iterations, {where}. fastrl's constraint solver: {solver}.", "",
                  *([f"Brax's rows were measured on {later[0]['measured']} by `--brax-only`, in a later run "
                     "than the others on the same machine.", ""] if later else []),
                  *([f"Shipped setting marked anew on {res['shipped_marked']} from the configs of that day "
                     "(`--from-json`; nothing re-measured).", ""] if res.get("shipped_marked") else []),
                  "| setting | control steps/s | error | front | fastrl front | shipped |",
                  "| --- | ---: | ---: | :---: | :---: | :---: |"]  # fmt: skip
        for r in sorted(res["rows"], key=lambda r: -r["control_steps_per_s"]):
            err = f"{r['error']:.2e}" if r["error"] is not None else f"diverged ({r['diverged']})"
            marks = ["yes" if r.get(k) else "" for k in ("pareto", "pareto_fastrl")]
            marks.append("**shipped**" if r["shipped"] else "")
            lines.append(f"| {label(r)} | {r['control_steps_per_s']:,.0f} | {err} | {' | '.join(marks)} |")
        lines.append("")
    return "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the pendulum, 2 timesteps, for CI")
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS)
    parser.add_argument("--models", nargs="+", choices=MODELS, default=None)
    parser.add_argument(
        "--merge",
        action="store_true",
        help="keep the other models already in the output JSON (run the sweep in parts)",
    )
    parser.add_argument("--no-brax", action="store_true", help="leave Brax's backends out")
    parser.add_argument("--brax-backends", nargs="+", default=list(BRAX_BACKENDS), metavar="BACKEND",
                        choices=("mjx", *BRAX_BACKENDS))  # fmt: skip
    parser.add_argument(
        "--brax-only",
        action="store_true",
        help="re-measure only Brax's backends, keeping fastrl's and MuJoCo C's rows from the output JSON",
    )
    parser.add_argument(
        "--from-json",
        action="store_true",
        help="measure nothing: mark the shipped settings anew from the current configs and re-render",
    )
    return parser


def sweep_plan(task: dict, quick: bool, args) -> dict:
    """What one model's sweep runs. Quick: the shipped integrator and iterations only, and one
    program shape for speed and accuracy (batch = sequences, timed over the whole short horizon)."""
    one_iteration_count = quick or task["name"] in CONTACT_FREE
    return {
        "batch": 64 if quick else BATCH,
        "sequences": 64 if quick else SEQUENCES,
        "speed_steps": task["steps"] if quick else 1,
        "substeps": substep_grid(task["frame_skip"], quick),
        "integrators": [task["shipped"]["integrator"]] if quick else ["euler", "rk4"],
        "iterations": [task["shipped"]["solver_iterations"]] if one_iteration_count else ITERATIONS,
        "brax": [] if quick or args.no_brax or not PEERS_PYTHON.exists() else args.brax_backends,
    }


def main() -> None:
    parser = _parser()
    args = parser.parse_args()
    if args.from_json:
        return rerender(args.out / ("speed_accuracy_quick.json" if args.quick else "speed_accuracy.json"))
    if args.brax_only and not PEERS_PYTHON.exists():
        parser.error(f"--brax-only needs the peer venv {PEERS_PYTHON} (experiments/peers/setup_peers.sh)")
    models = args.models or (["inverted_double_pendulum"] if args.quick else list(MODELS))
    measured = {}
    stem = "speed_accuracy_quick" if args.quick else "speed_accuracy"
    previous = args.out / f"{stem}.json"
    earlier = results.load(previous)["models"] if previous.exists() else {}
    if args.brax_only and not set(models) <= set(earlier):
        parser.error(f"--brax-only: {previous} has no rows for {sorted(set(models) - set(earlier))}")
    if args.merge or args.brax_only:
        measured = {k: v for k, v in earlier.items() if k not in models}
        print(f"keeping {', '.join(measured) or 'no models'} from {previous}")
    if not PEERS_PYTHON.exists() and not args.no_brax:
        print(f"no peer venv at {PEERS_PYTHON}: Brax left out (bash experiments/peers/setup_peers.sh)")
    for name in models:
        task = make_task(name, 64 if args.quick else BATCH, 0.2 if args.quick else HORIZON_S[name])
        keep = earlier[name]["rows"] if args.brax_only else None
        carried = None
        if args.merge and args.no_brax and name in earlier:  # Brax not run: keep its earlier rows
            carried = [r for r in earlier[name]["rows"] if r["engine"] == "Brax"]
        measured[name] = sweep_model(task, sweep_plan(task, args.quick, args), keep, carried)
    measured = {name: measured[name] for name in MODELS if name in measured}  # a fixed order
    write(args.out / f"{stem}.json", results.machine(), measured)


def write(path: pathlib.Path, machine: str, measured: dict) -> None:
    """The JSON at ``path``, and beside it the table (.md) and the chart (.png)."""
    text = markdown(measured, machine)
    results.save(path.parent, path.stem, {"machine": machine, "models": measured}, text, chart(measured))
    print(text)


def rerender(path: pathlib.Path) -> None:
    """Re-marks each model's shipped setting from today's configs (a shipped iteration count may
    have changed since the rows were measured) and rewrites the table and chart; measures nothing."""
    if not path.exists():
        raise SystemExit(f"--from-json: no {path}; run the sweep first")
    saved = results.load(path)
    for name, res in saved["models"].items():
        res["shipped"] = shipped_setting(name, res["dt"])
        for r in res["rows"]:
            r["shipped"] = is_shipped(r, res["shipped"], name)
        if not any(r["shipped"] for r in res["rows"]):
            print(f"{name}: the shipped setting {res['shipped']} is not among the measured rows")
        res["shipped_marked"] = time.strftime("%Y-%m-%d")
    write(path, saved["machine"], saved["models"])


if __name__ == "__main__":
    fastrl.use_recommended_xla_flags()  # the XLA:CPU flags fastrl's command line runs with
    main()
