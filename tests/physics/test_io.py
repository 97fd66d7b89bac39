"""Loading MJCF: the public API, the summary, and clear errors for what is not simulated."""

from __future__ import annotations

import numpy as np
import pytest

from fastrl import physics
from tests.conftest import asset

BASE = """<mujoco><worldbody>{body}</worldbody>{extra}</mujoco>"""
HINGE_BODY = (
    '<body name="b"><joint name="j" type="hinge"{joint}/>'
    '<geom size="0.1" contype="0" conaffinity="0"/></body>'
)


def _xml(joint="", extra="", body=None):
    return BASE.format(body=body or HINGE_BODY.format(joint=joint), extra=extra)


def test_public_api_shapes():
    m = physics.load_mjcf(asset("ant_air"))
    d = physics.make_data(m)
    assert (m.nq, m.nv, m.nu) == (15, 14, 8)
    d = physics.step(m, d, np.zeros(m.nu))
    assert d.qpos.shape == (15,) and d.qvel.shape == (14,)
    assert float(d.time) == pytest.approx(0.01)
    assert "nv 14" in m.summary() and "8" in m.summary()


@pytest.mark.parametrize(
    "xml, words",
    [
        (
            BASE.format(
                body='<body name="b"><joint name="bj" type="ball" range="0 1" limited="true"/>'
                '<geom size="0.1" contype="0" conaffinity="0"/></body>',
                extra="",
            ),
            ["limits on a free/ball joint", "'bj'"],
        ),
        (
            _xml(
                extra='<tendon><fixed name="t" range="-1 -0.99" margin="0.1"><joint joint="j" coef="1"/>'
                "</fixed></tendon>"
            ),
            ["tendon 't'", "narrower than twice its margin"],
        ),
        (
            _xml(extra='<actuator><general name="mus" joint="j" dyntype="muscle"/></actuator>'),
            ["'mus'", "activation dynamics mjDYN_MUSCLE"],
        ),
        (
            BASE.format(
                body='<body><joint type="hinge"/><geom name="fin" size="0.1" fluidshape="ellipsoid"/></body>',
                extra='<option viscosity="0.1"/>',
            ),
            ["ellipsoid fluid model", "'fin'"],
        ),
        (_xml(extra='<option integrator="implicit"/>'), ["integrator mjINT_IMPLICIT", "'implicitfast'"]),
    ],
)
def test_unsupported_features_raise_clear_errors(xml, words):
    with pytest.raises(physics.UnsupportedFeatureError) as err:
        physics.load_mjcf(xml)
    for w in words:
        assert w in str(err.value)


def test_disabling_contacts_and_limits_drops_their_rows():
    from fastrl.physics.constraint import sizes

    limited = _xml(joint=' range="-1 1" limited="true"')
    assert sizes(physics.load_mjcf(limited)) == (0, 1)  # one row per limited joint
    xml = _xml(joint=' range="-1 1" limited="true"', extra='<option><flag limit="disable"/></option>')
    assert sizes(physics.load_mjcf(xml)) == (0, 0)
    egg = '<geom type="plane" size="1 1 1"/><body><freejoint/><geom type="ellipsoid" size=".1 .1 .2"/></body>'
    off = BASE.format(body=egg, extra='<option><flag contact="disable"/></option>')
    assert physics.load_mjcf(off).npair == 0


def test_bad_inputs():
    with pytest.raises(FileNotFoundError):
        physics.load_mjcf("no/such/model.xml")
    m = physics.load_mjcf(asset("pendulum"))
    with pytest.raises(ValueError, match="qpos has shape"):
        physics.make_data(m, qpos=np.zeros(3))
    with pytest.raises(ValueError, match="integrator"):
        physics.load_mjcf(asset("pendulum"), integrator="verlet")


def test_solver_iterations_from_the_asset_or_the_argument():
    numeric = '<custom><numeric name="fastrl_solver_iterations" data="{}"/></custom>'
    exact = physics.load_mjcf(_xml(), linesearch="exact")
    assert exact.solver_iterations == physics.io.DEFAULT_SOLVER_ITERATIONS
    assert physics.load_mjcf(_xml(extra=numeric.format(3))).solver_iterations == 3
    assert physics.load_mjcf(_xml(extra=numeric.format(3)), solver_iterations=6).solver_iterations == 6
    for bad in ("0", "2.5"):
        with pytest.raises(ValueError, match="fastrl_solver_iterations"):
            physics.load_mjcf(_xml(extra=numeric.format(bad)))


def test_model_is_a_pytree_with_static_topology():
    import jax

    m = physics.load_mjcf(asset("double_pendulum"))
    leaves = jax.tree.leaves(m)
    assert all(isinstance(x, jax.Array) for x in leaves)
    # Static fields survive a round trip through flatten/unflatten unchanged.
    m2 = jax.tree.unflatten(jax.tree.structure(m), leaves)
    np.testing.assert_array_equal(m2.jnt_type, m.jnt_type)
    assert hash(jax.tree.structure(m)) == hash(jax.tree.structure(m2))


def test_info_cli_prints_scene_summary(capsys):
    from fastrl.tools import scene_info

    scene_info.main([str(__import__("pathlib").Path(physics.__file__).parents[1] / "assets" / "ant.xml")])
    out = capsys.readouterr().out
    assert "13 kept of 91 geom pairs (12 plane-capsule, 1 plane-sphere)" in out
    assert "25 candidates" in out and "rows for the 8 deepest (nconmax 8)" in out
    assert "40 (0 friction loss + 8 limit + 32 contact" in out
    with pytest.raises(SystemExit) as err:
        scene_info.main(["no/such.xml"])
    assert err.value.code == 2


def test_solver_iterations_follow_a_scene_tuned_budget():
    """MuJoCo's solver (the default) keeps ``<option iterations>`` as its cap, stopping early at
    the tolerance as MuJoCo does; the exact-line-search solver, which runs its count, takes the
    scene's budget where it is below fastrl's default (MJX-tuned scenes), else the default; the
    custom numeric wins."""
    body = '<worldbody><body><joint type="slide"/><geom size=".1"/></body></worldbody>'
    cases = [("", 100, 8), ('iterations="1"', 1, 1), ('iterations="3"', 3, 3), ('iterations="50"', 50, 8)]
    for option, mujoco_cap, exact_count in cases:
        xml = f"<mujoco><option {option}/>{body}</mujoco>"
        assert physics.load_mjcf(xml).solver_iterations == mujoco_cap, option
        assert physics.load_mjcf(xml, linesearch="exact").solver_iterations == exact_count, option
    custom = '<custom><numeric name="fastrl_solver_iterations" data="5"/></custom>'
    m = physics.load_mjcf(f'<mujoco><option iterations="1"/>{custom}{body}</mujoco>')
    assert m.solver_iterations == 5
