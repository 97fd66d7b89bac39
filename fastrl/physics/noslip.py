"""MuJoCo's noslip post-pass (mj_solNoSlip): the friction forces re-solved without regularisation.

A soft contact lets a resting or grasped body creep: its friction force comes from a regularised
problem, so some slip velocity is needed to produce it. With ``<option noslip_iterations=N>``
MuJoCo follows its solver with up to N sweeps of projected Gauss-Seidel over the friction rows
alone, on the dual cost without the regulariser ``R``:

    min_f  1/2 f^T A f + f^T b,    A = J M^-1 J^T,    b = J qacc_smooth - aref,

so a row's residual is ``J_i qacc(f) - aref_i`` with ``qacc(f) = qacc_smooth + M^-1 J^T f``. Each
sweep visits, in row order, every friction-loss row (its force clamped to the friction loss),
then every contact's friction: the pyramid's edges in opposing pairs ``(J_n + mu J_i,
J_n - mu J_i)``, their sum (the normal force) held, or an elliptic cone's friction directions, the
normal force held, minimising over the friction ellipse (MuJoCo's QCQP). Normal, limit and
equality forces stay the solver's. A block update that would raise the cost is undone, as in
MuJoCo. Afterwards ``qfrc_constraint = J^T f`` and ``qacc = qacc_smooth + M^-1 qfrc_constraint``.

MuJoCo sweeps each constraint island on its own and stops an island once a sweep improves its
cost by less than ``noslip_tolerance``, scaled by the island's inverse inertia (``island.islands``;
MuJoCo 4.0's scale, not the ``1 / (meaninertia nv)`` of older sources). Here the sweeps are
a ``fori_loop`` of ``noslip_iterations``, and an island that has stopped keeps its forces
(masked), so the result is MuJoCo's with a static trip count. The blocks of a sweep are
``lax.scan``s over static row indices, one per kind of block.
"""

from __future__ import annotations

import typing

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.physics import constraint, equality, factor, island, solver
from fastrl.physics.collision_driver import candidate_pairs
from fastrl.physics.types import Data, Model

MINVAL = mujoco.mjMINVAL
QCQP_ITERATIONS = 20  # mju_QCQP's Newton steps on the multiplier


def pyramid_pairs(m: Model) -> np.ndarray:
    """(npair,) the first row of every opposing pair of pyramid edges, in row order."""
    out = []
    if not constraint.elliptic(m):
        addr, slot = constraint.contact_efc_address(m), 0
        for dim, _, n in constraint.contact_groups(m):
            if dim > 1:
                out += [addr[s] + 2 * np.arange(dim - 1) for s in range(slot, slot + n)]
            slot += n
    return np.concatenate(out) if out else np.zeros(0, np.int64)


def friction_rows(m: Model) -> np.ndarray:
    """(nfric,) the friction-loss rows (after the equality rows)."""
    return equality.nrows(m) + np.arange(constraint.nfriction(m))


class _Sweep(typing.NamedTuple):
    """What a sweep updates: the forces, the acceleration they imply and each island's cost
    improvement so far."""

    force: jax.Array  # (nefc,)
    qacc: jax.Array  # (nv,)
    improvement: jax.Array  # (k,)


class _Problem(typing.NamedTuple):
    """The unregularised dual problem of one step."""

    jac: jax.Array  # (nefc, nv)
    minv_jt: jax.Array  # (nefc, nv) the rows of M^-1 J^T
    aref: jax.Array  # (nefc,)
    row_island: jax.Array  # (nefc, k) one-hot
    scale: jax.Array  # (k,) 1 / each island's inertia (MuJoCo's improvement scale)
    live: jax.Array  # (k,) islands still iterating

    def residual(self, qacc: jax.Array, rows: jax.Array) -> jax.Array:
        return self.jac[rows] @ qacc - self.aref[rows]

    def block(self, rows: jax.Array) -> jax.Array:
        """``A`` on ``rows``, its diagonal at least 1e-10 (MuJoCo's extractBlock)."""
        a = self.jac[rows] @ self.minv_jt[rows].T
        n = rows.shape[0]
        return a.at[np.arange(n), np.arange(n)].set(jnp.maximum(1e-10, jnp.diagonal(a)))

    def update(self, s: _Sweep, rows: jax.Array, new: jax.Array, gain: jax.Array) -> _Sweep:
        """``s`` with the forces of ``rows`` set to ``new`` (unless their island has stopped)
        and ``gain`` (the cost decrease) credited to their island."""
        onehot = self.row_island[rows[0]]
        on = jnp.any((onehot > 0) & self.live)
        delta = jnp.where(on, new - s.force[rows], 0.0)
        return _Sweep(
            s.force.at[rows].add(delta),
            s.qacc + delta @ self.minv_jt[rows],
            s.improvement + jnp.where(on, gain, 0.0) * onehot,
        )


def _cost_change(a, delta, res):
    """MuJoCo's costChange: the cost's change for a step ``delta``; a rise (> 1e-10) is undone."""
    change = 0.5 * delta @ a @ delta + delta @ res
    keep = change <= 1e-10
    return keep, jnp.where(keep, change, 0.0)


def _friction_loss(p: _Problem):
    """A friction-loss row's update: its unconstrained minimum, clamped to the friction loss."""

    def one(s: _Sweep, x):
        row, bound = x
        rows = row[None]
        res = p.residual(s.qacc, rows)[0]
        inv = 1.0 / jnp.maximum(MINVAL, p.jac[row] @ p.minv_jt[row])
        old = s.force[row]
        delta = jnp.clip(old - res * inv, -bound, bound) - old
        return p.update(s, rows, (old + delta)[None], -(0.5 * delta**2 / inv + delta * res)), None

    return one


def _pyramid(p: _Problem):
    """Two opposing pyramid edges' update: their sum held, their difference minimised (1-D)."""

    def one(s: _Sweep, first):
        rows = first + jnp.arange(2)
        res = p.residual(s.qacc, rows)
        a = p.block(rows)
        old = s.force[rows]
        bc = res - a @ old
        mid = 0.5 * (old[0] + old[1])
        k1 = a[0, 0] + a[1, 1] - a[0, 1] - a[1, 0]
        k0 = mid * (a[0, 0] - a[1, 1]) + bc[0] - bc[1]
        y = jnp.clip(-k0 / jnp.where(k1 < MINVAL, 1.0, k1), -mid, mid)
        new = jnp.where(k1 < MINVAL, jnp.stack([mid, mid]), jnp.stack([mid + y, mid - y]))
        keep, change = _cost_change(a, new - old, res)
        return p.update(s, rows, jnp.where(keep, new, old), -change), None

    return one


def _qcqp(a: jax.Array, b: jax.Array, mu: jax.Array, r: jax.Array) -> jax.Array:
    """MuJoCo's mju_QCQP: ``min 1/2 x^T a x + x^T b`` s.t. ``sum (x_i / mu_i)^2 <= r^2``, by
    Newton's method on the multiplier, the result put on the ellipse where it is active."""
    n = b.shape[0]
    bs, As = b * mu, a * mu[:, None] * mu[None, :]
    eye = jnp.eye(n, dtype=b.dtype)

    def step(_, carry):
        la, v, stop, fail = carry
        ala = As + la * eye
        if n <= 3:  # mju_QCQP2/3 check the determinant, mju_QCQP the Cholesky pivots
            bad = jnp.linalg.det(ala) < 1e-10
        else:
            pivots = jnp.diagonal(jnp.linalg.cholesky(ala)) ** 2
            bad = ~jnp.all(pivots >= 1e-10)
        safe = jnp.where(bad, eye, ala)
        x = -jnp.linalg.solve(safe, bs)
        val = x @ x - r**2
        curve = 2.0 * x @ jnp.linalg.solve(safe, x)  # 0 only where x is: then val < 1e-10 stops
        delta = val / jnp.where(curve > 0, curve, 1.0)
        go = ~stop
        stop_now = bad | (val < 1e-10) | (delta < 1e-10)
        return (
            jnp.where(go & ~stop_now, la + delta, la),
            jnp.where(go, x, v),
            stop | stop_now,
            fail | (go & bad),
        )

    zero = jnp.zeros((), b.dtype)
    la, v, _, fail = jax.lax.fori_loop(0, QCQP_ITERATIONS, step, (zero, jnp.zeros_like(b), False, False))
    x = v * mu
    ratio = r**2 / jnp.maximum(MINVAL, jnp.sum(v**2))
    scale = jnp.sqrt(jnp.where(ratio > 0, ratio, 1.0))  # a safe sqrt: r = 0 is masked by the caller
    return jnp.where(fail, 0.0, jnp.where(la != 0, x * scale, x))


def _cone(p: _Problem, dim: int):
    """An elliptic cone's friction update, the normal force held: the QCQP on its ellipse."""

    def one(s: _Sweep, x):
        normal, mu = x
        rows = normal + 1 + jnp.arange(dim - 1)
        res = p.residual(s.qacc, rows)
        a = p.block(rows)
        old = s.force[rows]
        fn = s.force[normal]
        new = jnp.where(fn < MINVAL, 0.0, _qcqp(a, res - a @ old, mu, fn))
        keep, change = _cost_change(a, new - old, res)
        return p.update(s, rows, jnp.where(keep, new, old), -change), None

    return one


def _problem(m: Model, d: Data) -> _Problem:
    """The rows, ``M^-1 J^T`` and this step's islands (``island.islands``: each row's island)."""
    solve = jax.vmap(lambda v: factor.solve(m, d.qM, v))
    isl = island.islands(m, solver.make_rows(m, d), d.qM)
    row_island = (((d.efc_J != 0).astype(d.qM.dtype) @ isl.dof.T) > 0).astype(d.qM.dtype)
    live = jnp.ones(isl.dof.shape[0], bool)
    return _Problem(d.efc_J, solve(d.efc_J), d.efc_aref, row_island, isl.scale, live)


def solve(m: Model, d: Data) -> Data:
    """``efc_force`` with the friction rows re-solved, and the ``qacc`` and ``qfrc_constraint``
    they imply (module docstring). Expects the constraint solver to have run."""
    p = _problem(m, d)
    fr = friction_rows(m)
    loss = jnp.concatenate([m.dof_frictionloss[m.friction_dofs], m.tendon_frictionloss[m.friction_tendons]])
    pairs = pyramid_pairs(m)
    cones = []
    ids = candidate_pairs(m, d)
    for dim, row, slot, n in constraint.elliptic_blocks(m):
        mu = m.pair_friction[ids[d.contact_id[slot : slot + n]], : dim - 1]
        cones.append((dim, jnp.asarray(row + dim * np.arange(n), np.int32), mu))
    regularised = jnp.where(d.efc_D > 0, 0.5 * d.efc_force**2 / jnp.where(d.efc_D > 0, d.efc_D, 1.0), 0.0)

    def iteration(i, carry):
        force, qacc, live = carry
        q = p._replace(live=live)
        # the first sweep also drops R's share of the cost (MuJoCo's "correct for cost change")
        s = _Sweep(force, qacc, jnp.where(i == 0, regularised @ p.row_island, 0.0))
        if fr.size:
            s = jax.lax.scan(_friction_loss(q), s, (jnp.asarray(fr, np.int32), loss))[0]
        if pairs.size:
            s = jax.lax.scan(_pyramid(q), s, jnp.asarray(pairs, np.int32))[0]
        for dim, normals, mu in cones:
            s = jax.lax.scan(_cone(q, dim), s, (normals, mu))[0]
        return s.force, s.qacc, live & ~(s.improvement * p.scale < m.noslip_tolerance)

    qacc0 = d.qacc_smooth + factor.solve(m, d.qM, d.efc_force @ d.efc_J)
    start = (d.efc_force, qacc0, p.live)
    force, _, _ = jax.lax.fori_loop(0, m.noslip_iterations, iteration, start)
    qfrc = force @ d.efc_J
    return d.replace(efc_force=force, qfrc_constraint=qfrc, qacc=d.qacc_smooth + factor.solve(m, d.qM, qfrc))
