"""Momentum and energy drift vs timestep of a free-floating articulated body, fastrl beside MuJoCo C.

    python -m experiments.conservation           # 6 timesteps, 1 s + 1 s phases (~1 min on 2 cores)
    python -m experiments.conservation --quick   # 2 timesteps, 0.2 s + 0.2 s phases, no float32
                                                 # Euler, for CI

The protocol of Erez, Tassa & Todorov (2015), "Simulation tools for model-based robotics", which
compared engines on how well they conserve what physics conserves. The body is an Ant (torso
sphere, four two-hinge capsule legs, ``MODEL`` below) floating free: no gravity, no contacts, no
joint damping, armature, springs or limits, so nothing external acts on it and nothing dissipates.

    kick      at t = 0 the body gets a fixed random velocity (root linear and angular velocity
              and every joint's), so its linear and angular momentum are non-zero;
    phase 1   ``PHASE1_S`` of random joint torques (uniform in the motors' range, piecewise
              constant, held ``HOLD_S``): joint motors act between a parent and a child body,
              internal forces summing to a zero external wrench, so linear momentum P and
              angular momentum L about the centre of mass must stay as the kick left them;
    phase 2   ``PHASE2_S`` with the controls off: the body coasts, so its energy (all kinetic:
              no gravity, no springs) must stay as phase 1 left it.

Measured at every ``SAMPLE_S`` of simulated time (a whole number of steps at every timestep):

    momentum drift  max over phase 1 of max(|P(t) - P(0)| / |P(0)|, |L(t) - L(0)| / |L(0)|)
                    (relative; the kick makes both initial norms non-zero)
    energy drift    max over phase 2 of |E(t) - E(t1)| / E(t1), t1 the start of phase 2

Both engines' states are measured by the same code, MuJoCo's own float64 functions on the
recorded (qpos, qvel): P = subtree mass x ``subtree_linvel`` and L = ``subtree_angmom`` of the
root body (``mj_subtreeVel``), E = ``mj_energyPos`` + ``mj_energyVel`` (0.5 qvel' M qvel). At
t = 0 they are checked against fastrl's own float64 quantities (the sum over bodies of the
com-based inertia times the spatial velocity, and 0.5 qvel' qM qvel); the JSON records the
largest relative difference.

Settings: timesteps ``TIMESTEPS`` x {fastrl Euler, fastrl RK4, each in float64
(``jax_enable_x64``) and float32 (fastrl's default), MuJoCo C Euler, RK4 and implicitfast (its
float64)}. Every setting gets the same kick and the same torque sequence. float32 has a rounding
floor (a relative 1e-7 per operation): below some timestep its drift stops falling with the
timestep, the integrator's error being smaller than the rounding.

Speed, a rough axis only: simulated seconds per wall-clock second of one trajectory (fastrl: the
jitted rollout on CPU after compilation; MuJoCo C: ``mujoco.rollout`` on one thread), the best of
up to 3 runs, on whatever else the machine is running.

Writes ``experiments/results/conservation.{json,md,png}`` (``conservation_quick.*`` with
``--quick``): the table, a summary written from the numbers, and two log-log panels (momentum
drift, energy drift vs timestep), one line per engine, integrator and precision.
"""

from __future__ import annotations

import argparse
import pathlib
import time

import jax
import jax.numpy as jnp
import mujoco
import mujoco.rollout
import numpy as np

import fastrl
from experiments import results
from fastrl import physics
from fastrl.physics import math

TIMESTEPS = [0.0005, 0.001, 0.002, 0.005, 0.01, 0.02]
QUICK_TIMESTEPS = [0.01, 0.02]
SAMPLE_S = 0.02  # measurement spacing: a whole number of steps at every timestep above
HOLD_S = 0.1  # each random torque is held this long (a whole number of samples)
PHASE1_S, PHASE2_S = 1.0, 1.0
QUICK_PHASE_S = 0.2
SEED = 0
STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS  # time, qpos, qvel, ...

# The Ant's shape with solid density, in the air: no gravity, contacts off (contype 0), no
# damping, armature, springs or joint limits. Motors of gear 20 N m: under random torques the
# legs swing through radians, spinning at a few rad/s, in a second. The four legs are one
# leg's bodies (``_LEG``) along each leg's direction in the plane, with the Ant's ankle axes.
_BODY = """
<mujoco model="ant_free">
  <option timestep="0.01" gravity="0 0 0"/>
  <default>
    <joint armature="0" damping="0" stiffness="0" limited="false"/>
    <geom type="capsule" size="0.08" density="1000" contype="0" conaffinity="0"/>
    <motor gear="20" ctrlrange="-1 1" ctrllimited="true"/>
  </default>
  <worldbody>
    <body name="torso" pos="0 0 0.75">
      <freejoint name="root"/>
      <geom type="sphere" size="0.25"/>
{legs}
    </body>
  </worldbody>
  <actuator>
    <motor joint="hip_1"/><motor joint="ankle_1"/><motor joint="hip_2"/><motor joint="ankle_2"/>
    <motor joint="hip_3"/><motor joint="ankle_3"/><motor joint="hip_4"/><motor joint="ankle_4"/>
  </actuator>
</mujoco>"""
_LEG = """\
      <body><geom fromto="0 0 0 {x:g} {y:g} 0"/>
        <body pos="{x:g} {y:g} 0"><joint name="hip_{i}" type="hinge" axis="0 0 1"/>
          <geom fromto="0 0 0 {x:g} {y:g} 0"/>
          <body pos="{x:g} {y:g} 0"><joint name="ankle_{i}" type="hinge" axis="{ankle}"/>
            <geom fromto="0 0 0 {x2:g} {y2:g} 0"/></body></body></body>"""
_LEGS = [(0.2, 0.2, "-1 1 0"), (-0.2, 0.2, "1 1 0"), (-0.2, -0.2, "-1 1 0"), (0.2, -0.2, "1 1 0")]
MODEL = _BODY.format(
    legs="\n".join(
        _LEG.format(i=i, x=x, y=y, x2=2 * x, y2=2 * y, ankle=a) for i, (x, y, a) in enumerate(_LEGS, 1)
    )
)

MUJOCO_INTEGRATORS = {"euler": mujoco.mjtIntegrator.mjINT_EULER, "rk4": mujoco.mjtIntegrator.mjINT_RK4,
                      "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST}  # fmt: skip


# ---------------------------------------------------------------- the fixed problem


def make_problem(phase1_s: float, phase2_s: float, seed: int = SEED) -> dict:
    """The model, the kick (initial state) and phase 1's torques, one row per sample interval."""
    mj = mujoco.MjModel.from_xml_string(MODEL)
    assert not mj.dof_damping.any() and not mj.dof_armature.any() and not mj.opt.gravity.any()
    rng = np.random.default_rng(seed)
    n1, n2 = round(phase1_s / SAMPLE_S), round(phase2_s / SAMPLE_S)
    hold = round(HOLD_S / SAMPLE_S)
    qvel = np.concatenate([[0.3, -0.2, 0.1, 0.5, -0.4, 0.2], rng.standard_normal(mj.nv - 6)])
    ctrl = np.repeat(rng.uniform(-1, 1, (-(-n1 // hold), mj.nu)), hold, axis=0)[:n1]
    return {"mj": mj, "qpos": mj.qpos0.copy(), "qvel": qvel, "ctrl": ctrl, "n1": n1, "n2": n2,
            "phase1_s": n1 * SAMPLE_S, "phase2_s": n2 * SAMPLE_S}  # fmt: skip


def stride_of(timestep: float) -> int:
    """Steps per measurement sample."""
    stride = round(SAMPLE_S / timestep)
    if abs(stride * timestep - SAMPLE_S) > 1e-9:
        raise ValueError(f"timestep {timestep} does not divide the sample spacing {SAMPLE_S}")
    return stride


# ---------------------------------------------------------------- measurement (shared)


def measure(qpos: np.ndarray, qvel: np.ndarray) -> dict:
    """P (n,3), L about the com (n,3) and E (n,) of states (n,nq), (n,nv), by MuJoCo in float64."""
    model = mujoco.MjModel.from_xml_string(MODEL)
    model.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY
    d = mujoco.MjData(model)
    mass = model.body_subtreemass[1]
    out = {"P": np.empty((len(qpos), 3)), "L": np.empty((len(qpos), 3)), "E": np.empty(len(qpos))}
    for i, (q, v) in enumerate(zip(np.asarray(qpos, np.float64), np.asarray(qvel, np.float64), strict=True)):
        d.qpos[:], d.qvel[:] = q, v
        mujoco.mj_forward(model, d)
        mujoco.mj_energyPos(model, d)
        mujoco.mj_energyVel(model, d)
        mujoco.mj_subtreeVel(model, d)
        out["P"][i] = mass * d.subtree_linvel[1]
        out["L"][i] = d.subtree_angmom[1]
        out["E"][i] = d.energy[0] + d.energy[1]
    return out


def drifts(problem: dict, qpos: np.ndarray, qvel: np.ndarray) -> dict:
    """The drift metrics of one trajectory: samples 0 (the kick) to n1 (phase 1), n1 to the end."""
    if not (np.all(np.isfinite(qpos)) and np.all(np.isfinite(qvel))):
        keys = ("momentum_drift", "linear_drift", "angular_drift", "energy_drift", "energy_phase2",
                "energy_kick", "joint_travel")  # fmt: skip
        return dict.fromkeys(keys)
    q = measure(qpos, qvel)
    n1 = problem["n1"]
    rel = lambda x: float(np.max(np.linalg.norm(x[1 : n1 + 1] - x[0], axis=-1)) / np.linalg.norm(x[0]))
    lin, ang = rel(q["P"]), rel(q["L"])
    e = q["E"][n1:]
    return {
        "momentum_drift": max(lin, ang), "linear_drift": lin, "angular_drift": ang,
        "energy_drift": float(np.max(np.abs(e[1:] - e[0])) / e[0]), "energy_phase2": float(e[0]),
        "energy_kick": float(q["E"][0]),
        "joint_travel": float(np.max(np.abs(qpos[: n1 + 1, 7:] - qpos[0, 7:]))),
    }  # fmt: skip


def best_time(fn, runs: int = 3, max_s: float = 1.0):
    """The shortest wall time of ``fn()`` over up to ``runs`` calls (no new call once ``max_s``
    seconds are spent), and its output: the minimum is the least disturbed by other load."""
    times = []
    while len(times) < runs and sum(times) < max_s:
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


# ---------------------------------------------------------------- fastrl


def fastrl_program(problem: dict, integrator: str):
    """Jitted ``(timestep, stride) -> (qpos, qvel)`` at the n1 + n2 + 1 samples (the kick first)."""
    m = physics.model_from_mujoco(problem["mj"], integrator=integrator)
    dtype = m.body_mass.dtype
    ctrl = jnp.concatenate([jnp.asarray(problem["ctrl"], dtype), jnp.zeros((problem["n2"], m.nu), dtype)])
    d0 = physics.make_data(m, qpos=problem["qpos"], qvel=problem["qvel"])

    def run(timestep, stride):
        mt = m.replace(timestep=timestep)

        def sample(d, u):
            d = jax.lax.fori_loop(0, stride, lambda _, d: physics.step(mt, d, u), d)
            return d, (d.qpos, d.qvel)

        _, (qpos, qvel) = jax.lax.scan(sample, d0, ctrl)
        return jnp.concatenate([d0.qpos[None], qpos]), jnp.concatenate([d0.qvel[None], qvel])

    program = jax.jit(run)
    return lambda dt, stride: program(jnp.asarray(dt, dtype), jnp.int32(stride))


def sweep_fastrl(problem: dict, timesteps: list[float], quick: bool) -> list[dict]:
    """fastrl's settings; ``quick`` leaves out float32 Euler (a compilation saved in CI)."""
    rows = []
    previous = jax.config.jax_enable_x64
    try:
        for precision in ("float64", "float32"):
            jax.config.update("jax_enable_x64", precision == "float64")
            for integrator in ("rk4",) if quick and precision == "float32" else ("euler", "rk4"):
                program = fastrl_program(problem, integrator)
                t0 = time.perf_counter()
                jax.block_until_ready(program(max(timesteps), 1))
                compile_s = time.perf_counter() - t0
                for dt in timesteps:
                    wall, (qpos, qvel) = best_time(
                        lambda p=program, dt=dt: jax.block_until_ready(p(dt, stride_of(dt)))
                    )
                    rows.append(_row(problem, "fastrl", integrator, precision, dt, wall, qpos, qvel))
                    rows[-1]["compile_s"] = compile_s
    finally:
        jax.config.update("jax_enable_x64", previous)
    return rows


# ---------------------------------------------------------------- MuJoCo C


def sweep_mujoco(problem: dict, timesteps: list[float]) -> list[dict]:
    rows = []
    for integrator, enum in MUJOCO_INTEGRATORS.items():
        for dt in timesteps:
            mj = mujoco.MjModel.from_xml_string(MODEL)
            mj.opt.timestep, mj.opt.integrator = dt, enum
            d = mujoco.MjData(mj)
            d.qpos[:], d.qvel[:] = problem["qpos"], problem["qvel"]
            init = np.empty(mujoco.mj_stateSize(mj, STATE))
            mujoco.mj_getState(mj, d, init, STATE)
            stride = stride_of(dt)
            ctrl = np.concatenate([problem["ctrl"], np.zeros((problem["n2"], mj.nu))])
            ctrl = np.repeat(ctrl, stride, axis=0)[None]
            wall, (state, _) = best_time(
                lambda mj=mj, d=d, i=init, c=ctrl: mujoco.rollout.rollout(mj, d, i[None], c)
            )
            state = state[0]
            state = np.concatenate([init[None], state[stride - 1 :: stride]])
            qpos, qvel = state[:, 1 : 1 + mj.nq], state[:, 1 + mj.nq : 1 + mj.nq + mj.nv]
            rows.append(_row(problem, "MuJoCo C", integrator, "float64", dt, wall, qpos, qvel))
    return rows


def _row(problem, engine, integrator, precision, dt, wall, qpos, qvel) -> dict:
    row = {"engine": engine, "integrator": integrator, "precision": precision, "timestep": dt,
           **drifts(problem, np.asarray(qpos), np.asarray(qvel)),
           "sim_s_per_wall_s": (problem["phase1_s"] + problem["phase2_s"]) / wall}  # fmt: skip
    row["label"] = label(row)
    fmt = lambda x: "diverged" if x is None else f"{x:.2e}"
    print(f"  {row['label']:28s} dt {dt:<7g} momentum {fmt(row['momentum_drift'])}  "
          f"energy {fmt(row['energy_drift'])}  {row['sim_s_per_wall_s']:,.0f} sim s/s",
          flush=True)  # fmt: skip
    return row


def label(r: dict) -> str:
    return f"{r['engine']} {r['integrator']}" + (f" {r['precision']}" if r["engine"] == "fastrl" else "")


# ---------------------------------------------------------------- validation of the measurement


def validate(problem: dict) -> dict:
    """fastrl's own float64 momentum and energy of the kicked state against ``measure``'s."""
    previous = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    try:
        m = physics.model_from_mujoco(problem["mj"])

        @jax.jit  # eager, op by op, takes ~10x longer than compiling
        def quantities(qpos, qvel):
            d = physics.forward(m, physics.make_data(m, qpos=qpos, qvel=qvel))
            spatial = jnp.sum(math.mul_inert_vec(d.cinert, d.cvel), axis=0)  # (L, P) about the com
            return spatial, 0.5 * d.qvel @ d.qM @ d.qvel

        spatial, energy = quantities(problem["qpos"], problem["qvel"])
        spatial, energy = np.asarray(spatial), float(energy)
    finally:
        jax.config.update("jax_enable_x64", previous)
    q = measure(problem["qpos"][None], problem["qvel"][None])
    rel = lambda a, b: float(np.linalg.norm(a - b) / np.linalg.norm(b))
    out = {"linear_momentum": rel(spatial[3:], q["P"][0]), "angular_momentum": rel(spatial[:3], q["L"][0]),
           "energy": abs(energy - q["E"][0]) / q["E"][0]}  # fmt: skip
    out["max_relative_difference"] = max(out.values())
    out["P0"], out["L0"], out["E0"] = q["P"][0].tolist(), q["L"][0].tolist(), float(q["E"][0])
    return out


# ---------------------------------------------------------------- outputs


STYLES = {  # label -> (colour, line style, marker, marker size, filled)
    "fastrl euler float64": ("tab:blue", "-", "o", 4, True),
    "fastrl euler float32": ("tab:cyan", "--", "o", 4, True),
    "fastrl rk4 float64": ("tab:orange", "-", "s", 4, True),
    "fastrl rk4 float32": ("tab:red", "--", "s", 4, True),
    "MuJoCo C euler": ("black", ":", "^", 10, False),
    "MuJoCo C rk4": ("black", ":", "v", 10, False),
    "MuJoCo C implicitfast": ("tab:gray", ":", "x", 8, True),
}


def chart(result: dict):
    """Two log-log panels, momentum and energy drift against the timestep; returns the figure."""
    plt = results.pyplot()
    p = result["protocol"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    panels = (("momentum_drift", f"phase 1 ({p['phase1_s']:g} s random torques): momentum drift",
               "max relative change of P or L"),
              ("energy_drift", f"phase 2 ({p['phase2_s']:g} s coasting): energy drift",
               "max relative change of energy"))  # fmt: skip
    for ax, (key, title, ylabel) in zip(axes, panels, strict=True):
        for name, (color, ls, marker, size, filled) in STYLES.items():
            pts = sorted((r["timestep"], r[key]) for r in result["rows"] if r["label"] == name and r[key])
            if pts:
                ax.plot(*zip(*pts, strict=True), color=color, ls=ls, marker=marker, ms=size,
                        mfc=color if filled else "none", label=name)  # fmt: skip
        ax.set(xscale="log", yscale="log", xlabel="timestep (s)", ylabel=ylabel, title=title)
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8)
    fig.suptitle("Free-floating Ant, no gravity or contacts: fastrl vs MuJoCo C (MuJoCo's hollow markers "
                 "ring the fastrl float64 points where the drifts coincide)", fontsize=9)  # fmt: skip
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    return fig


def _get(rows, name, dt, key):
    return next((r[key] for r in rows if r["label"] == name and r["timestep"] == dt), None)


def _slope(rows, name, key, floor):
    """Log-log slope of drift vs timestep over the points above ``floor`` (None if under 2)."""
    pts = [(r["timestep"], r[key]) for r in rows if r["label"] == name and r[key] and r[key] > floor]
    if len(pts) < 2:
        return None
    x, y = np.log(np.array(pts)).T
    return float(np.polyfit(x, y, 1)[0])


def _orders(rows: list[dict], dts: list[float]) -> list[str]:
    """fastrl float64's drifts from the coarsest timestep to the finest, with their log-log slope."""
    lo, hi = min(dts), max(dts)
    parts = []
    for key, what in (
        ("momentum_drift", "momentum drift (phase 1)"),
        ("energy_drift", "energy drift (phase 2)"),
    ):
        for integ in ("euler", "rk4"):
            name = f"fastrl {integ} float64"
            a, b = _get(rows, name, hi, key), _get(rows, name, lo, key)
            if a is None or b is None:
                parts.append(f"fastrl {integ} float64 diverged somewhere in the sweep ({what}).")
                continue
            s = _slope(rows, name, key, floor=1e-12)
            slope = f", a log-log slope of {s:.1f}" if s is not None else ""
            parts.append(f"fastrl {integ} float64's {what} goes from {a:.1e} at {hi:g} s to {b:.1e} at "
                         f"{lo:g} s{slope}.")  # fmt: skip
    return parts


def _agreement(rows: list[dict], dts: list[float]) -> list[str]:
    """How far fastrl float64's drifts are from MuJoCo C's at the same integrator and timestep."""
    ratios = []
    for integ in ("euler", "rk4"):
        for dt in dts:
            for key in ("momentum_drift", "energy_drift"):
                f, c = (
                    _get(rows, f"fastrl {integ} float64", dt, key),
                    _get(rows, f"MuJoCo C {integ}", dt, key),
                )
                if f and c and max(f, c) > 1e-12:  # above float64 rounding
                    ratios.append(f / c)
    if not ratios:
        return []
    worst = max(abs(r - 1) for r in ratios)
    return [f"At the same integrator and timestep, fastrl in float64 and MuJoCo C drift alike: "
            f"their drifts differ by at most {worst:.1e} (relative) over the {len(ratios)} "
            f"pairs above float64 rounding (1e-12)."]  # fmt: skip


def _float32_floor(rows: list[dict], dts: list[float]) -> list[str]:
    """Where float32 rounding, not the integrator, sets fastrl's drift."""
    parts = []
    for integ in ("euler", "rk4"):
        for key, what in (("momentum_drift", "momentum"), ("energy_drift", "energy")):
            d32 = {dt: _get(rows, f"fastrl {integ} float32", dt, key) for dt in dts}
            d64 = {dt: _get(rows, f"fastrl {integ} float64", dt, key) for dt in dts}
            both = [dt for dt in dts if d32[dt] and d64[dt]]
            if not both:
                continue
            floored = [dt for dt in both if d32[dt] > 3 * d64[dt]]
            if floored:
                best = min(d32[dt] for dt in both)
                at = ", ".join(f"{dt:g}" for dt in floored)
                finest = min(both)
                rise = (f"; it rises again to {d32[finest]:.1e} at {finest:g} s, as the steps, and so "
                        f"the roundings, multiply" if d32[finest] > 2 * best else "")  # fmt: skip
                parts.append(f"In float32, fastrl {integ}'s {what} drift never falls below {best:.0e}: "
                             f"float32 rounding, not the integrator, sets it, and it exceeds float64's "
                             f"threefold at {at} s{rise}.")  # fmt: skip
            else:
                worst = max(abs(d32[dt] / d64[dt] - 1) for dt in both)
                parts.append(f"In float32, fastrl {integ}'s {what} drift is within {worst:.0e} (relative) "
                             f"of float64's at every timestep: its discretisation error is far above "
                             f"float32 rounding.")  # fmt: skip
    return parts


def _mujoco_integrators(rows: list[dict], dts: list[float]) -> list[str]:
    """MuJoCo's implicitfast against its Euler, then RK4's energy drift against Euler's."""
    parts = []
    for key, what in (("momentum_drift", "momentum"), ("energy_drift", "energy")):
        pairs = [
            (_get(rows, "MuJoCo C implicitfast", dt, key), _get(rows, "MuJoCo C euler", dt, key))
            for dt in dts
        ]
        pairs = [(a, b) for a, b in pairs if a and b]
        if pairs:
            worst = max(abs(a / b - 1) for a, b in pairs)
            same = "matches" if worst < 1e-3 else "differs from"
            parts.append(f"MuJoCo's implicitfast {same} its Euler on {what} (largest relative "
                         f"difference {worst:.1e}): with no damping and no velocity-dependent force "
                         f"its implicit correction has nothing to act on.")  # fmt: skip
    eul = [(_get(rows, f"{e} euler{p}", dt, "energy_drift"), _get(rows, f"{e} rk4{p}", dt, "energy_drift"))
           for e, p in (("fastrl", " float64"), ("MuJoCo C", "")) for dt in dts]  # fmt: skip
    eul = [e / r for e, r in eul if e and r]
    if eul:
        parts.append(f"RK4's energy drift is {min(eul):.0e} to {max(eul):.0e} times smaller than "
                     f"Euler's at the same timestep (both engines).")  # fmt: skip
    return parts


def summary(result: dict) -> str:
    """One paragraph, every claim computed from the rows."""
    rows, dts = result["rows"], result["protocol"]["timesteps"]
    parts = [*_orders(rows, dts), *_agreement(rows, dts), *_float32_floor(rows, dts),
             *_mujoco_integrators(rows, dts)]  # fmt: skip
    return " ".join(parts)


def markdown(result: dict) -> str:
    p, v = result["protocol"], result["validation"]
    cmd = "python -m experiments.conservation" + (" --quick" if p["quick"] else "")
    lines = ["# Conservation: momentum and energy drift vs timestep", "",
             f"Machine: {result['machine']}. Command: `{cmd}`.", "",
             "A free-floating Ant (no gravity, contacts, damping, armature, springs or limits) is "
             f"kicked (random initial velocity; kinetic energy {v['E0']:.3g} J), driven by random "
             f"joint torques for {p['phase1_s']:g} s (phase 1: internal forces, so linear and angular "
             f"momentum must stay constant), then coasts with controls off for {p['phase2_s']:g} s "
             "(phase 2: energy must stay constant). Momentum drift: the largest relative change over "
             "phase 1 of P or of L about the centre of mass. Energy drift: the largest relative change "
             f"over phase 2 of the energy. Sampled every {SAMPLE_S:g} s, measured for both engines by "
             "MuJoCo's float64 functions on the recorded states; at t = 0 fastrl's own float64 momentum "
             f"and energy agree with them to {v['max_relative_difference']:.1e} (relative). Speed: "
             "simulated s per wall s of one trajectory (fastrl: jitted, on CPU, after compilation; MuJoCo C: "
             "`mujoco.rollout`, one thread), the best of up to 3 runs on a shared CPU: a rough axis (fastrl "
             "is built for large batches; one trajectory shows its per-step latency, not its "
             "throughput).", "",
             "| engine | integrator | precision | timestep (s) | momentum drift | energy drift | "
             "sim s / wall s |",
             "| --- | --- | --- | ---: | ---: | ---: | ---: |"]  # fmt: skip
    fmt = lambda x: "diverged" if x is None else f"{x:.2e}"
    order = list(STYLES)
    for r in sorted(result["rows"], key=lambda r: (order.index(r["label"]), r["timestep"])):
        lines.append(f"| {r['engine']} | {r['integrator']} | {r['precision']} | {r['timestep']:g} | "
                     f"{fmt(r['momentum_drift'])} | {fmt(r['energy_drift'])} | "
                     f"{r['sim_s_per_wall_s']:,.0f} |")  # fmt: skip
    lines += ["", summary(result), ""]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 timesteps, 0.2 s phases, for CI")
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS)
    args = parser.parse_args()
    timesteps = QUICK_TIMESTEPS if args.quick else TIMESTEPS
    problem = make_problem(*((QUICK_PHASE_S, QUICK_PHASE_S) if args.quick else (PHASE1_S, PHASE2_S)))
    validation = validate(problem)
    print(f"measurement check at t = 0: {validation['max_relative_difference']:.1e}", flush=True)
    rows = sweep_fastrl(problem, timesteps, args.quick) + sweep_mujoco(problem, timesteps)

    protocol = {"quick": args.quick, "timesteps": timesteps, "phase1_s": problem["phase1_s"],
                "phase2_s": problem["phase2_s"], "sample_s": SAMPLE_S, "hold_s": HOLD_S, "seed": SEED,
                "kick_qvel": problem["qvel"].tolist()}  # fmt: skip
    result = {"machine": results.machine(), "protocol": protocol, "validation": validation, "rows": rows}
    text = markdown(result)
    results.save(
        args.out, "conservation_quick" if args.quick else "conservation", result, text, chart(result)
    )
    print(text)


if __name__ == "__main__":
    fastrl.use_recommended_xla_flags()  # the XLA:CPU flags fastrl's command line runs with
    main()
