"""Passive joint forces: springs and dampers (mj_passive)."""

from __future__ import annotations

import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.physics.types import Data, JointType, Model

_DSBL = mujoco.mjtDisableBit


def passive(m: Model, d: Data) -> Data:
    """Spring ``-k (q - q_spring)`` on hinge/slide joints and damping ``-b qdot`` on every dof."""
    spring = jnp.zeros_like(d.qvel)
    scalar = np.flatnonzero((m.jnt_type == JointType.HINGE) | (m.jnt_type == JointType.SLIDE))
    if scalar.size and not m.disableflags & _DSBL.mjDSBL_SPRING:
        adr = m.jnt_qposadr[scalar]
        stretch = d.qpos[adr] - m.qpos_spring[adr]
        spring = spring.at[m.jnt_dofadr[scalar]].set(-m.jnt_stiffness[scalar] * stretch)
    damper = jnp.zeros_like(d.qvel)
    if not m.disableflags & _DSBL.mjDSBL_DAMPER:
        damper = -m.dof_damping * d.qvel
    return d.replace(qfrc_spring=spring, qfrc_damper=damper, qfrc_passive=spring + damper)
