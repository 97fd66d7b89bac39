"""Solving with the mass matrix and matrices of its sparsity (the constraint solver's Hessian
``M + J^T D J``, implicitfast's ``M - h D``): ``qm^-1 vec`` from an ``L^T D L`` factor along the
static dof tree (elementwise, or level by level for a large tree), or from a dense Cholesky for a
large dense structure, with a reverse-mode rule that reuses the factor.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from fastrl.physics import tree
from fastrl.physics.types import Model


def _factor(anc: tuple[tuple[int, ...], ...], qm: jax.Array) -> tuple[jax.Array, jax.Array]:
    nv = len(anc)
    low = {(k, i): qm[k, i] for k in range(nv) for i in anc[k]}
    diag = [qm[k, k] for k in range(nv)]
    for k in reversed(range(nv)):
        for pos, i in enumerate(anc[k]):
            scale = low[k, i] / diag[k]
            diag[i] = diag[i] - scale * low[k, i]
            for j in anc[k][pos + 1 :]:  # the ancestors of i are the later entries of k's chain
                low[i, j] = low[i, j] - scale * low[k, j]
            low[k, i] = scale
    one, zero = jnp.ones((), qm.dtype), jnp.zeros((), qm.dtype)
    rows = [jnp.stack([low.get((k, i), one if k == i else zero) for i in range(nv)]) for k in range(nv)]
    return jnp.stack(rows), jnp.stack(diag)


def _solve_factored(anc, factor, vec):
    low, diag = factor
    nv = len(anc)
    x = [vec[i] for i in range(nv)]
    for k in reversed(range(nv)):  # x <- L^-T x
        for i in anc[k]:
            x[i] = x[i] - low[k, i] * x[k]
    x = [x[i] / diag[i] for i in range(nv)]  # x <- D^-1 x
    for k in range(nv):  # x <- L^-1 x
        for i in anc[k]:
            x[k] = x[k] - low[k, i] * x[i]
    return jnp.stack(x)


# From this many scalar elimination steps (``elimination_steps``) a tree structure is factorised
# level by level (``_factor_levels``) instead of entry by entry: the elementwise program grows with
# the sum of depth^2 and XLA:CPU's compile time with it. The Humanoid's M takes 778 steps (kept
# elementwise: its factor and solve run in ~0.7 us/env), dm_control's CMU humanoid's 8,288,
# whose elementwise factor and solve are 25k instructions of optimised HLO per use.
LEVEL_FACTOR_MIN_STEPS = 2000


def elimination_steps(anc: tuple[tuple[int, ...], ...]) -> int:
    """Scalar updates of the elementwise L^T D L elimination of the structure ``anc``."""
    return sum(len(chain) * (len(chain) + 1) // 2 for chain in anc)


def _structure_levels(anc: tuple[tuple[int, ...], ...]) -> tuple[np.ndarray, list[np.ndarray]]:
    """(nv, nv) 0/1 mask of each row's strict ancestors, and the rows grouped by their number of
    ancestors, roots first: no row of a group is an ancestor of another."""
    nv = len(anc)
    mask = np.zeros((nv, nv))
    for k, chain in enumerate(anc):
        mask[k, list(chain)] = 1.0
    depth = np.array([len(chain) for chain in anc], np.int64)
    return mask, [np.flatnonzero(depth == k) for k in range(int(depth.max(initial=-1)) + 1)]


def _factor_levels(anc, qm):
    """``_factor`` with one dense step per level of the tree, from the leaves: a level's rows are
    final once every deeper level is eliminated, and their updates to the shared ancestors add up
    (``scale^T rows``, zero off the ancestor chains), so the program grows with the depth only."""
    mask, levels = _structure_levels(anc)
    q = jnp.asarray(qm)
    for level in reversed(levels[1:]):  # roots update nothing
        rows = q[level] * jnp.asarray(mask[level], dtype=q.dtype)
        scale = rows / q[level, level][:, None]
        q = q - jnp.matmul(scale.T, rows, precision=jax.lax.Precision.HIGHEST)
    diag = jnp.diagonal(q)
    return jnp.eye(len(anc), dtype=q.dtype) + q * jnp.asarray(mask, dtype=q.dtype) / diag[:, None], diag


def _solve_levels(anc, factor, vec):
    """``_solve_factored`` for ``_factor_levels``' factor: one matrix-vector product per level."""
    mask, levels = _structure_levels(anc)
    low = factor[0] * jnp.asarray(mask, dtype=factor[0].dtype)
    x = jnp.asarray(vec)
    for level in reversed(levels[1:]):  # x <- L^-T x, from the leaves
        x = x - jnp.matmul(x[level], low[level], precision=jax.lax.Precision.HIGHEST)
    x = x / factor[1]
    for level in levels[1:]:  # x <- L^-1 x, from the roots
        x = x.at[level].add(-jnp.matmul(low[level], x, precision=jax.lax.Precision.HIGHEST))
    return x


def ancestors(m: Model) -> tuple[tuple[int, ...], ...]:
    """Each dof's ancestors, nearest first: the structure of M and of its factor."""
    return tuple(tuple(chain) for chain in tree.dof_ancestors(m))


def factor_m(m: Model, qm: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Sparse L^T D L factorisation of a mass-matrix-shaped ``qm`` (mj_factorM).

    The mass matrix of a tree couples a dof only with its ancestors, and eliminating dofs from the
    leaves up creates no fill-in, so the factorisation is exact and costs O(sum of depth^2) rather
    than O(nv^3). The loops run over the static tree while tracing, so the traced program is a
    single chain of elementwise operations that XLA fuses (measured faster on XLA:CPU than a
    vectorised dense-masked variant, 2.8 vs 6.0 ms for 4096 Ants).

    Returns:
      ``L`` (nv, nv) unit lower-triangular (L[k, i] nonzero only for ancestors i of k) and the
      diagonal ``D`` (nv,), with ``qm = L^T diag(D) L``.
    """
    return _factor(ancestors(m), qm)


def solve_m(m: Model, factor: tuple[jax.Array, jax.Array], vec: jax.Array) -> jax.Array:
    """Solves ``qm x = vec`` given ``factor_m(m, qm)`` (mj_solveM), along the static tree."""
    return _solve_factored(ancestors(m), factor, vec)


# From this many dofs a dense structure is factorised by a Cholesky (``dense_solver``) instead of
# the elementwise elimination, whose ~nv^3/6 scalar steps each become a small loop over the batch.
# Measured at batch 1024 (factor + solve, us/env, elementwise vs LAPACK): nv 6 0.16 vs 0.34, 9
# 0.29 vs 0.83, 11 0.48 vs 0.87, 14 2.1 vs 0.95, 23 4.4 vs 1.8; and the elementwise form of nv 23
# took 7 s to compile, LAPACK's 0.4 s. Tree structures stay elementwise (the Ant's 14-dof
# Hessian: 0.56 vs 0.89 LAPACK).
DENSE_CHOLESKY_MIN_DOFS = 14


def dense_solver(anc: tuple[tuple[int, ...], ...]) -> str | None:
    """How ``solve_structured`` factorises this structure: None for the elementwise elimination;
    for a large dense one, "columns" (``_dense_cholesky``, XLA's own ops) on CPU and "linalg"
    (``lax.linalg.cholesky``: cuSOLVER on GPU) elsewhere.

    The choice depends on the platform only, never on the number of devices, so a program is the
    same on 1 device as on several. LAPACK's batched Cholesky is not used on CPU: a program
    holding it deadlocked on several XLA:CPU devices (its kernel waits on the intra-op thread
    pool that every device's program occupies; the Humanoid's PPO chunk on 2 devices), and on
    one device it saves little (``experiments/results/dense_factor.md``: factor + solve at
    batch 1024, us/env, LAPACK vs column-wise: n 15 0.74 vs 0.63, n 22 1.05 vs 1.41)."""
    dense = all(len(chain) == k for k, chain in enumerate(anc))
    if not (dense and len(anc) >= DENSE_CHOLESKY_MIN_DOFS):
        return None
    return "columns" if jax.default_backend() == "cpu" else "linalg"


# Above this many rows ``_dense_cholesky`` splits the matrix in 2 x 2 blocks (measured at batch
# 1024, float32, us per factor + solve, column-wise vs blocked: n 14 0.83 vs 0.94, 18 1.09 vs
# 0.95, 23 2.33 vs 1.74, 30 7.60 vs 3.74; LAPACK 0.74, 1.05, 1.43, 2.00).
COLUMN_CHOLESKY_MAX = 16


def _column_cholesky(qm: jax.Array) -> jax.Array:
    """The lower Cholesky factor of ``qm``: right-looking, one column per unrolled step, each a
    rank-1 update of the shrinking trailing block (~n vector ops, not the ~n^3/6 scalar ones of an
    elementwise elimination)."""
    n = qm.shape[-1]
    trailing, cols = jnp.asarray(qm), []
    for k in range(n):
        pivot = jnp.sqrt(trailing[0, 0])
        below = trailing[1:, 0] / pivot
        cols.append(jnp.concatenate([jnp.zeros(k, qm.dtype), pivot[None], below]))
        trailing = trailing[1:, 1:] - below[:, None] * below[None, :]
    return jnp.stack(cols, axis=1)


# Above this many rows the dense factor and solve run as loops (``_loop_cholesky``): unrolled,
# the blocked factor of a 56-dof tree's Hessian was 118k optimised HLO instructions.
UNROLLED_CHOLESKY_MAX = 32


def _loop_cholesky(qm: jax.Array) -> jax.Array:
    """``_column_cholesky`` as a loop over columns with masked rank-1 updates of the whole
    matrix: a program of constant size for any number of rows."""
    n = qm.shape[-1]
    idx = jnp.arange(n)

    def column(k, a):
        pivot = jnp.sqrt(a[k, k])
        below = jnp.where(idx > k, a[:, k] / pivot, 0.0)  # the factor's column k under its pivot
        a = a - below[:, None] * below[None, :]
        return a.at[:, k].set(below.at[k].set(pivot))

    return jnp.tril(jax.lax.fori_loop(0, n, column, jnp.asarray(qm)))


def _loop_cho_solve(c: jax.Array, vec: jax.Array) -> jax.Array:
    """``_dense_cho_solve`` as two loops over rows (forward, then back substitution)."""
    c, vec = jnp.asarray(c), jnp.asarray(vec)
    n = c.shape[-1]

    def forward(i, y):  # c y = vec; y is still zero from row i on
        return y.at[i].set((vec[i] - c[i] @ y) / c[i, i])

    y = jax.lax.fori_loop(0, n, forward, jnp.zeros_like(vec))

    def back(t, x):  # c^T x = y; x is still zero up to row i
        i = n - 1 - t
        return x.at[i].set((y[i] - c[:, i] @ x) / c[i, i])

    return jax.lax.fori_loop(0, n, back, jnp.zeros_like(vec))


def _dense_cholesky(qm: jax.Array) -> jax.Array:
    """The lower Cholesky factor ``c`` of ``qm`` (``qm = c c^T``). Up to ``COLUMN_CHOLESKY_MAX``
    rows, column by column; above, by 2 x 2 blocks: the leading block's factor ``c11``, the block
    below it ``l21 = qm21 c11^-T`` (forward substitution), and the factor of the Schur complement
    ``qm22 - l21 l21^T``, whose product is one matrix multiplication (a batched GEMM under vmap)
    in place of ``h`` rank-1 updates of that block."""
    n = qm.shape[-1]
    if n > UNROLLED_CHOLESKY_MAX:
        return _loop_cholesky(qm)
    if n <= COLUMN_CHOLESKY_MAX:
        return _column_cholesky(qm)
    h = n // 2
    c11 = _dense_cholesky(qm[:h, :h])
    rows = []  # c11 x = qm[:h, h:] by forward substitution, row by row: x = l21^T
    for i in range(h):
        r = qm[i, h:]
        for j in range(i):
            r = r - c11[i, j] * rows[j]
        rows.append(r / c11[i, i])
    l21 = jnp.stack(rows, axis=1)
    c22 = _dense_cholesky(qm[h:, h:] - jnp.matmul(l21, l21.T, precision=jax.lax.Precision.HIGHEST))
    top = jnp.concatenate([c11, jnp.zeros((h, n - h), qm.dtype)], axis=1)
    return jnp.concatenate([top, jnp.concatenate([l21, c22], axis=1)], axis=0)


def _dense_cho_solve(c: jax.Array, vec: jax.Array) -> jax.Array:
    """``(c c^T)^-1 vec``: forward then back substitution, column-oriented (one unrolled axpy per
    row of ``c``)."""
    n = c.shape[-1]
    if n > UNROLLED_CHOLESKY_MAX:
        return _loop_cho_solve(c, vec)
    r, y = jnp.asarray(vec), []
    for i in range(n):  # c y = vec
        y.append(r[i] / c[i, i])
        r = r - c[:, i] * y[i]  # rows above i are done: c[j < i, i] is 0
    r, x = jnp.stack(y), [None] * n
    for i in reversed(range(n)):  # c^T x = y
        x[i] = r[i] / c[i, i]
        r = r - c[i] * x[i]  # c[i, j > i] is 0
    return jnp.stack(x)


def _factor_any(anc, qm):
    which = dense_solver(anc)
    if which == "linalg":
        return jax.lax.linalg.cholesky(qm, symmetrize_input=False)
    if which == "columns":
        return _dense_cholesky(qm)
    if elimination_steps(anc) >= LEVEL_FACTOR_MIN_STEPS:
        return _factor_levels(anc, qm)
    return _factor(anc, qm)


def _solve_any(anc, factor, vec):
    which = dense_solver(anc)
    if which == "linalg":
        return jax.scipy.linalg.cho_solve((factor, True), vec)
    if which == "columns":
        return _dense_cho_solve(factor, vec)
    if elimination_steps(anc) >= LEVEL_FACTOR_MIN_STEPS:
        return _solve_levels(anc, factor, vec)
    return _solve_factored(anc, factor, vec)


@functools.partial(jax.custom_vjp, nondiff_argnums=(0,))
def _solve(anc, qm, vec):
    return _solve_any(anc, _factor_any(anc, qm), vec)


def _solve_fwd(anc, qm, vec):
    factor = _factor_any(anc, qm)
    x = _solve_any(anc, factor, vec)
    return x, (factor, x)


def _solve_bwd(anc, residual, x_bar):
    factor, x = residual
    vec_bar = _solve_any(anc, factor, x_bar)  # qm is symmetric: qm^-T = qm^-1
    return -jnp.outer(vec_bar, x), vec_bar


_solve.defvjp(_solve_fwd, _solve_bwd)


def solve_structured(structure: tuple[tuple[int, ...], ...], qm: jax.Array, vec: jax.Array) -> jax.Array:
    """``qm^-1 vec`` for a symmetric positive-definite ``qm`` whose factor has the sparsity
    ``structure`` (each row's nonzero columns, nearest first); differentiable like ``solve``.
    Large dense structures go to a dense Cholesky (``dense_solver``)."""
    return _solve(structure, qm, vec)


def solve(m: Model, qm: jax.Array, vec: jax.Array) -> jax.Array:
    """``qm^-1 vec`` by ``factor_m`` + ``solve_m``, with a reverse-mode rule that reuses the factor.

    Differentiating through the unrolled factorisation would build (and compile) its transpose;
    the rule ``vec_bar = qm^-1 x_bar``, ``qm_bar = -vec_bar x^T`` needs one more solve instead.
    """
    return _solve(ancestors(m), qm, vec)
