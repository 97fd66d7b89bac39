"""Torsional (condim 4) and rolling (condim 6) friction under the pyramidal and the elliptic cone,
against MuJoCo C: a box spinning on a plane, a ball rolling to rest, a box sliding (condim 3)."""

from __future__ import annotations

import jax
import mujoco
import numpy as np
import pytest

from fastrl import physics

SCENE = """
<mujoco>
  <option timestep="0.005" cone="{cone}" impratio="{impratio}"/>
  <worldbody>
    <geom type="plane" size="3 3 .1" condim="{condim}" friction="0.8 0.05 0.01"/>
    <body pos="0 0 {height}">
      <freejoint/>
      <geom type="{shape}" size="{size}" condim="{condim}" friction="0.6 0.03 0.02"/>
    </body>
  </worldbody>
</mujoco>
"""
SPINNING_BOX = dict(shape="box", size="0.1 0.1 0.05", height=0.0495, condim=4, qvel=[0, 0, 0, 0, 0, 20.0])
ROLLING_BALL = dict(shape="sphere", size="0.1", height=0.0995, condim=6, qvel=[1.5, 0.5, 0, -5.0, 15.0, 1.0])
SLIDING_BOX = dict(shape="box", size="0.1 0.1 0.05", height=0.0495, condim=3, qvel=[2.0, 1.0, 0, 0, 0, 3.0])
CASES = pytest.mark.parametrize(
    "case", [SPINNING_BOX, ROLLING_BALL, SLIDING_BOX], ids=["torsion", "rolling", "sliding"]
)
CONES = pytest.mark.parametrize("cone", ["pyramidal", "elliptic"])


def _scene(case, impratio=1.0, cone="pyramidal"):
    xml = SCENE.format(cone=cone, impratio=impratio, **{k: v for k, v in case.items() if k != "qvel"})
    mj = mujoco.MjModel.from_xml_string(xml)
    # MuJoCo's Newton solver stops at a tolerance (1e-8 of the cost's scale), fastrl's runs its
    # static count: the oracle is asked to converge so that both are the same minimiser.
    mj.opt.tolerance = 1e-14
    return mj, physics.model_from_mujoco(mj)


@CASES
@CONES
@pytest.mark.parametrize("impratio", [1.0, 3.0])
def test_rows_and_forces_match_mujoco(case, impratio, cone, x64):
    mj, m = _scene(case, impratio, cone)
    md = mujoco.MjData(mj)
    md.qpos[:] = mj.qpos0
    md.qvel[:] = case["qvel"]
    mujoco.mj_forward(mj, md)
    d = jax.jit(physics.forward)(m, physics.make_data(m, qpos=md.qpos.copy(), qvel=md.qvel.copy()))
    rows = case["condim"] if cone == "elliptic" else 2 * (case["condim"] - 1)
    assert md.ncon >= 1 and md.efc_J.size == md.ncon * rows * mj.nv
    ours = {}
    for k in range(int(np.asarray(d.contact_id).size)):  # our slots hold MuJoCo's contacts, any order
        a = physics.constraint.contact_efc_address(m)[k]
        if float(d.efc_D[a]) > 0:
            ours[round(float(d.efc_pos[a]), 9), tuple(np.round(np.asarray(d.efc_J[a]), 9))] = a
    mj_j = md.efc_J.reshape(md.nefc, mj.nv)
    for c in range(md.ncon):
        a = c * rows
        key = (round(md.efc_pos[a], 9), tuple(np.round(mj_j[a], 9)))
        assert key in ours, "a MuJoCo contact has no matching fastrl row block"
        o = ours[key]
        np.testing.assert_allclose(d.efc_J[o : o + rows], mj_j[a : a + rows], atol=1e-12)
        np.testing.assert_allclose(d.efc_D[o : o + rows], 1 / md.efc_R[a : a + rows], rtol=1e-10)
        np.testing.assert_allclose(
            d.efc_aref[o : o + rows], md.efc_aref[a : a + rows], rtol=1e-10, atol=1e-10
        )
        scale = np.abs(md.efc_force).max()
        np.testing.assert_allclose(d.efc_force[o : o + rows], md.efc_force[a : a + rows], atol=1e-6 * scale)
    np.testing.assert_allclose(d.qacc, md.qacc, rtol=1e-6, atol=1e-6 * np.abs(md.qacc).max())
    force = physics.sensor.contact_force(m, d)
    for c in range(md.ncon):  # each MuJoCo contact's force in its frame (mj_contactForce)
        want = np.zeros(6)
        mujoco.mj_contactForce(mj, md, c, want)
        assert np.abs(np.asarray(force) - want).max(-1).min() < 1e-6 * np.abs(want).max()


@CASES
@CONES
def test_spin_and_roll_come_to_rest_as_in_mujoco(case, cone, x64):
    mj, m = _scene(case, cone=cone)
    md = mujoco.MjData(mj)
    md.qvel[:] = case["qvel"]
    d = physics.make_data(m, qvel=md.qvel.copy())
    step = jax.jit(physics.step)
    worst = 0.0
    for _ in range(200):  # 1 s
        mujoco.mj_step(mj, md)
        d = step(m, d, np.zeros(0))
        worst = max(worst, float(np.abs(np.asarray(d.qpos) - md.qpos).max()))
    assert worst < 1e-6, f"qpos parted from MuJoCo's by {worst:.2e} within 1 s"
    # torsional / rolling friction took the spin and the roll out (MuJoCo's own result)
    if case is not SLIDING_BOX:
        spin = abs(md.qvel[5]) if case is SPINNING_BOX else np.abs(md.qvel[3:]).max()
        assert spin < 0.5 * np.abs(case["qvel"][3:]).max()


@pytest.mark.parametrize("case", [SPINNING_BOX, ROLLING_BALL], ids=["torsion", "rolling"])
@CONES
def test_contact_torques_reach_cfrc_ext(case, cone, x64):
    mj, m = _scene(case, cone=cone)
    md = mujoco.MjData(mj)
    md.qvel[:] = case["qvel"]
    mujoco.mj_forward(mj, md)
    mujoco.mj_rnePostConstraint(mj, md)
    d = jax.jit(physics.forward)(m, physics.make_data(m, qvel=md.qvel.copy()))
    ours = physics.sensor.cfrc_ext(m, d)
    assert np.abs(md.cfrc_ext[1, :3]).max() > 1e-3  # the contact torque is there to be seen
    np.testing.assert_allclose(ours, md.cfrc_ext, atol=1e-8 * np.abs(md.cfrc_ext).max())
