"""Static tables derived from a model's kinematic tree, computed with numpy while tracing.

They turn the recursions of rigid-body dynamics into a few dense operations with constant
matrices (subtree sums, ancestor sums), which XLA:CPU runs far faster than per-body loops.
"""

from __future__ import annotations

import numpy as np

from fastrl.physics.types import JointType, Model


def body_levels(m: Model) -> list[np.ndarray]:
    """Bodies grouped by depth (world excluded), parents always in an earlier group."""
    depth = np.zeros(m.nbody, np.int64)
    for b in range(1, m.nbody):
        depth[b] = depth[m.body_parentid[b]] + 1
    return [np.flatnonzero(depth == k) for k in range(1, int(depth.max(initial=0)) + 1)]


def body_ancestors(m: Model) -> np.ndarray:
    """(nbody, nbody) 0/1 matrix: ``[i, j] = 1`` iff body j is i or an ancestor of i (not world)."""
    a = np.zeros((m.nbody, m.nbody))
    for b in range(1, m.nbody):
        j = b
        while j > 0:
            a[b, j] = 1.0
            j = m.body_parentid[j]
    return a


def body_dof_ancestors(m: Model) -> np.ndarray:
    """(nbody, nv) 0/1 matrix: ``[b, d] = 1`` iff dof d moves body b (d in b or an ancestor)."""
    return body_ancestors(m)[:, m.dof_bodyid]


def dof_ancestors(m: Model) -> list[list[int]]:
    """For each dof, its strict ancestors in the dof tree, nearest first."""
    out = []
    for i in range(m.nv):
        chain, j = [], m.dof_parentid[i]
        while j >= 0:
            chain.append(int(j))
            j = m.dof_parentid[j]
        out.append(chain)
    return out


def dof_levels(m: Model) -> list[np.ndarray]:
    """Dofs grouped by depth in the dof tree (roots first), parents always in the group before."""
    depth = np.zeros(m.nv, np.int64)
    for i in range(m.nv):  # a dof's parent comes before it
        p = m.dof_parentid[i]
        depth[i] = depth[p] + 1 if p >= 0 else 1
    return [np.flatnonzero(depth == k) for k in range(1, int(depth.max(initial=0)) + 1)]


def body_inertia_dof(m: Model) -> np.ndarray:
    """(nbody,) the dof whose articulated inertia carries each body's inertia: the last dof of the
    nearest body at or above it that has dofs (-1 for bodies welded to the world)."""
    out = np.full(m.nbody, -1, np.int64)
    for b in range(1, m.nbody):  # a body's parent comes before it
        n = m.body_dofnum[b]
        out[b] = m.body_dofadr[b] + n - 1 if n else out[m.body_parentid[b]]
    return out


def dof_ancestor_mask(m: Model) -> np.ndarray:
    """(nv, nv) 0/1 lower-triangular mask: ``[i, j] = 1`` iff dof j is i or an ancestor of i.

    It is the sparsity pattern of the mass matrix's lower triangle.
    """
    mask = np.eye(m.nv)
    for i, chain in enumerate(dof_ancestors(m)):
        mask[i, chain] = 1.0
    return mask


def is_free_translation(m: Model) -> np.ndarray:
    """(nv,) bool: the three world-axis translational dofs of each free joint."""
    out = np.zeros(m.nv, bool)
    for j in np.flatnonzero(m.jnt_type == JointType.FREE):
        out[m.jnt_dofadr[j] : m.jnt_dofadr[j] + 3] = True
    return out


def dof_velocity_before(m: Model) -> np.ndarray:
    """(nv, nv) 0/1 matrix selecting, for each dof, the dofs whose motion precedes it.

    MuJoCo's ``mj_comVel`` forms ``cdof_dot = cvel x cdof`` with the body velocity accumulated up
    to (not including) the dof's own joint: ancestors' dofs, earlier joints of the same body, and
    for a free joint's rotations its own translations.
    """
    out = np.zeros((m.nv, m.nv))
    anc = body_dof_ancestors(m)
    for d in range(m.nv):
        b, j = m.dof_bodyid[d], m.dof_jntid[d]
        out[d] = anc[m.body_parentid[b]] if b > 0 else 0.0
        first = m.body_dofadr[b]
        out[d, first : m.jnt_dofadr[j]] = 1.0
        if m.jnt_type[j] == JointType.FREE and d >= m.jnt_dofadr[j] + 3:
            out[d, m.jnt_dofadr[j] : m.jnt_dofadr[j] + 3] = 1.0
    return out


def joint_actuators(m: Model) -> np.ndarray:
    """The actuators with a joint transmission (the others drive tendons)."""
    return np.flatnonzero(m.actuator_trntype == 0)  # mjTRN_JOINT


def actuator_moment_pattern(m: Model) -> np.ndarray:
    """(nv, nu) 0/1 matrix: ``[d, u] = 1`` iff actuator u's joint transmission drives dof d."""
    out = np.zeros((m.nv, m.nu))
    joint = joint_actuators(m)
    out[m.jnt_dofadr[m.actuator_trnid[joint]], joint] = 1.0
    return out
