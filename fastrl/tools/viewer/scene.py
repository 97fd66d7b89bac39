"""The scene a viewer draws: the model's geoms and every body's world pose per frame.

Poses come from fastrl's own forward kinematics (``physics.smooth.kinematics``, the stage of
``physics.forward`` that fills ``xpos``/``xquat``) run over the trajectory's ``qpos``. What
fastrl's ``Model`` does not keep because the physics never needs it (colours, groups, meshes)
is read from the MuJoCo model compiled from the env's MJCF file.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import jax
import mujoco
import numpy as np

from fastrl import physics
from fastrl.envs.base import ASSETS
from fastrl.physics import smooth
from fastrl.physics.types import GeomType

# Geom groups MuJoCo's own viewer shows by default (3-5 hold collision-only or helper geoms).
VISIBLE_GROUPS = (0, 1, 2)
# Decimals kept in the embedded trajectory: 0.1 mm and 1e-4 of a unit quaternion.
DECIMALS = 4


def asset_path(env, asset: str | Path | None = None) -> Path:
    """The MJCF file of ``env``, resolved as ``Env.__init__`` does (``asset`` overrides it)."""
    path = Path(asset or type(env).asset)
    if not path.is_absolute() and not path.exists():
        path = ASSETS / path
    return path


def load_mj_model(env, asset: str | Path | None = None) -> mujoco.MjModel:
    """MuJoCo's compiled model of ``env``'s MJCF, checked to match the env's fastrl model."""
    m = mujoco.MjModel.from_xml_path(str(asset_path(env, asset)))
    fm = env.model
    if (m.nbody, m.ngeom, m.nq) != (fm.nbody, fm.ngeom, fm.nq):
        raise ValueError(
            f"{asset_path(env, asset)} has {m.nbody} bodies, {m.ngeom} geoms, nq={m.nq}, but the "
            f"env's model has {fm.nbody}, {fm.ngeom}, {fm.nq}: pass the env's own asset= file"
        )
    return m


def body_poses(model: physics.Model, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World poses of every body along a trajectory, by fastrl's forward kinematics.

    Args:
      model: the env's fastrl ``Model``.
      qpos: (T, nq) positions.
    Returns:
      xpos (T, nbody, 3), xquat (T, nbody, 4) and geom_xpos (T, ngeom, 3), as in ``mjData``.
    """

    def one(q):
        d = smooth.kinematics(model, physics.make_data(model, qpos=q))
        return d.xpos, d.xquat, d.geom_xpos

    # A viewer is an entry point, so it jits here: one small program over the whole trajectory.
    out = jax.device_get(jax.jit(jax.vmap(one))(np.asarray(qpos, model.body_mass.dtype)))
    return tuple(np.asarray(x) for x in out)


def _static_geoms(m: mujoco.MjModel) -> tuple[list[dict], list[dict]]:
    """The drawable geoms (type, size, colour, body, pose in the body) and the meshes they use."""
    geoms, meshes, mesh_index = [], [], {}
    for g in range(m.ngeom):
        rgba = m.mat_rgba[m.geom_matid[g]] if m.geom_matid[g] >= 0 else m.geom_rgba[g]
        if m.geom_group[g] not in VISIBLE_GROUPS or rgba[3] <= 0 or m.geom_type[g] == GeomType.HFIELD:
            continue
        mesh = -1
        if m.geom_type[g] == GeomType.MESH:
            mid = int(m.geom_dataid[g])
            if mid not in mesh_index:
                va, vn = m.mesh_vertadr[mid], m.mesh_vertnum[mid]
                fa, fn = m.mesh_faceadr[mid], m.mesh_facenum[mid]
                mesh_index[mid] = len(meshes)
                meshes.append(
                    {
                        "vert": _rounded(m.mesh_vert[va : va + vn]),
                        "face": m.mesh_face[fa : fa + fn].reshape(-1).tolist(),
                    }
                )
            mesh = mesh_index[mid]
        geoms.append(
            {
                "name": mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}",
                "type": int(m.geom_type[g]),
                "size": _rounded(m.geom_size[g]),
                "rgba": _rounded(rgba),
                "body": int(m.geom_bodyid[g]),
                "pos": _rounded(m.geom_pos[g]),
                "quat": _rounded(m.geom_quat[g]),
                "mesh": mesh,
            }
        )
    return geoms, meshes


def _rounded(x) -> list:
    return np.round(np.asarray(x, np.float64), DECIMALS).tolist()


def root_body(m: mujoco.MjModel) -> int:
    """The body a follow camera tracks: the first child of the world that moves (else the world)."""
    moving = [b for b in range(1, m.nbody) if m.body_parentid[b] == 0 and m.body_weldid[b] != 0]
    return moving[0] if moving else 0


def _framing(m: mujoco.MjModel, root_pos: np.ndarray, geom_xpos: np.ndarray) -> tuple[float, float]:
    """(radius, ground z) at the first frame: how far the geoms reach from the root body, and
    the lowest point of any geom (where a ground grid goes when the model has no plane)."""
    solid = m.geom_type != GeomType.PLANE
    if not solid.any():
        return 1.0, 0.0
    centres = geom_xpos[solid]
    reach = np.linalg.norm(centres - root_pos, axis=1) + m.geom_rbound[solid]
    ground = float((centres[:, 2] - m.geom_rbound[solid]).min())
    return max(float(reach.max()), 0.1), ground


def build_scene(
    env,
    qpos: np.ndarray,
    title: str = "",
    asset: str | Path | None = None,
    markers: np.ndarray | None = None,
    overflow: np.ndarray | None = None,
) -> dict:
    """The JSON-ready scene of a trajectory of ``env``: static geoms plus per-frame body poses.

    Args:
      env: a fastrl env (its ``model``, ``dt`` and MJCF asset are used).
      qpos: (T, nq) positions, e.g. from ``fastrl.tools.evaluate.rollout_qpos``.
      title: a line shown above the view.
      asset: the env's MJCF file when it was built with a non-default ``asset=``.
      markers: (T, M, 3) goal positions per frame (None: none).
      overflow: (T,) contacts the scene's budgets dropped per frame (None: none).
    Returns:
      A dict: ``geoms`` (type, size, rgba, body, pos, quat, mesh), ``meshes``, ``nbody``,
      ``nframe``, ``dt``, ``root`` (body to follow), ``radius``, ``ground``, ``has_plane`` and
      ``frames``, the (T, nbody, 7) poses ``[x, y, z, qw, qx, qy, qz]`` flattened, and
      ``nmarker`` with ``markers``, the (T, M, 3) goal positions flattened, and ``overflow``, the
      (T,) dropped contacts (empty when none were given).
    """
    qpos = np.asarray(qpos)
    markers = np.zeros((len(qpos), 0, 3)) if markers is None else np.asarray(markers, float)
    if markers.ndim != 3 or markers.shape[0] != len(qpos) or markers.shape[2] != 3:
        raise ValueError(f"markers has shape {markers.shape}; expected ({len(qpos)}, M, 3)")
    overflow = np.zeros(0) if overflow is None else np.asarray(overflow)
    if overflow.size and overflow.shape != (len(qpos),):
        raise ValueError(f"overflow has shape {overflow.shape}; expected ({len(qpos)},)")
    if qpos.ndim != 2 or qpos.shape[1] != env.model.nq or len(qpos) == 0:
        raise ValueError(f"qpos has shape {qpos.shape}; expected (T, {env.model.nq}) with T >= 1")
    m = load_mj_model(env, asset)
    xpos, xquat, geom_xpos = body_poses(env.model, qpos)
    geoms, meshes = _static_geoms(m)
    root = root_body(m)
    radius, ground = _framing(m, xpos[0, root], geom_xpos[0])
    frames = np.concatenate([xpos, xquat], axis=-1)
    return {
        "title": title or env.name,
        "dt": float(env.dt),
        "nframe": int(len(qpos)),
        "nbody": int(m.nbody),
        "root": root,
        "radius": round(radius, 3),
        "ground": round(ground, 3),
        "has_plane": bool(any(g["type"] == GeomType.PLANE for g in geoms)),
        "geoms": geoms,
        "meshes": meshes,
        "frames": _rounded(frames.reshape(-1)),
        "nmarker": int(markers.shape[1]),
        "markers": _rounded(markers.reshape(-1)),
        "overflow": [int(round(float(x))) for x in overflow],
    }


def scene_json(scene: dict) -> str:
    """Compact JSON of a scene, safe to embed in an HTML ``<script>`` element."""
    text = json.dumps(scene, separators=(",", ":"))
    text = re.sub(r"(?<=\d)\.0(?=[,\]}])", "", text)  # 1.0 -> 1: a quarter of the floats are whole
    return text.replace("</", "<\\/")
