"""Contact slots (rows only for the deepest candidates), one row per limited joint, and the
Newton solver staying put once converged."""

from __future__ import annotations

import importlib
import pathlib

import jax
import mujoco
import numpy as np
import pytest

from fastrl import physics
from fastrl.physics import collision_driver, constraint

fwd = importlib.import_module("fastrl.physics.forward")
ANT = str(pathlib.Path(physics.__file__).parents[1] / "assets" / "ant.xml")


def _walk(mj, steps, seed=0):
    """MuJoCo states along a random-control walk of the Ant from its start pose."""
    md = mujoco.MjData(mj)
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        md.ctrl[:] = rng.uniform(-1, 1, mj.nu)
        mujoco.mj_step(mj, md)
        yield md


def _data(m, md):
    copy = lambda x: np.array(x, copy=True)  # noqa: E731  (MuJoCo reuses its buffers)
    d = physics.make_data(m, qpos=copy(md.qpos), qvel=copy(md.qvel), ctrl=copy(md.ctrl))
    return d.replace(qacc_warmstart=copy(md.qacc_warmstart))


def test_slots_hold_the_contacts_mujoco_makes_rows_for(x64):
    """Along a walk with falls, ``ncon`` equals MuJoCo's contact count, every contact within its
    margin has a slot, and ``qacc`` equals MuJoCo's (the rows are MuJoCo's rows)."""
    mj = mujoco.MjModel.from_xml_path(ANT)
    mj.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
    m = physics.model_from_mujoco(mj)
    assert constraint.contact_slots(m) == 8 < constraint.sizes(m)[0] == 25
    forward = jax.jit(lambda d: fwd.forward(m, d))
    seen = 0
    for md in _walk(mj, 80):
        mujoco.mj_forward(mj, md)
        d = forward(_data(m, md))
        assert int(d.ncon) == md.ncon
        within = np.flatnonzero(np.asarray(d.contact_dist) < 0)
        assert set(within) <= set(np.asarray(d.contact_id).tolist())
        np.testing.assert_allclose(d.qacc, md.qacc, rtol=0, atol=1e-7)
        seen = max(seen, md.ncon)
    assert seen >= 2, "the walk never made more than one contact"


def test_too_few_slots_keep_the_deepest_contacts(x64):
    """With 2 slots for a box lying flat (4 corner contacts), the slots hold the two deepest, and
    the two left out are counted (``contact_overflow``)."""
    xml = (
        '<mujoco><worldbody><geom type="plane" size="5 5 .1"/>'
        '<body pos="0 0 0.09" euler="3 0 0"><freejoint/><geom type="box" size=".2 .1 .1"/></body>'
        "</worldbody></mujoco>"
    )
    m = physics.load_mjcf(xml, nconmax=2)
    d = jax.jit(lambda d: fwd.forward(m, d))(physics.make_data(m))
    dist = np.asarray(d.contact_dist)
    assert int(d.ncon) == 4
    assert sorted(np.asarray(d.contact_id).tolist()) == sorted(np.argsort(dist)[:2].tolist())
    assert d.efc_J.shape[0] == 2 * 4
    assert int(d.contact_overflow) == 2 and physics.contact_budgeted(m)
    roomy = physics.load_mjcf(xml, nconmax=4)
    assert int(jax.jit(lambda d: fwd.forward(roomy, d))(physics.make_data(roomy)).contact_overflow) == 0
    assert not physics.contact_budgeted(roomy)


def test_gjk_budget_overflow_is_counted():
    """A box touching 40 small mesh cubes at once: GJK runs on 32 of the 40 pairs and EPA on 16
    (``collision_driver.gjk_slots``), so 24 touching pairs get no contact, and the step says so;
    with the cubes moved apart nothing is dropped."""
    cube = " ".join(f"{x} {y} {z}" for x in (-0.02, 0.02) for y in (-0.02, 0.02) for z in (-0.02, 0.02))
    spots = [
        (0.1 * np.cos(a), 0.1 * np.sin(a), 0.05 * (k % 3 - 1)) for k, a in enumerate(np.linspace(0, 6, 40))
    ]
    cubes = "".join(
        f'<geom name="c{k}" type="mesh" mesh="cube" pos="{x} {y} {z}"/>' for k, (x, y, z) in enumerate(spots)
    )
    pairs = "".join(f'<pair geom1="box" geom2="c{k}"/>' for k in range(40))
    xml = (
        f'<mujoco><asset><mesh name="cube" vertex="{cube}"/></asset><worldbody>'
        '<body><freejoint/><geom name="box" type="box" size=".11 .11 .1" contype="0" conaffinity="0"/></body>'
        f'<body pos="0 0 0"><freejoint/>{cubes}</body></worldbody><contact>{pairs}</contact></mujoco>'
    )
    m = physics.load_mjcf(xml, nconmax=400)
    assert collision_driver.gjk_slots(40) == (32, 16)
    forward = jax.jit(lambda q: fwd.forward(m, physics.make_data(m, qpos=q)))
    d = forward(physics.make_data(m).qpos)
    assert int(d.contact_overflow) == 40 - 16
    apart = physics.make_data(m).qpos.at[9].add(5.0)  # the cubes' body 5 m away
    assert int(forward(apart).contact_overflow) == 0


def test_converged_newton_iterate_stays_put(x64):
    """Many more Newton iterations than needed give MuJoCo's ``qacc`` to rounding: a converged
    iterate is not thrown off by the line search (its step is rounding noise)."""
    mj = mujoco.MjModel.from_xml_path(ANT)
    mj.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
    for iterations in (8, 40):
        m = physics.model_from_mujoco(mj, solver_iterations=iterations)
        forward = jax.jit(lambda d, m=m: fwd.forward(m, d))
        for i, md in enumerate(_walk(mj, 40)):
            if i % 4 == 0 and md.ncon:
                mujoco.mj_forward(mj, md)
                np.testing.assert_allclose(forward(_data(m, md)).qacc, md.qacc, rtol=0, atol=1e-7)


def test_bad_slot_counts_and_narrow_ranges_are_refused():
    with pytest.raises(ValueError, match="nconmax=0"):
        physics.load_mjcf(ANT, nconmax=0)
    xml = (
        '<mujoco><worldbody><body><joint type="hinge" range="-0.01 0.01" limited="true" margin="0.1"/>'
        '<geom type="sphere" size=".1"/></body></worldbody></mujoco>'
    )
    with pytest.raises(physics.UnsupportedFeatureError, match="narrower than twice its margin"):
        physics.load_mjcf(xml)


def _box_row(max_geom_pairs: int) -> str:
    """Five free cubes in a row, each pressed into the next by 5-20 mm (centres 0.18-0.195 apart),
    with MJX's broad-phase caps in ``<custom>``."""
    xs = np.cumsum([0.0, 0.19, 0.185, 0.195, 0.18])
    bodies = "".join(f'<body pos="{x} 0 1"><freejoint/><geom type="box" size=".1 .1 .1"/></body>' for x in xs)
    return (
        f'<mujoco><custom><numeric name="max_geom_pairs" data="{max_geom_pairs}"/>'
        '<numeric name="max_contact_points" data="20"/></custom>'
        f"<worldbody>{bodies}</worldbody></mujoco>"
    )


def test_mjx_caps_collide_the_closest_pairs_and_size_the_slots(x64):
    """MJX's ``max_geom_pairs`` collides only the pairs whose bounding spheres overlap most, and
    ``max_contact_points`` sets the contact slots; where the caps do not bind the step is MuJoCo
    C's; without ``mjx_caps=True`` (the default) they are ignored."""
    # 10 box-box pairs, the 4 neighbours touching: a cap of 6 does not bind
    mj = mujoco.MjModel.from_xml_string(_box_row(6))
    m = physics.model_from_mujoco(mj, mjx_caps=True)
    assert (m.max_geom_pairs, m.nconmax) == (6, 20)
    md = mujoco.MjData(mj)
    mujoco.mj_forward(mj, md)
    d = jax.jit(lambda d: fwd.forward(m, d))(_data(m, md))
    assert int(d.ncon) == md.ncon > 4
    np.testing.assert_allclose(d.qacc, md.qacc, rtol=1e-6, atol=1e-6)
    # the capped group lays out only its 6 collided pairs; forces reach the bodies of each one's pair
    assert d.contact_dist.size == 6 * 8
    mujoco.mj_rnePostConstraint(mj, md)
    np.testing.assert_allclose(physics.cfrc_ext(m, d), md.cfrc_ext, rtol=1e-6, atol=1e-6)
    uncapped = physics.model_from_mujoco(mj)  # the default: MuJoCo C's, every pair
    assert uncapped.max_geom_pairs == -1 and uncapped.nconmax == constraint.default_nconmax(80)

    # a cap of 2: only the two closest neighbours (centres 0.18 and 0.185 apart) touch
    m = physics.load_mjcf(_box_row(2), mjx_caps=True)
    d = jax.jit(lambda d: fwd.forward(m, d))(physics.make_data(m))
    # only the collided pairs' candidates are laid out (2 pairs x 8), each naming its pair
    assert collision_driver.contact_layout(m).size == d.contact_dist.size == 16
    assert collision_driver.dynamic_candidates(m).all()
    pairs = np.asarray(d.contact_pair)
    assert {(int(m.pair_geom1[p]), int(m.pair_geom2[p])) for p in pairs} == {(1, 2), (3, 4)}
    touching = {(int(m.pair_geom1[p]), int(m.pair_geom2[p])) for p in pairs[np.asarray(d.contact_dist) < 0]}
    assert touching == {(1, 2), (3, 4)}
    # the boxes shifted so other pairs are closest: the slots follow them
    mj = mujoco.MjModel.from_xml_string(_box_row(2))
    md = mujoco.MjData(mj)
    md.qpos[0] += 0.01  # the first box moves 10 mm into its neighbour: centres 0.18 apart
    md.qpos[28] += 0.02  # the last moves away from its neighbour: 0.2 apart
    d = jax.jit(lambda d: fwd.forward(m, d))(physics.make_data(m, qpos=md.qpos))
    pairs = np.asarray(d.contact_pair)
    assert {(int(m.pair_geom1[p]), int(m.pair_geom2[p])) for p in pairs} == {(0, 1), (1, 2)}
