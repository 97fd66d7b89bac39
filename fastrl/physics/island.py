"""Constraint islands (MuJoCo's ``mj_island``, ``engine_island.c``).

Trees (a world child with its descendants) that share a constraint row form an island. MuJoCo's
Newton solver (``newton.py``) and no-slip pass (``noslip.py``) treat each island on its own, with
its own scale ``1 / sum(diag M)``. Islands are found in the traced program from which trees each
existing row's Jacobian touches (a transitive closure over the static trees), so every per-island
quantity is a vector over ``ntree`` possible islands.
"""

from __future__ import annotations

import typing

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.physics.solver import Rows
from fastrl.physics.types import Model


def each(onehot: jax.Array, per_island: jax.Array) -> jax.Array:
    """Each row's (or dof's) island's value, for a (k, r, ...) island map."""
    return jnp.tensordot(per_island, onehot, axes=1)


class Islands(typing.NamedTuple):
    """Each island's dofs and rows, as one-hot maps with the islands first: under ``vmap`` their
    products with per-row (or per-dof) vectors are batched dots that contract the maps' minor
    axis, which XLA:CPU runs several times faster than with the rows first (Leap's Newton solve at
    batch 1024, float32: 98 -> 49 us/env)."""

    dof: jax.Array  # (k, nv) one-hot: each constrained dof's island
    rows: tuple[jax.Array, ...]  # per row group of Rows.j (cones: per block), (k, r) one-hot
    scale: jax.Array  # (k,) 1 / island inertia; 0 where no island

    def per(self, x: jax.Array) -> jax.Array:
        """Sum of a per-dof quantity over each island."""
        return self.dof @ x

    def norm(self, x: jax.Array) -> jax.Array:
        return jnp.sqrt(self.per(x * x))

    def row_maps(self) -> tuple[jax.Array, ...]:
        """Per row group of ``Rows.j``, each row's island one-hot (cone blocks: per block row)."""
        fr, lim, con, eq, *cones = self.rows
        return (fr, lim, con, eq, *(c[:, :, None] for c in cones))


def _row_jacobians(rows: Rows, nv: int):
    """Each row group's |J| != 0 (r, nv) and whether each row exists (efc_D > 0)."""
    eye = np.eye(nv, dtype=bool)
    fr = jnp.concatenate([jnp.asarray(eye[rows.fr_dofs]), rows.tf_jac != 0])
    touch = [fr, jnp.asarray(eye[rows.lim_dofs]), rows.jac != 0, rows.eq_jac != 0]
    touch += [jnp.any(c.jac != 0, axis=1) for c in rows.cones]
    exist = [jnp.ones(fr.shape[0], bool), rows.lim_D > 0, rows.dd > 0, rows.eq_D > 0]
    exist += [c.dd[:, 0] > 0 for c in rows.cones]
    return touch, exist


def islands(m: Model, rows: Rows, qm: jax.Array) -> Islands:
    """The constraint islands of this step (mj_island), as one-hot maps over ``m.ntree`` slots."""
    nv, k = qm.shape[-1], m.ntree
    tree = np.eye(k)[m.dof_treeid]  # (nv, ntree)
    dtype = qm.dtype
    touch, exist = _row_jacobians(rows, nv)
    incid = [(t.astype(dtype) @ tree > 0) & e[:, None] for t, e in zip(touch, exist, strict=True)]
    if m.disableflags & mujoco.mjtDisableBit.mjDSBL_ISLAND:  # one island of every dof, MuJoCo's global scale
        dof = jnp.ones((1, nv), dtype)
        row_isl = tuple(jnp.any(b, axis=1, keepdims=True).astype(dtype).T for b in incid)
        return Islands(dof, row_isl, jnp.full((1,), 1.0 / (m.meaninertia * max(1, nv)), dtype))
    # boolean products as fused reductions (under vmap a ``@`` is one tiny product per env)
    b = jnp.concatenate(incid)
    adj = jnp.any(b[:, :, None] & b[:, None, :], axis=0)  # trees sharing a row
    constrained = jnp.diagonal(adj)
    reach = adj | jnp.eye(k, dtype=bool)
    for _ in range(int(np.ceil(np.log2(max(k, 2))))):
        reach = jnp.any(reach[:, :, None] & reach[None, :, :], axis=1)
    label = jnp.argmax(reach, axis=1)  # an island's id: its lowest tree
    tree_isl = (label[:, None] == np.arange(k)) & constrained[:, None]  # (tree, island)
    dof = jnp.any((tree.T > 0)[:, None, :] & tree_isl[:, :, None], axis=0).astype(dtype)
    row_isl = tuple(jnp.any(x.T[:, None, :] & tree_isl[:, :, None], axis=0).astype(dtype) for x in incid)
    inertia = dof @ jnp.diagonal(qm)
    scale = jnp.where(inertia > 0, 1.0 / jnp.where(inertia > 0, inertia, 1.0), 0.0)
    return Islands(dof, row_isl, scale)
