"""Cylinder collisions against MuJoCo C: plane, sphere and capsule pairs, a dropped cylinder, Pusher.

Each primitive is compared with ``mjData.contact`` after ``mj_forward`` over random relative poses
(cylinders tilted every way): the same contacts (count, distance, position, frame). MuJoCo
collides capsule-cylinder with GJK/EPA, whose answer is only as exact as ``ccd_tolerance``; those
oracle models tighten it so MuJoCo converges to the exact contact fastrl computes, and disable
MuJoCo 4.0's multi-CCD, which fastrl does not reproduce (see the capsule test for how often it
matters).
"""

from __future__ import annotations

import os

import gymnasium
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from fastrl import physics
from fastrl.physics import collision_primitive as prim
from fastrl.physics.collision_driver import make_frame

PUSHER = os.path.join(os.path.dirname(gymnasium.__file__), "envs", "mujoco", "assets", "pusher_v5.xml")
TIGHT_CCD = 'ccd_tolerance="1e-12" ccd_iterations="500"'
NO_MULTICCD = '<flag multiccd="disable"/>'
CYLINDER = '<geom type="cylinder" size="0.05 0.07" margin="0.002"/>'
SECOND = {
    "plane": ('<geom type="plane" size="1 1 .1" margin="0.002"/>', prim.plane_cylinder),
    "sphere": ('<geom type="sphere" size="0.03" margin="0.002"/>', prim.sphere_cylinder),
    "capsule": ('<geom type="capsule" size="0.02 0.1" margin="0.002"/>', prim.capsule_cylinder),
}


def _pair_model(other: str, multiccd: bool = False) -> mujoco.MjModel:
    """geom 0 is the plane/sphere/capsule (a free body unless a plane), geom 1 a free cylinder."""
    geom = SECOND[other][0]
    first = geom if other == "plane" else f"<body><freejoint/>{geom}</body>"
    flag = "" if multiccd else NO_MULTICCD
    return mujoco.MjModel.from_xml_string(
        f'<mujoco><option gravity="0 0 0" {TIGHT_CCD}>{flag}</option><worldbody>{first}'
        f"<body><freejoint/>{CYLINDER}</body></worldbody></mujoco>"
    )


# Each primitive over a batch of poses; the geoms' sizes are shared.
BATCHED = {k: jax.jit(jax.vmap(fn, in_axes=(0, 0, None, 0, 0, None))) for k, (_, fn) in SECOND.items()}


def _random_qpos(mj: mujoco.MjModel, rng: np.random.Generator) -> np.ndarray:
    """Random poses of the free bodies; near the plane for a plane pair, where a third of the
    cylinders stand exactly upright or lie exactly on their side (MuJoCo's special cases)."""
    qpos = []
    for _ in range(mj.njnt):
        quat = rng.standard_normal(4)
        if mj.ngeom == 2 and mj.geom_type[0] == mujoco.mjtGeom.mjGEOM_PLANE:
            pos = np.r_[rng.uniform(-0.2, 0.2, 2), rng.uniform(-0.03, 0.1)]
            special = rng.integers(6)
            quat = [[1.0, 0, 0, 0], [1.0, 1.0, 0, 0]][special] if special < 2 else quat
        else:
            pos = rng.uniform(-0.08, 0.08, 3)
        qpos.append(np.r_[pos, np.asarray(quat) / np.linalg.norm(quat)])
    return np.concatenate(qpos)


def _compare(other: str, qposes: np.ndarray, multiccd: bool = False):
    """Per pose: MuJoCo's contacts and ours (active ones), as lists of (dist, pos, frame)."""
    mj = _pair_model(other, multiccd)
    md = mujoco.MjData(mj)
    xpos, xmat, refs = [], [], []
    for qpos in qposes:
        md.qpos[:] = qpos
        mujoco.mj_forward(mj, md)
        xpos.append(md.geom_xpos.copy())
        xmat.append(md.geom_xmat.reshape(-1, 3, 3).copy())
        refs.append([(c.dist, c.pos.copy(), c.frame.reshape(3, 3).copy()) for c in md.contact[: md.ncon]])
    xpos, xmat = jnp.asarray(np.array(xpos)), jnp.asarray(np.array(xmat))
    size = jnp.asarray(mj.geom_size)
    dist, pos, normal, tangent = BATCHED[other](
        xpos[:, 0], xmat[:, 0], size[0], xpos[:, 1], xmat[:, 1], size[1]
    )
    frame = np.asarray(make_frame(normal, tangent))
    margin = mj.geom_margin.sum()
    ours = [
        [
            (dist[i, k], np.asarray(pos[i, k]), frame[i, k])
            for k in np.flatnonzero(np.asarray(dist[i]) < margin)
        ]
        for i in range(len(qposes))
    ]
    return refs, ours


def _errors(ref, ours) -> np.ndarray:
    """(n, 3) errors in dist, pos, frame of MuJoCo's contacts, each matched to our nearest."""
    errs = []
    for dist, pos, frame in ref:
        k = int(np.argmin([np.max(np.abs(p - pos)) for _, p, _ in ours]))
        d, p, f = ours[k]
        errs.append([abs(float(d) - dist), np.max(np.abs(p - pos)), np.max(np.abs(f - frame))])
    return np.array(errs).reshape(-1, 3)


@pytest.mark.parametrize("other", ["plane", "sphere"])
def test_plane_and_sphere_cylinder_contacts_match_mujoco(other, x64):
    """300 random poses: the same contacts as MuJoCo's primitives, to rounding."""
    mj = _pair_model(other)
    rng = np.random.default_rng(0)
    qposes = np.array([_random_qpos(mj, rng) for _ in range(300)])
    refs, ours = _compare(other, qposes)
    counts = [len(r) for r in refs]
    assert [len(o) for o in ours] == counts
    assert len(set(counts)) == (5 if other == "plane" else 2)  # 0-4 contacts, or 0-1
    errs = np.concatenate([_errors(r, o) for r, o in zip(refs, ours, strict=True)])
    assert np.all(errs < 1e-12), errs.max(0)


def test_capsule_cylinder_contact_matches_mujoco(x64):
    """600 random poses, apart, touching and deep: MuJoCo's converged GJK/EPA contact.

    Distances agree to 1e-10 and points to 1e-6; normals to 3e-5 at worst (median under 1e-6):
    MuJoCo's normal is its looser quantity, as its EPA stops on the overlap, which is flat in the
    normal at the optimum (the next test shows ours is the better minimum).
    """
    mj = _pair_model("capsule")
    rng = np.random.default_rng(1)
    qposes = np.array([_random_qpos(mj, rng) for _ in range(600)])
    refs, ours = _compare("capsule", qposes)
    assert [len(o) for o in ours] == [len(r) for r in refs]
    touching = [i for i, r in enumerate(refs) if r]
    assert len(touching) > 0.4 * len(refs)
    errs = np.concatenate([_errors(refs[i], ours[i]) for i in touching])
    assert np.all(errs[:, 0] < 1e-10), errs[:, 0].max()
    assert np.all(errs[:, 1] < 1e-6), errs[:, 1].max()
    assert np.all(errs[:, 2] < 3e-5), errs[:, 2].max()
    assert np.median(errs[:, 2]) < 1e-6


def test_capsule_cylinder_differs_from_mujoco_multiccd_only_near_parallel_caps(x64):
    """With MuJoCo 4.0's default multi-CCD, a few poses (a capsule passing a cap almost parallel
    to it) get a second contact, and both then lie on the cap's plane: fastrl keeps the single
    GJK/EPA contact. Every other pose is unchanged."""
    mj = _pair_model("capsule", multiccd=True)
    rng = np.random.default_rng(1)
    qposes = np.array([_random_qpos(mj, rng) for _ in range(600)])
    refs, ours = _compare("capsule", qposes, multiccd=True)
    multi = [i for i, r in enumerate(refs) if len(r) > 1]
    assert 0 < len(multi) < 0.03 * len(refs)
    md = mujoco.MjData(mj)
    for i in multi:
        md.qpos[:] = qposes[i]
        mujoco.mj_forward(mj, md)
        axis = md.geom_xmat[1].reshape(3, 3)[:, 2]
        assert len(ours[i]) == 1
        assert all(abs(abs(frame[0] @ axis) - 1) < 1e-9 for _, _, frame in refs[i])
    single = [i for i, r in enumerate(refs) if len(r) == 1]
    errs = np.concatenate([_errors(refs[i], ours[i]) for i in single])
    assert np.all(errs[:, 0] < 1e-10) and np.all(errs[:, 1] < 1e-6)


def test_cylinder_contact_gradients_are_finite(x64):
    """Gradients of every output of the three primitives with respect to both poses, over random
    poses (upright and lying cylinders, deep and touching contacts): all finite."""
    rng = np.random.default_rng(3)
    for other, (_, fn) in SECOND.items():
        mj = _pair_model(other)
        md = mujoco.MjData(mj)
        poses = []
        for _ in range(200):
            md.qpos[:] = _random_qpos(mj, rng)
            mujoco.mj_forward(mj, md)
            poses.append((md.geom_xpos.copy(), md.geom_xmat.reshape(-1, 3, 3).copy()))
        xpos, xmat = (jnp.asarray(np.array(x)) for x in zip(*poses, strict=True))
        size = jnp.asarray(mj.geom_size)

        def loss(p1, m1, p2, m2, fn=fn, size=size):
            dist, pos, normal, _ = fn(p1, m1, size[0], p2, m2, size[1])
            return jnp.sum(1.3 * dist) + jnp.sum(0.7 * pos) + jnp.sum(0.3 * normal)

        grads = jax.jit(jax.vmap(jax.grad(loss, argnums=(0, 1, 2, 3))))(
            xpos[:, 0], xmat[:, 0], xpos[:, 1], xmat[:, 1]
        )
        assert all(bool(jnp.all(jnp.isfinite(g))) for g in grads), other


def _overlap_along(n, qpos, mj, md):
    """The capsule segment's overlap with the cylinder along world direction n (cylinder frame)."""
    md.qpos[:] = qpos
    mujoco.mj_forward(mj, md)
    rot, centre = md.geom_xmat[1].reshape(3, 3), md.geom_xpos[1]
    axis = md.geom_xmat[0].reshape(3, 3)[:, 2] * mj.geom_size[0, 1]
    a, b = (md.geom_xpos[0] - axis - centre) @ rot, (md.geom_xpos[0] + axis - centre) @ rot
    radius, half = mj.geom_size[1, :2]
    return prim._overlap(jnp.asarray(rot.T @ n), jnp.asarray(a), jnp.asarray(b), radius, half)


def test_capsule_cylinder_deep_normal_is_the_least_overlap(x64):
    """Where MuJoCo's deep (EPA) normal differs from ours, ours has the smaller overlap."""
    mj = _pair_model("capsule")
    md = mujoco.MjData(mj)
    rng = np.random.default_rng(1)
    qposes = np.array([_random_qpos(mj, rng) for _ in range(600)])
    refs, ours = _compare("capsule", qposes)
    deep = [i for i, r in enumerate(refs) if len(r) == 1 and r[0][0] < -0.025 and len(ours[i]) == 1]
    assert len(deep) > 50
    for i in deep:
        mine = float(_overlap_along(ours[i][0][2][0], qposes[i], mj, md))
        theirs = float(_overlap_along(refs[i][0][2][0], qposes[i], mj, md))
        assert mine <= theirs + 1e-14
        assert -(mine + mj.geom_size[0, 0]) == pytest.approx(refs[i][0][0], abs=1e-10)


def _upright_cylinder_pose(centre, direction):
    """qpos of a capsule at ``centre`` along ``direction``, the cylinder upright at the origin."""
    quat = np.zeros(4)
    mujoco.mju_quatZ2Vec(quat, np.asarray(direction, float))
    return np.r_[centre, quat, 0, 0, 0, 1, 0, 0, 0]


# Fingertip-like capsules (radius 0.02, half-length 0.1) against an upright cylinder (radius 0.05,
# half-height 0.07): (centre, direction). "Deep" cases reach the segment into the cylinder (EPA).
PUSHER_POSES = {
    "side, horizontal": ([0.065, 0.0, 0.02], [0.0, 1.0, 0.0]),
    "side, horizontal, deep": ([0.045, 0.01, -0.03], [0.3, 1.0, 0.0]),
    "side, tilted": ([0.066, 0.0, 0.01], [0.0, 0.6, 0.8]),
    "rim, tilted": ([0.06, 0.0, 0.08], [0.0, 1.0, 0.2]),
    "rim, pointing down": ([0.05, 0.01, 0.07], [0.6, 0.1, -1.0]),
    "rim, pointing down, deep": ([0.04, 0.01, 0.06], [0.6, 0.1, -1.0]),
    "rim, sloping across, deep": ([0.045, 0.0, 0.07], [1.0, 0.2, -1.0]),
    "through the rim, pushed sideways, deep": ([0.045, 0.0, 0.075], [1.0, 0.2, 1.0]),
    "rim, crossing over": ([0.05, 0.0, 0.085], [0.1, 1.0, 0.1]),
    "cap, end on top": ([0.04, 0.02, 0.175], [0.3, 0.2, 1.0]),
    "cap, end pressed in": ([0.03, 0.005, 0.155], [0.4, -0.2, 1.0]),
}


def test_capsule_cylinder_fingertip_cases_match_mujoco(x64):
    """Side, cap and rim contacts of a fingertip capsule on an upright cylinder, as in Pusher."""
    qposes = np.array([_upright_cylinder_pose(*pose) for pose in PUSHER_POSES.values()])
    refs, ours = _compare("capsule", qposes)
    for case, ref, mine in zip(PUSHER_POSES, refs, ours, strict=True):
        assert len(ref) == 1 and len(mine) == 1, case
        err = _errors(ref, mine)[0]
        assert err[0] < 1e-10 and err[1] < 1e-6 and err[2] < 1e-5, (case, err)


def test_contacts_through_the_pipeline_match_mujoco(x64):
    """A cylinder on the floor with a sphere and a capsule leaning on it: ``physics.forward``
    yields MuJoCo's contacts (the driver's table, contact order and frames)."""
    xml = (
        f'<mujoco><option gravity="0 0 0" {TIGHT_CCD}/><worldbody>'
        '<geom type="plane" size="1 1 .1"/>'
        '<body pos="0 0 0.0695"><freejoint/><geom type="cylinder" size="0.05 0.07"/></body>'
        '<body pos="0.075 0 0.05"><freejoint/><geom type="sphere" size="0.03"/></body>'
        '<body pos="-0.06 0.02 0.14" euler="0 50 10"><freejoint/>'
        '<geom type="capsule" size="0.02 0.1"/></body>'
        "</worldbody></mujoco>"
    )
    mj = mujoco.MjModel.from_xml_string(xml)
    md = mujoco.MjData(mj)
    mujoco.mj_forward(mj, md)
    m = physics.model_from_mujoco(mj)
    d = jax.jit(physics.forward)(m, physics.make_data(m))
    active = np.flatnonzero(np.asarray(d.contact_dist) < np.asarray(m.pair_margin)[0])
    ours = [(d.contact_dist[k], np.asarray(d.contact_pos[k]), np.asarray(d.contact_frame[k])) for k in active]
    ref = [(c.dist, c.pos, c.frame.reshape(3, 3)) for c in md.contact[: md.ncon]]
    assert len(ours) == len(ref) == 5  # the upright cylinder's 3 floor contacts, sphere, capsule
    assert np.all(_errors(ref, ours) < np.array([1e-10, 1e-6, 1e-5]))


def _drop(euler: str, integrator: str, steps: int):
    xml = (
        f'<mujoco><option timestep="0.002" integrator="{integrator}"/><worldbody>'
        '<geom type="plane" size="5 5 .1"/>'
        f'<body pos="0 0 0.3" euler="{euler}"><freejoint/><geom type="cylinder" size="0.05 0.07"/></body>'
        "</worldbody></mujoco>"
    )
    mj = mujoco.MjModel.from_xml_string(xml)
    md = mujoco.MjData(mj)
    ref = []
    for _ in range(steps):
        mujoco.mj_step(mj, md)
        ref.append(md.qpos[2])
    m = physics.model_from_mujoco(mj)

    def body(d, _):
        d = physics.step(m, d)
        return d, d.qpos[2]

    _, ours = jax.jit(lambda d: jax.lax.scan(body, d, None, length=steps))(physics.make_data(m))
    return np.array(ref), np.asarray(ours)


@pytest.mark.parametrize(
    "euler, rest", [("0 0 0", 0.07), ("90 0 0", 0.05), ("25 10 0", 0.07)], ids=["upright", "side", "tilted"]
)
def test_dropped_cylinder_rests_like_mujoco_and_never_sinks(euler, rest, x64):
    """Dropped from 0.3 m for 10 s (the tilted one lands on its rim and falls onto its cap): the
    whole fall tracks MuJoCo, the rest height is the geometry's (less the soft contact's sink,
    under 1 mm) and stays constant to 0.1 mm over the last 5 s."""
    steps = 5000
    ref, ours = _drop(euler, "Euler", steps)
    assert np.max(np.abs(ours - ref)) < 1e-6, np.max(np.abs(ours - ref))
    assert abs(ours[-1] - ref[-1]) < 1e-3 and abs(ours[-1] - rest) < 1e-3
    late = ours[steps // 2 :]
    assert late.max() - late.min() < 1e-4
    assert ours.min() > 0.03  # the impact compresses the contact by 1.5 cm at most


def _fingertip_on_object(mj, contact) -> bool:
    types = mj.geom_type[contact.geom]
    return types[0] == mujoco.mjtGeom.mjGEOM_CAPSULE and types[1] == mujoco.mjtGeom.mjGEOM_CYLINDER


def _pusher_rollout(mj, qpos, qvel, warmstart, ctrls):
    """qpos after each of MuJoCo's and fastrl's steps (float64) under ``ctrls`` (steps, nu)."""
    md = mujoco.MjData(mj)
    md.qpos[:], md.qvel[:], md.qacc_warmstart[:] = qpos, qvel, warmstart
    ref, pairs = [], 0
    for u in ctrls:
        md.ctrl[:] = u
        mujoco.mj_step(mj, md)
        ref.append(md.qpos.copy())
        pairs += sum(_fingertip_on_object(mj, c) for c in md.contact[: md.ncon])
    m = physics.model_from_mujoco(mj)

    def body(d, u):
        d = physics.step(m, d, u)
        return d, d.qpos

    d0 = physics.make_data(m, qpos=qpos, qvel=qvel).replace(qacc_warmstart=jnp.asarray(warmstart))
    _, ours = jax.jit(lambda d, c: jax.lax.scan(body, d, c))(d0, jnp.asarray(ctrls))
    return np.array(ref), np.asarray(ours), pairs


def test_pusher_loads_and_tracks_mujoco_under_random_controls(x64):
    """Gymnasium's Pusher-v5: 50 random controls held for 5 steps each (its frame skip) from the
    initial pose; the object rests on the table through its cylinder's plane contacts."""
    m = physics.load_mjcf(PUSHER)
    assert m.npair == 7  # table vs 3 fingertip capsules and the object; capsules vs the object
    mj = mujoco.MjModel.from_xml_path(PUSHER)
    ctrls = np.repeat(np.random.default_rng(0).uniform(-2, 2, (50, mj.nu)), 5, axis=0)
    ref, ours, _ = _pusher_rollout(mj, mj.qpos0, np.zeros(mj.nv), np.zeros(mj.nv), ctrls)
    assert np.max(np.abs(ours - ref)) < 1e-9, np.max(np.abs(ours - ref))


def _pusher_push(mj):
    """A Pusher state 10 steps before a fingertip capsule first touches the object under seeded
    random controls (MuJoCo), and the next 50 controls."""
    md = mujoco.MjData(mj)
    for seed in range(100):
        rng = np.random.default_rng(seed)
        mujoco.mj_resetData(mj, md)
        md.qpos[-4:-2] = [rng.uniform(-0.3, 0.0), rng.uniform(-0.2, 0.2)]  # object, as Gymnasium
        ctrls = np.repeat(rng.uniform(-2, 2, (100, mj.nu)), 5, axis=0)
        states = []
        for t, u in enumerate(ctrls):
            states.append((md.qpos.copy(), md.qvel.copy(), md.qacc_warmstart.copy()))
            md.ctrl[:] = u
            mujoco.mj_step(mj, md)
            if any(_fingertip_on_object(mj, c) for c in md.contact[: md.ncon]):
                start = max(t - 10, 0)
                return (*states[start], ctrls[start : start + 50])
    raise AssertionError("no seed pushes the object")


def test_pusher_fingertip_pushing_the_object_tracks_mujoco(x64):
    """50 steps in which the fingertip capsules press on the object (capsule-cylinder contacts,
    mostly deep): fastrl tracks MuJoCo with GJK/EPA converged (tight ccd_tolerance) and without
    multi-CCD. (With MuJoCo's defaults the trajectories part by 1e-4 here: at one step multi-CCD
    swaps a fingertip's contact for two on the cap's plane, and GJK/EPA's normals carry 1e-3.)"""
    mj = mujoco.MjModel.from_xml_path(PUSHER)
    mj.opt.ccd_tolerance, mj.opt.ccd_iterations = 1e-12, 500
    mj.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_MULTICCD
    qpos, qvel, warmstart, ctrls = _pusher_push(mj)
    ref, ours, pairs = _pusher_rollout(mj, qpos, qvel, warmstart, ctrls)
    assert pairs >= 10
    assert np.max(np.abs(ours - ref)) < 1e-6, np.max(np.abs(ours - ref))
