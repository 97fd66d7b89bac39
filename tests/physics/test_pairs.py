"""Explicit contact pairs against MuJoCo C: which geom pairs collide, with which parameters;
the stage-by-stage and trajectory checks run on the same asset in test_oracle.py."""

from __future__ import annotations

import jax
import mujoco
import numpy as np
import pytest

from fastrl import physics
from tests.conftest import asset


def _geom_pair(mj, a, b):
    return frozenset((int(a), int(b)))


def test_pairs_collide_with_their_own_parameters_as_in_mujoco(x64):
    mj = mujoco.MjModel.from_xml_path(asset("pairs"))
    md = mujoco.MjData(mj)
    m = physics.model_from_mujoco(mj)
    name = lambda g: mujoco.mj_id2name(mj, mujoco.mjtObj.mjOBJ_GEOM, g)  # noqa: E731
    ours = {_geom_pair(mj, a, b): i for i, (a, b) in enumerate(zip(m.pair_geom1, m.pair_geom2, strict=True))}
    # the feet (contype 0) touch the floor only through their pairs; ball-floor appears once
    assert {"foot1", "floor"} <= {name(g) for g in next(p for p in ours if "foot1" in map(name, p))}
    assert sum(1 for p in ours if {name(g) for g in p} == {"ball", "floor"}) == 1
    # Let the body land, then compare every MuJoCo contact with ours, parameter by parameter.
    step = jax.jit(physics.step)
    d = physics.make_data(m)
    ctrl = np.zeros(mj.nu)
    for _ in range(150):
        mujoco.mj_step(mj, md)
        d = step(m, d, ctrl)
    d = jax.jit(physics.forward)(m, d)
    assert md.ncon >= 3
    seen = set()
    for c in md.contact:
        i = ours[_geom_pair(mj, c.geom1, c.geom2)]
        seen.add((name(c.geom1), name(c.geom2)))
        assert m.pair_condim[i] == c.dim
        np.testing.assert_allclose(m.pair_friction[i], c.friction, rtol=1e-12)
        np.testing.assert_allclose(m.pair_solref[i], c.solref, rtol=1e-12)
        np.testing.assert_allclose(m.pair_solimp[i], c.solimp, rtol=1e-12)
        np.testing.assert_allclose(m.pair_margin[i], c.includemargin, rtol=1e-12)  # MuJoCo 4: margin
    assert {frozenset(s) for s in seen} >= {frozenset(("foot1", "floor")), frozenset(("floor", "foot2"))}
    assert int(d.ncon) == md.ncon
    np.testing.assert_allclose(d.qpos, md.qpos, atol=1e-6)


def test_pair_adhesion_is_refused_by_name():
    xml = open(asset("pairs")).read().replace('condim="1"/>', 'condim="1" adhesion="1"/>')
    with pytest.raises(physics.UnsupportedFeatureError, match="adhesion"):
        physics.load_mjcf(xml)
