"""Models users bring at scale: a deep chain in float32, and a scene of many static geoms.

A chain of 200 hinges has a mass matrix too ill-conditioned for float32 entries; its smooth
dynamics are solved from the articulated inertias (``smooth.solve_mass``), and where the constraint
solver would need those entries the model is refused by name. Loading a scene of 10,000 static
spheres builds its pair table in time linear in the geoms.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from fastrl import physics
from fastrl.physics import io, io_contacts, smooth


def _chain(depth: int, contacts: bool) -> str:
    """A hanging chain of ``depth`` capsules, each on a hinge about y in the one before."""
    body = ""
    for i in reversed(range(depth)):
        body = (
            f'<body name="b{i}" pos="0 0 {-0.1 if i else 0}"><joint name="j{i}" axis="0 1 0" '
            f'damping="0.01"/><geom type="capsule" fromto="0 0 0 0 0 -0.1" size="0.01"/>{body}</body>'
        )
    flag = "" if contacts else '<option><flag contact="disable"/></option>'
    return f'<mujoco>{flag}<worldbody><body name="top" pos="0 0 25">{body}</body></worldbody></mujoco>'


def test_deep_chain_steps_in_float32_as_mujoco():
    """The 200-deep chain steps finite in float32 and tracks MuJoCo C (float64): its float32
    mass matrix is not positive definite, so a solve with it was NaN at the first step."""
    xml = _chain(200, contacts=False)
    model = physics.load_mjcf(xml)
    assert model.body_mass.dtype == jnp.float32
    mj = mujoco.MjModel.from_xml_string(xml)
    md = mujoco.MjData(mj)
    md.qpos[:] = np.random.default_rng(0).uniform(-0.1, 0.1, mj.nq)
    d = physics.make_data(model, qpos=md.qpos)
    step = jax.jit(lambda d: physics.step(model, d))
    for _ in range(3):
        d = step(d)
        mujoco.mj_step(mj, md)
        assert not bool(d.diverged)
        scale = np.abs(md.qvel).max()
        np.testing.assert_allclose(np.asarray(d.qvel), md.qvel, rtol=0, atol=1e-2 * scale)
        np.testing.assert_allclose(np.asarray(d.qpos), md.qpos, rtol=0, atol=1e-4)


def test_articulated_solve_matches_the_mass_matrix(x64):
    """The articulated factor solves with ``M + diag(extra)`` on a branched tree of every joint
    type (free, ball, two joints in one body, a welded body between two others), to rounding."""
    hinge = '<joint type="hinge" axis="{}"/><geom type="capsule" fromto="0 0 0 .2 .1 0" size=".05"/>'
    xml = f"""<mujoco><worldbody><body pos="0 0 1"><freejoint/><geom size=".2" mass="3"/>
      <body pos=".2 0 0"><joint type="ball"/><geom type="box" size=".1 .05 .2"/>
        <body pos="0 0 -.3">{hinge.format("1 0 0")}</body></body>
      <body pos="-.2 0 0" euler="0 30 0"><joint type="slide" axis="0 0 1"/>{hinge.format("0 1 0")}
        <body pos="-.2 0 0"><geom size=".1"/>
          <body pos="-.1 0 .1"><joint type="hinge" axis="0 0 1" armature=".3"/>
            <geom type="capsule" fromto="0 0 0 0 0 .3" size=".04"/></body></body></body>
    </body></worldbody></mujoco>"""
    model = physics.load_mjcf(xml)
    mj = mujoco.MjModel.from_xml_string(xml)
    rng = np.random.default_rng(1)
    qpos = mj.qpos0 + 0.3 * rng.standard_normal(mj.nq)
    for a in (3, 7):
        qpos[a : a + 4] /= np.linalg.norm(qpos[a : a + 4])
    vec, extra = jnp.asarray(rng.standard_normal(model.nv)), jnp.asarray(rng.uniform(0, 1, model.nv))

    @jax.jit
    def solve(d):
        d = physics.forward_forces(model, d)
        return d, smooth._articulated_solve(model, smooth._articulated_factor(model, d, extra), vec)

    d, got = solve(physics.make_data(model, qpos=qpos))
    want = np.linalg.solve(np.asarray(d.qM) + np.diag(np.asarray(extra)), np.asarray(vec))
    np.testing.assert_allclose(np.asarray(got), want, rtol=1e-10, atol=1e-10)


def test_deep_chain_with_contacts_is_refused_in_float32_by_name():
    """With contacts the constraint solver factorises ``M + J^T D J`` from float32 entries, which
    the 200-deep chain's M does not survive: refused at load, naming the chain and the way out."""
    with pytest.raises(physics.UnsupportedFeatureError) as err:
        physics.load_mjcf(_chain(200, contacts=True))
    for words in ("float32", "constraint solver", "200 dofs deep", "'j199'", "jax_enable_x64"):
        assert words in str(err.value)


def _spheres(n: int) -> str:
    """A floor, ``n`` static spheres on a grid, and one free sphere above them."""
    k = int(np.ceil(np.sqrt(n)))
    grid = "".join(f'<geom size=".1" pos="{i % k * 0.5} {i // k * 0.5} .1"/>' for i in range(n))
    ball = '<body pos="0 0 2"><freejoint/><geom size=".2"/></body>'
    return f'<mujoco><worldbody><geom type="plane" size="100 100 .1"/>{grid}{ball}</worldbody></mujoco>'


def _seconds(fn, *args) -> float:
    best = np.inf
    for _ in range(2):
        start = time.perf_counter()
        fn(*args)
        best = min(best, time.perf_counter() - start)
    return best


def test_many_static_geoms_load_in_linear_time():
    """10,000 static spheres load in under 5 s (MuJoCo compiles them in about 0.4 s), and the
    conversion's time grows linearly: the static-static pairs are never enumerated."""
    xml = _spheres(10000)
    start = time.perf_counter()
    model = physics.load_mjcf(xml)
    assert time.perf_counter() - start < 5.0
    assert model.pair_geom1.size == 10001  # the free sphere against the floor and each sphere
    small, large = (mujoco.MjModel.from_xml_string(_spheres(n)) for n in (2500, 10000))
    ratio = _seconds(io.model_from_mujoco, large) / _seconds(io.model_from_mujoco, small)
    assert ratio < 8.0  # 4 when linear, 16 when quadratic


def _pairs_by_loop(m: mujoco.MjModel) -> list[tuple[int, int]]:
    """MuJoCo's broad-phase filter over every geom pair, one at a time: the oracle."""
    excluded = set(m.exclude_signature.tolist())
    explicit = {frozenset((int(a), int(b))) for a, b in zip(m.pair_geom1, m.pair_geom2, strict=True)}
    weld, parent = m.body_weldid, m.body_parentid
    filterparent = not m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT
    pairs = []
    for g1 in range(m.ngeom):
        for g2 in range(g1 + 1, m.ngeom):
            if not (
                m.geom_contype[g1] & m.geom_conaffinity[g2] or m.geom_contype[g2] & m.geom_conaffinity[g1]
            ):
                continue
            b1, b2 = int(m.geom_bodyid[g1]), int(m.geom_bodyid[g2])
            w1, w2 = weld[b1], weld[b2]
            if w1 == w2 or (w1 == 0 and w2 == 0):
                continue
            if filterparent and w1 and w2 and (weld[parent[w1]] == w2 or weld[parent[w2]] == w1):
                continue
            if min(b1, b2) << 16 | max(b1, b2) in excluded or frozenset((g1, g2)) in explicit:
                continue
            pairs.append((g1, g2))
    pairs += [(int(min(a, b)), int(max(a, b))) for a, b in zip(m.pair_geom1, m.pair_geom2, strict=True)]
    return [(a, b) if m.geom_type[a] <= m.geom_type[b] else (b, a) for a, b in pairs]


@pytest.mark.parametrize("filterparent", [True, False])
def test_pair_table_matches_the_pairwise_filter(filterparent):
    """The vectorised pair table equals the pairwise filter, in order, on a scene with contype
    masks, welded and static geoms, parent-child pairs, exclusions and explicit pairs."""
    bodies = "".join(
        f'<body name="b{i}" pos="{i} 0 1"><freejoint/><geom name="g{i}" size=".1" '
        f'contype="{1 + i % 3}" conaffinity="{1 + i * 7 % 3}"/><body name="c{i}"><joint/>'
        f'<geom type="capsule" size=".1 .2"/><body><geom type="box" size=".1 .1 .1"/></body></body></body>'
        for i in range(12)
    )
    statics = "".join(f'<geom name="s{i}" type="box" size=".1 .1 .1" contype="{i % 4}"/>' for i in range(9))
    flag = "" if filterparent else '<option><flag filterparent="disable"/></option>'
    xml = f"""<mujoco>{flag}<worldbody>{statics}{bodies}<body><geom size=".1"/></body></worldbody>
      <contact><exclude body1="b3" body2="b5"/><exclude body1="c7" body2="b2"/>
        <pair geom1="g1" geom2="g2"/><pair geom1="s4" geom2="s3"/></contact></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    pairs = io_contacts.candidate_geom_pairs(m)
    assert pairs == _pairs_by_loop(m)
    assert len(pairs) > 500
