"""Scene summary: what the compiled program will model.

    python -m fastrl.tools.scene_info MODEL.xml [--integrator rk4] [--solver-iterations 8]

Prints bodies, joints and dofs, geoms, the candidate contact pairs kept (by geom-type pair) out
of all geom pairs, and the static constraint-row budget the solver works with.
"""

from __future__ import annotations

import argparse
import collections

import mujoco
import numpy as np

from fastrl.physics import actuation, collision_driver, constraint, equality, io, io_checks, tendon
from fastrl.physics.types import GeomType, JointType, Model


def _collision(m: Model) -> str:
    """Each geom-type pair's method and candidate contacts per pair."""
    parts: dict[str, list[int]] = {}
    for key, idx in collision_driver.pair_groups(m):
        types = collision_driver.key_types(key)
        name = "-".join("/".join(GeomType(t).name.lower() for t in np.atleast_1d(side)) for side in types)
        each = collision_driver.candidates_per_pair(m, key, idx)
        if key in collision_driver.FACE_CLIPPED:
            how = f"GJK/EPA and face clipping, {each} each"
        elif collision_driver.is_gjk(key):
            how = f"GJK/EPA, {each} each"
        elif GeomType.HFIELD in key:
            rows, cols = (int(w) for w in m.pair_window[idx].max(axis=0))
            how = f"{rows}x{cols}-cell window, {each} each"
        else:
            how = f"{each} each"
        entry = parts.setdefault(f"{name} ({how}", [0, 0, 0])
        entry[0] += idx.size
        cap = m.max_geom_pairs if collision_driver.capped(m, key) else idx.size
        if collision_driver.is_gjk(key):
            gjk, epa = collision_driver.gjk_slots(idx.size)
            entry[1] += min(gjk, cap)
            entry[2] += min(epa, gjk, cap)
        else:
            entry[1] += min(idx.size, cap)
    out = []
    for label, (n, kept, epa) in parts.items():
        if epa and epa < n:
            culled = f"; GJK on {kept}, EPA on {epa} per step)"
        elif not epa and kept < n:
            culled = f"; {kept} collided per step)"
        else:
            culled = ")"
        out.append(f"{n} {label}{culled}")
    if m.max_geom_pairs > 0:
        out.append(f"MJX's max_geom_pairs {m.max_geom_pairs} per pair group")
    return ", ".join(out) or "none"


def summary_lines(m: Model) -> list[str]:
    """Human-readable description of a ``Model``'s size and static structure."""
    joints = collections.Counter(JointType(t).name.lower() for t in m.jnt_type)
    geoms = collections.Counter(GeomType(t).name.lower() for t in m.geom_type)
    pairs = collections.Counter(
        f"{GeomType(m.geom_type[a]).name.lower()}-{GeomType(m.geom_type[b]).name.lower()}"
        for a, b in zip(m.pair_geom1, m.pair_geom2, strict=True)
    )
    ncon, nefc = constraint.sizes(m)
    nlim = constraint.limited_joints(m).size + constraint.limited_tendons(m).size
    nfric = constraint.nfriction(m)
    condims = ", ".join(f"{n} x {dim}" for dim, _, n in constraint.contact_groups(m)) or "none"
    all_pairs = m.ngeom * (m.ngeom - 1) // 2
    eq_kinds = collections.Counter(mujoco.mjtEq(t).name[5:].lower() for t in m.eq_type)
    kinds = ", ".join(f"{n} {k}" for k, n in sorted(eq_kinds.items())) or "none"
    off = int((m.eq_active0 == 0).sum())
    ne = equality.nrows(m)
    fmt = lambda c: ", ".join(f"{n} {k}" for k, n in sorted(c.items())) or "none"  # noqa: E731
    return [
        f"bodies          {m.nbody - 1} (+ world)",
        f"joints          {m.njnt} ({fmt(joints)}); nq {m.nq}, nv {m.nv}",
        f"actuators       {m.nu}",
        f"activation      {_activation(m)}",
        f"tendons         {_tendons(m)}",
        f"geoms           {m.ngeom} ({fmt(geoms)})",
        f"contact pairs   {m.npair} kept of {all_pairs} geom pairs ({fmt(pairs)})",
        f"collision       {_collision(m)}",
        f"contacts        {ncon} candidates (fixed count, active when within margin); "
        f"rows for the {constraint.contact_slots(m)} deepest (nconmax {m.nconmax})",
        f"limits          {constraint.limited_joints(m).size} joints, "
        f"{constraint.limited_tendons(m).size} tendons (one row each)",
        f"friction loss   {constraint.friction_dofs(m).size} dofs, "
        f"{constraint.friction_tendons(m).size} tendons (one row each)",
        f"mocap bodies    {m.mocap_bodies.size} (posed by Data.mocap_pos/mocap_quat)",
        f"equalities      {m.eq_type.size} ({kinds}; {off} off at reset), {ne} rows",
        f"gravity comp.   {m.gravcomp_bodies.size} bodies",
        f"constraint rows {nefc} ({f'{ne} equality + ' if ne else ''}{nfric} friction loss + {nlim} limit + "
        f"{nefc - ne - nfric - nlim} contact, "
        f"{'elliptic' if constraint.elliptic(m) else 'pyramidal'} cone; contact slots by condim: {condims})",
        f"solver          {'none traced' if nefc == 0 else _solver(m)}",
        f"noslip          {_noslip(m) if nefc else 'none traced'}",
        f"integrator      {m.summary().split('integrator ')[1]}",
    ]


def _solver(m: Model) -> str:
    if m.linesearch == "exact":
        return f"Newton, {m.solver_iterations} iterations, exact line searches"
    return (
        f"Newton as MuJoCo's (islands, tolerance {m.solver_tolerance:g}, up to {m.ls_iterations} "
        f"line-search evaluations), at most {m.solver_iterations} iterations"
    )


def _activation(m: Model) -> str:
    """``N act (a filter, b integrator; c actearly, d clamped to actrange)``, or none."""
    dyn = actuation.dynamic_actuators(m)
    if not dyn.size:
        return "none (every force from ctrl)"
    kinds = collections.Counter(mujoco.mjtDyn(t).name[6:].lower() for t in m.actuator_dyntype[dyn])
    early, limited = int(m.actuator_actearly[dyn].sum()), int(m.actuator_actlimited[dyn].sum())
    kind = ", ".join(f"{n} {k}" for k, n in sorted(kinds.items()))
    return f"{m.na} activations ({kind}; {early} actearly, {limited} clamped to actrange)"


def _noslip(m: Model) -> str:
    """The noslip post-pass and the rows it re-solves, or off."""
    if not m.noslip_iterations:
        return "off"
    cones = sum(n for dim, _, n in constraint.contact_groups(m) if dim > 1)
    return (
        f"up to {m.noslip_iterations} Gauss-Seidel sweeps (tolerance {m.noslip_tolerance:g}) over "
        f"{constraint.nfriction(m)} friction-loss rows and the friction of {cones} contact slots"
    )


def _tendons(m: Model) -> str:
    """``N (a fixed, b spatial; c actuated)``: the simulated tendons (none when all are inert)."""
    fixed = int(tendon.is_fixed(m).sum())
    driven = np.unique(m.actuator_trnid[m.actuator_trntype == int(mujoco.mjtTrn.mjTRN_TENDON)]).size
    return f"{m.ntendon} ({fixed} fixed, {m.ntendon - fixed} spatial; {driven} actuated)"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m fastrl.tools.scene_info", description=__doc__.splitlines()[0]
    )
    parser.add_argument("model", help="an MJCF file")
    parser.add_argument("--integrator", choices=["euler", "rk4", "implicitfast"], default=None)
    parser.add_argument("--solver-iterations", type=int, default=None, help="default: the model's own")
    args = parser.parse_args(argv)
    try:
        m = io.load_mjcf(args.model, integrator=args.integrator, solver_iterations=args.solver_iterations)
    except (io_checks.UnsupportedFeatureError, FileNotFoundError, ValueError) as err:
        parser.exit(2, f"error: {err}\n")
    mj_name = mujoco.MjModel.from_xml_path(args.model).names.split(b"\0")[0].decode() or args.model
    print(f"{mj_name}: {args.model}")
    print("\n".join("  " + line for line in summary_lines(m)))


if __name__ == "__main__":
    main()
