"""fastrl's MJCF assets compile to the same physics as Gymnasium v5's MuJoCo models.

Both files go through MuJoCo's own compiler and every field that shapes the dynamics is compared
(topology, masses and inertias, joints, geoms and their contact parameters, actuators, sites,
options), then both are stepped 200 times with the same random controls. Only MuJoCo runs here,
never fastrl's physics.
"""

from __future__ import annotations

import pathlib

import mujoco
import numpy as np
import pytest

from fastrl import envs

gymnasium = pytest.importorskip("gymnasium")

OURS = pathlib.Path(__file__).parents[2] / "fastrl" / "assets"
GYM = pathlib.Path(gymnasium.__file__).parent / "envs" / "mujoco" / "assets"

# fastrl asset -> the Gymnasium v5 file it reproduces
PAIRS = {
    "ant": "ant",
    "half_cheetah": "half_cheetah",
    "hopper": "hopper",
    "walker2d": "walker2d_v5",
    "humanoid": "humanoid",
    "humanoidstandup": "humanoidstandup",
    "reacher": "reacher",
    "swimmer": "swimmer",
    "pusher": "pusher_v5",
    "inverted_pendulum": "inverted_pendulum",
    "inverted_double_pendulum": "inverted_double_pendulum",
}

SIZES = ("nq", "nv", "nu", "nbody", "njnt", "ngeom", "nsite", "nmocap", "neq")

OPTIONS = ("timestep", "integrator", "gravity", "density", "viscosity", "wind", "solver", "iterations")

FIELDS = (
    # bodies and their mass properties
    "body_parentid",
    "body_pos",
    "body_quat",
    "body_mass",
    "body_inertia",
    "body_ipos",
    "body_iquat",
    # joints and dofs
    "jnt_type",
    "jnt_bodyid",
    "jnt_axis",
    "jnt_pos",
    "jnt_range",
    "jnt_limited",
    "jnt_stiffness",
    "jnt_margin",
    "jnt_solref",
    "jnt_solimp",
    "dof_armature",
    "dof_damping",
    "dof_frictionloss",
    "qpos0",
    "qpos_spring",
    # geoms
    "geom_bodyid",
    "geom_type",
    "geom_size",
    "geom_pos",
    "geom_quat",
    "geom_contype",
    "geom_conaffinity",
    "geom_condim",
    "geom_friction",
    "geom_margin",
    "geom_gap",
    "geom_solref",
    "geom_solimp",
    "geom_solmix",
    "geom_priority",
    # actuators
    "actuator_trntype",
    "actuator_dyntype",
    "actuator_gaintype",
    "actuator_biastype",
    "actuator_trnid",
    "actuator_gear",
    "actuator_ctrlrange",
    "actuator_ctrllimited",
    "actuator_forcelimited",
    "actuator_gainprm",
    "actuator_biasprm",
    # sites
    "site_bodyid",
    "site_pos",
)

# object kinds whose names the Gymnasium envs and users' code look up, with their count field
NAMED = {
    mujoco.mjtObj.mjOBJ_BODY: "nbody",
    mujoco.mjtObj.mjOBJ_JOINT: "njnt",
    mujoco.mjtObj.mjOBJ_ACTUATOR: "nu",
    mujoco.mjtObj.mjOBJ_SITE: "nsite",
}


def _close(actual, expected, err_msg):
    np.testing.assert_allclose(actual, expected, rtol=1e-9, atol=1e-12, err_msg=err_msg)


@pytest.fixture(params=sorted(PAIRS), scope="module")
def models(request):
    name = request.param
    ours = mujoco.MjModel.from_xml_path(str(OURS / f"{name}.xml"))
    gym = mujoco.MjModel.from_xml_path(str(GYM / f"{PAIRS[name]}.xml"))
    return name, ours, gym


# fastrl's own scenes have no Gymnasium model; tests/envs/test_scenes.py checks them against MuJoCo
SCENE_ASSETS = {"arm", "arm_push", "hand"}


def test_every_asset_is_covered():
    assert sorted(p.stem for p in OURS.glob("*.xml") if p.stem not in SCENE_ASSETS) == sorted(PAIRS)
    assert {f"{a}.xml" for a in SCENE_ASSETS} <= {envs.make(n).asset for n in envs.names()}


def test_compiled_model_matches_gymnasium(models):
    name, ours, gym = models
    for size in SIZES:
        assert getattr(ours, size) == getattr(gym, size), f"{name}: {size}"
    for option in OPTIONS:
        a, b = np.asarray(getattr(ours.opt, option)), np.asarray(getattr(gym.opt, option))
        _close(a, b, f"{name}: opt.{option}")
    for field in FIELDS:
        a, b = getattr(ours, field), getattr(gym, field)
        assert a.shape == b.shape, f"{name}: {field} shape {a.shape} != {b.shape}"
        _close(a, b, f"{name}: {field}")


def test_gymnasium_names_are_kept(models):
    """Every body, joint, actuator and site Gymnasium names has the same name at the same index."""
    name, ours, gym = models
    for kind, count in NAMED.items():
        for i in range(getattr(gym, count)):
            theirs = mujoco.mj_id2name(gym, kind, i)
            if theirs is not None:
                assert mujoco.mj_id2name(ours, kind, i) == theirs, f"{name}: {kind.name} {i}"


def test_trajectory_matches_gymnasium(models):
    name, ours, gym = models
    d_ours, d_gym = mujoco.MjData(ours), mujoco.MjData(gym)
    rng = np.random.default_rng(0)
    low, high = gym.actuator_ctrlrange.T
    for _ in range(200):
        ctrl = rng.uniform(low, high)
        d_ours.ctrl[:] = ctrl
        d_gym.ctrl[:] = ctrl
        mujoco.mj_step(ours, d_ours)
        mujoco.mj_step(gym, d_gym)
    assert np.all(np.isfinite(d_gym.qpos))
    np.testing.assert_allclose(d_ours.qpos, d_gym.qpos, rtol=0, atol=1e-9, err_msg=name)
    np.testing.assert_allclose(d_ours.qvel, d_gym.qvel, rtol=0, atol=1e-6, err_msg=name)
