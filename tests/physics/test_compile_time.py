"""Compile time of wide, deep trees: the step's program grows with the tree's depth, not depth^2.

dm_control's CMU humanoid (62 dofs, 26 deep) took about 3 minutes to compile one step on the
2-core machine, most of it in the elementwise L^T D L elimination of its mass matrix, whose
program grows with the sum of each dof's depth squared, used three times a step (the smooth
acceleration, the Newton solver's gap and the implicit damping). Beyond
``factor.LEVEL_FACTOR_MIN_STEPS`` elimination steps the factor and solve take one dense step per
level of the tree instead. ``python -m experiments.compile_time`` measures the third-party models.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from fastrl import physics
from fastrl.physics import collision_ccd as ccd
from fastrl.physics import factor


def _tree(depth: int, branches: int = 5) -> str:
    """A free torso on a plane with ``branches`` capsule limbs of ``depth`` hinges each (a
    CMU-humanoid-like tree when ``depth`` is ~10)."""
    limb = ""
    for _ in range(depth):
        limb = (f'<body pos="0 0 -.2"><joint axis="1 0 0" range="-1 1" damping=".1"/>'
                f'<geom type="capsule" fromto="0 0 0 0 0 -.18" size=".04"/>{limb}</body>')  # fmt: skip
    limbs = "".join(limb.replace('pos="0 0 -.2"', f'pos="{0.1 * k} 0 -.1"', 1) for k in range(branches))
    return (f'<mujoco><worldbody><geom type="plane" size="5 5 .1"/><body pos="0 0 3"><freejoint/>'
            f'<geom size=".15"/>{limbs}</body></worldbody></mujoco>')  # fmt: skip


def _random_tree(nv: int, seed: int) -> tuple[tuple[tuple[int, ...], ...], np.ndarray]:
    """A random dof tree's structure (each dof's ancestors, nearest first) and an SPD matrix of
    that sparsity, ``L^T D L``."""
    rng = np.random.default_rng(seed)
    parent = [-1] + [int(rng.integers(max(0, k - 4), k)) for k in range(1, nv)]  # deep and branched
    anc = []
    for k in range(nv):
        chain, j = [], parent[k]
        while j >= 0:
            chain.append(j)
            j = parent[j]
        anc.append(tuple(chain))
    low = np.eye(nv)
    for k, chain in enumerate(anc):
        low[k, list(chain)] = rng.normal(size=len(chain)) / np.sqrt(len(chain))
    return tuple(anc), low.T @ np.diag(rng.uniform(0.5, 2.0, nv)) @ low


def test_level_factor_equals_the_elementwise_elimination(x64):
    """The level-by-level factor and solve are the elementwise ones, to rounding (float64)."""
    anc, qm = _random_tree(60, seed=0)
    assert factor.elimination_steps(anc) >= 1000
    vec = np.random.default_rng(1).normal(size=qm.shape[0])
    low, diag = factor._factor(anc, jnp.asarray(qm))
    low_l, diag_l = factor._factor_levels(anc, jnp.asarray(qm))
    np.testing.assert_allclose(low_l, low, rtol=0, atol=1e-12)
    np.testing.assert_allclose(diag_l, diag, rtol=1e-12)
    x = factor._solve_levels(anc, (low_l, diag_l), jnp.asarray(vec))
    elementwise = factor._solve_factored(anc, (low, diag), jnp.asarray(vec))
    np.testing.assert_allclose(x, elementwise, rtol=0, atol=1e-10)
    np.testing.assert_allclose(qm @ np.asarray(x), vec, rtol=0, atol=1e-10)


def _solve_program_size(depth: int) -> int:
    """Operations in the lowered (unoptimised) program of ``factor.solve`` with the mass matrix
    of a ``_tree(depth)``."""
    m = physics.load_mjcf(_tree(depth))
    qm, vec = jnp.eye(m.nv), jnp.ones(m.nv)
    text = jax.jit(lambda qm, vec: factor.solve(m, qm, vec)).lower(qm, vec).as_text()
    return sum(1 for line in text.splitlines() if " = " in line)


def test_mass_matrix_solve_program_grows_with_depth_not_depth_squared():
    """Limbs twice as deep (16 -> 26 dofs deep, 4.4x the elimination steps) less than double the
    solve's program: 1.0k -> 1.7k operations, where the elementwise elimination's went from 19k
    to 69k (3.6x)."""
    small, large = _solve_program_size(10), _solve_program_size(20)
    assert large < 2.0 * small, (small, large)
    assert large < 5_000, large


def test_wide_deep_tree_step_compiles_quickly():
    """One float32 step of a 56-dof tree with contacts and limits (5 limbs 10 deep on a free
    torso): under 40k optimised HLO instructions and 40 s to trace and compile on the 2-core
    machine, shared (measured: 19k and 14 s; with the elementwise elimination 167k and 68 s);
    and it steps finite. The tests' persistent compilation cache may serve a repeat run, so the
    instruction bound is the one that always holds the line."""
    m = physics.load_mjcf(_tree(10))
    assert factor.elimination_steps(factor.ancestors(m)) >= factor.LEVEL_FACTOR_MIN_STEPS
    d = physics.make_data(m)
    t0 = time.perf_counter()
    compiled = jax.jit(lambda d: physics.step(m, d)).lower(d).compile()
    seconds = time.perf_counter() - t0
    instructions = sum(1 for line in compiled.as_text().splitlines() if " = " in line)
    assert instructions < 40_000, instructions
    assert seconds < 40.0, seconds
    for _ in range(20):
        d = compiled(d)
    assert not bool(d.diverged) and np.all(np.isfinite(np.asarray(d.qpos)))


def _optimised_instructions(fn, *args) -> int:
    compiled = jax.jit(fn).lower(*args).compile()
    return sum(1 for line in compiled.as_text().splitlines() if " = " in line)


def test_multi_contact_search_compiles_gjk_epa_once():
    """A GJK/EPA pair's multi-contact search (the plain contact, then four turned ones) is one
    loop over the five poses, so its program is little more than one contact's (measured for a
    box against a mesh: 3.1k against 2.6k optimised instructions; with the turned contacts
    compiled apart from the plain one, 6.2k)."""
    n, verts = 8, 24
    eye = jnp.tile(jnp.eye(3), (n, 1, 1))
    hull = jnp.asarray(np.random.default_rng(0).normal(size=(n, verts, 3)))
    poses = (jnp.zeros((n, 3)), eye, jnp.ones((n, 3)), jnp.ones((n, 3)), eye, jnp.ones((n, 3)))
    box, mesh = int(physics.types.GeomType.BOX), int(physics.types.GeomType.MESH)
    one = _optimised_instructions(jax.vmap(ccd.single_contact(box, mesh)), *poses, jnp.zeros((n, 1, 3)), hull)
    search = _optimised_instructions(
        jax.vmap(ccd.convex_pair(box, mesh)),
        *poses,
        jnp.zeros((n, 1, 3)),
        hull,
        None,
        jnp.zeros(n),
        jnp.ones(n),
    )
    assert search < 1.5 * one, (search, one)
