"""Gravity compensation (body gravcomp, joint actuatorgravcomp) against MuJoCo C; the
stage-by-stage and trajectory checks run on the same asset in test_oracle.py."""

from __future__ import annotations

import jax
import mujoco
import numpy as np
import pytest

from fastrl import physics
from fastrl.physics.passive import gravcomp
from tests.conftest import asset


def test_gravity_compensation_matches_mujoco_and_counts_against_actuator_limits(x64):
    """In the gravcomp asset the compensation forces match MuJoCo C;
    the wrist's compensation goes through its actuator and is clamped by actuatorfrcrange."""
    mj = mujoco.MjModel.from_xml_path(asset("gravcomp"))
    md = mujoco.MjData(mj)
    m = physics.model_from_mujoco(mj)
    d = jax.jit(physics.forward)(m, physics.make_data(m))
    mujoco.mj_forward(mj, md)
    np.testing.assert_allclose(gravcomp(m, d), md.qfrc_gravcomp, atol=1e-12)
    np.testing.assert_allclose(d.qfrc_actuator, md.qfrc_actuator, atol=1e-12)
    wrist = mj.jnt_dofadr[mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, "wrist")]
    assert abs(md.qfrc_gravcomp[wrist]) > 0.05  # clamped to 0.05 in qfrc_actuator, not passive
    assert abs(float(d.qfrc_actuator[wrist])) == pytest.approx(0.05)
    assert float(d.qfrc_passive[wrist]) == pytest.approx(0.0)
