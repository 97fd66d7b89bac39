"""Where fastrl's height-field contacts part from MuJoCo C's, and which side MuJoCo C's own
convex collision takes.

    python -m experiments.hfield_contacts            # the rough-terrain scenes (~1 min)
    python -m experiments.hfield_contacts --quick --out DIR    # one scene, for CI

Two of Playground's rough-terrain scenes part from MuJoCo C within their first contacts even with
both solvers converged (``robot_coverage.md``). This script finds where and why. For each scene,
MuJoCo C steps from the first keyframe with its ``ctrl`` held, converged as robot_coverage's
``converged`` comparison runs it; before each step fastrl computes its contacts from MuJoCo C's
state (float64, ``physics.forward``). At the first step where the contacts of a geom against the
height field differ (their count, or a depth by more than ``DEPTH_TOL``), three answers are put
side by side for that geom:

    height field   the contacts MuJoCo C's height-field routine reports (``mjData.contact``):
                   each cell's two triangles are prisms, each tested by GJK/EPA
    fastrl         fastrl's contacts (one per prism of the window)
    as meshes      MuJoCo C's own convex collision (GJK/EPA, converged) of the same geom against
                   each prism of the window given to it as a mesh geom: a second opinion on the
                   same geometry, from MuJoCo C itself; the deepest contact per prism

Depths are in mm; ``-`` means no contact. Writes ``experiments/results/hfield_contacts.{md,json}``.
"""

from __future__ import annotations

import argparse
import pathlib

import jax
import mujoco
import numpy as np

from experiments import results
from experiments import robot_coverage as coverage
from fastrl import physics
from fastrl.envs.robots import assets
from fastrl.physics import collision_driver

SCENES = (
    "playground/locomotion/berkeley_humanoid/scene_mjx_feetonly_rough_terrain",
    "playground/locomotion/g1/scene_mjx_feetonly_rough_terrain",
)
DEPTH_TOL = 1e-7  # m: contacts that differ by more
AGREE_TOL = 1e-5  # m: a side agrees with the mesh opinion within this (EPA's own spread is ~1e-6)


def _prisms(mj: mujoco.MjModel, d: mujoco.MjData, hf_geom: int, geom: int) -> np.ndarray:
    """(n, 6, 3) the prisms MuJoCo's height-field routine tests against ``geom`` (its sub-grid of
    cells from the geom's box in the field's frame; two triangles a cell, bottom face first), in
    the field's frame."""
    h = mj.geom_dataid[hf_geom]
    nrow, ncol = mj.hfield_nrow[h], mj.hfield_ncol[h]
    sx, sy, sz, base = mj.hfield_size[h]
    z = mj.hfield_data[mj.hfield_adr[h] : mj.hfield_adr[h] + nrow * ncol].reshape(nrow, ncol)
    frame = d.geom_xmat[hf_geom].reshape(3, 3)
    rot = frame.T @ d.geom_xmat[geom].reshape(3, 3)
    centre = frame.T @ (d.geom_xpos[geom] - d.geom_xpos[hf_geom])
    size = mj.geom_size[geom]
    if mj.geom_type[geom] == mujoco.mjtGeom.mjGEOM_BOX:
        extent = np.abs(rot) @ size
    elif mj.geom_type[geom] == mujoco.mjtGeom.mjGEOM_SPHERE:
        extent = np.full(3, size[0])
    else:
        raise ValueError(f"geom {geom}: only boxes and spheres are handled here")
    lo, hi = centre - extent, centre + extent
    cmin = max(0, int(np.floor((lo[0] + sx) / (2 * sx) * (ncol - 1))))
    cmax = min(ncol - 1, int(np.ceil((hi[0] + sx) / (2 * sx) * (ncol - 1))))
    rmin = max(0, int(np.floor((lo[1] + sy) / (2 * sy) * (nrow - 1))))
    rmax = min(nrow - 1, int(np.ceil((hi[1] + sy) / (2 * sy) * (nrow - 1))))
    dx, dy = 2 * sx / (ncol - 1), 2 * sy / (nrow - 1)

    def top(r, c):
        return np.array([dx * c - sx, dy * r - sy, z[r, c] * sz])

    out = []
    for r in range(rmin, rmax):
        for c in range(cmin + 1, cmax + 1):
            for tri in (
                (top(r + 1, c - 1), top(r, c - 1), top(r + 1, c)),
                (top(r, c - 1), top(r + 1, c), top(r, c)),
            ):
                upper = np.array(tri)
                lower = upper.copy()
                lower[:, 2] = -base
                out.append(np.concatenate([lower, upper]))
    return np.array(out)


def _quat(mat: np.ndarray) -> np.ndarray:
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, mat.reshape(-1))
    return q


def _as_mesh_depth(mj: mujoco.MjModel, d: mujoco.MjData, hf_geom: int, geom: int, prism: np.ndarray):
    """MuJoCo C's deepest contact (m, negative: penetration) of ``geom`` against ``prism`` given
    as a mesh geom at the field's pose, both converged; None without contact."""
    fmt = lambda x: " ".join(f"{v:.17g}" for v in np.ravel(x))  # noqa: E731
    field_pose = f'pos="{fmt(d.geom_xpos[hf_geom])}" quat="{fmt(_quat(d.geom_xmat[hf_geom]))}"'
    kind = mujoco.mjtGeom(mj.geom_type[geom]).name[len("mjGEOM_") :].lower()
    xml = f"""<mujoco><option><flag gravity="disable"/></option>
      <asset><mesh name="prism" vertex="{fmt(prism)}"/></asset>
      <worldbody>
        <geom type="mesh" mesh="prism" {field_pose}/>
        <body pos="{fmt(d.geom_xpos[geom])}" quat="{fmt(_quat(d.geom_xmat[geom]))}">
          <freejoint/><geom type="{kind}" size="{fmt(mj.geom_size[geom])}"/>
        </body>
      </worldbody></mujoco>"""
    m2 = coverage._converged(mujoco.MjModel.from_xml_string(xml))
    d2 = mujoco.MjData(m2)
    mujoco.mj_forward(m2, d2)
    return min((float(c.dist) for c in d2.contact[: d2.ncon]), default=None)


def scene(name: str, path: pathlib.Path, max_steps: int) -> dict:
    """The first step where fastrl's and MuJoCo C's height-field contacts differ, with the three
    answers for each geom that differs there (or ``step: None`` if none within ``max_steps``)."""
    mj = coverage._converged(mujoco.MjModel.from_xml_path(str(path)))
    with jax.enable_x64(True):
        model = physics.model_from_mujoco(mj, **coverage.MODEL_OPTIONS)
        forward = jax.jit(lambda d: physics.forward(model, d))
        layout = collision_driver.contact_layout(model)
        g1 = np.asarray(model.pair_geom1)[layout]
        g2 = np.asarray(model.pair_geom2)[layout]
        margin = np.asarray(model.pair_margin)[layout]
        field = np.flatnonzero(mj.geom_type == mujoco.mjtGeom.mjGEOM_HFIELD)
        d, _ = coverage._initial(mj)
        for step in range(max_steps):  # noqa: B007  (the step where it stops is reported)
            mujoco.mj_forward(mj, d)
            f = forward(physics.make_data(model, qpos=d.qpos.copy(), qvel=d.qvel.copy(), ctrl=d.ctrl.copy()))
            dist = np.asarray(f.contact_dist)
            geoms = {}
            for c in d.contact[: d.ncon]:
                if c.geom[0] in field:
                    geoms.setdefault((int(c.geom[0]), int(c.geom[1])), [[], []])[0].append(float(c.dist))
            for i in np.flatnonzero((dist < margin) & np.isin(g1, field)):
                geoms.setdefault((int(g1[i]), int(g2[i])), [[], []])[1].append(float(dist[i]))
            differ = {
                k: v
                for k, v in geoms.items()
                if len(v[0]) != len(v[1]) or np.abs(np.sort(v[0]) - np.sort(v[1])).max() > DEPTH_TOL
            }
            if differ:
                break
            mujoco.mj_step(mj, d)
        else:
            return {"step": None, "geoms": []}
    rows = []
    for (hf, geom), (mine, ours) in sorted(differ.items()):
        prisms = _prisms(mj, d, hf, geom)
        meshes = [_as_mesh_depth(mj, d, hf, geom, p) for p in prisms]
        rows.append(
            {
                "geom": mj.geom(geom).name or str(geom),
                "type": mujoco.mjtGeom(mj.geom_type[geom]).name[len("mjGEOM_") :].lower(),
                "prisms": len(prisms),
                "mujoco_hfield": sorted(mine),
                "fastrl": sorted(ours),
                "as_meshes": sorted(x for x in meshes if x is not None),
            }
        )
    return {"step": step, "time": step * mj.opt.timestep, "geoms": rows}


def _agree(a: list[float], b: list[float]) -> bool:
    return len(a) == len(b) and (not a or np.abs(np.sort(a) - np.sort(b)).max() <= AGREE_TOL)


def markdown(rows: dict, meta: dict) -> str:
    mm = lambda xs: ", ".join(f"{-1e3 * x:.3f}" for x in xs) or "-"  # noqa: E731
    lines, fastrl_agrees, mujoco_agrees, total = [], 0, 0, 0
    for name, r in rows.items():
        if r["step"] is None:
            lines.append(f"| `{name}` | none within {meta['max_steps']} steps | | | | | |")
            continue
        for g in r["geoms"]:
            total += 1
            ours, theirs = _agree(g["fastrl"], g["as_meshes"]), _agree(g["mujoco_hfield"], g["as_meshes"])
            fastrl_agrees += ours
            mujoco_agrees += theirs
            lines.append(
                f"| `{name}` | {r['step']} ({r['time']:.3f} s) "
                f"| {g['geom']} ({g['type']}, {g['prisms']} prisms) "
                f"| {mm(g['mujoco_hfield'])} | {mm(g['fastrl'])} | {mm(g['as_meshes'])} "
                f"| {'fastrl' if ours else ''}{' and ' if ours and theirs else ''}"
                f"{'MuJoCo height field' if theirs else ''}{'neither' if not (ours or theirs) else ''} |"
            )
    return "\n".join(
        [
            "# Height-field contacts: where fastrl and MuJoCo C part, and which one MuJoCo C's own "
            "convex collision agrees with",
            "",
            f"{meta['date']}, {meta['machine']}; fastrl {meta['fastrl']}, MuJoCo {meta['mujoco']}. "
            f"Command: `{meta['command']}`.",
            "",
            f"- **At the first step where the contacts differ, fastrl's depths equal MuJoCo C's "
            f"convex collision of the same prisms given as meshes for {fastrl_agrees} of {total} geoms; "
            f"MuJoCo C's height-field routine does for {mujoco_agrees}.** Both run converged "
            "(GJK/EPA at ccd_tolerance 1e-13, 1000 iterations), from the same MuJoCo C state.",
            "- Columns: penetration depths (mm) of the geom's contacts against the height field, "
            "one per prism that touches. *as meshes*: MuJoCo C's box-mesh (GJK/EPA) collision of "
            "the geom with each prism of its window, the prism given as a mesh geom at the field's "
            f"pose; the deepest contact per prism. A side agrees with the meshes when it has as many "
            f"contacts and each depth is within {AGREE_TOL * 1e3:g} mm.",
            "",
            "| scene | first step that differs | geom | MuJoCo height field | fastrl | MuJoCo as meshes "
            "| agrees with the meshes |",
            "| --- | ---: | --- | ---: | ---: | ---: | --- |",
            *lines,
        ]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="*", default=list(SCENES))
    parser.add_argument("--max-steps", type=int, default=500)
    parser.add_argument(
        "--quick", action="store_true", help="the last scene only (G1: its contacts part at step 6), for CI"
    )
    parser.add_argument("--out", type=pathlib.Path, default=results.RESULTS)
    args = parser.parse_args()
    names = args.scenes[-1:] if args.quick else args.scenes
    paths = assets.scene_paths()
    rows = {n: scene(n, paths[n], args.max_steps) for n in names}
    meta = {
        "date": results.today(),
        "machine": results.machine(),
        "fastrl": results.fastrl_version(),
        "mujoco": mujoco.__version__,
        "command": results.command(),
        "max_steps": args.max_steps,
    }
    stem = "hfield_contacts_quick" if args.quick else "hfield_contacts"
    results.save(args.out, stem, {"meta": meta, "rows": rows}, markdown(rows, meta))
    print(markdown(rows, meta))


if __name__ == "__main__":
    main()
