"""Constraint solver: Newton's method on MuJoCo's primal cost, with a static iteration count.

MuJoCo's soft constraints turn the constrained dynamics into the unconstrained convex problem

    qacc = argmin_a  1/2 (a - a0)^T M (a - a0) + sum_i 1/2 D_i min(J_i a - aref_i, 0)^2

with ``a0`` the unconstrained acceleration (pyramidal contacts and limits; ``D = 1/R``). The
cost is piecewise quadratic, so Newton's method finds the exact minimiser once it has the right
active set; it is MuJoCo's default for that reason, and with a static iteration count the
solution should stop changing before the count runs out. Iteration counts (``Model.solver_iterations``)
are per model: fastrl's assets name theirs (``<custom><numeric name="fastrl_solver_iterations">``),
the smallest count at which MuJoCo's own Newton solver (tolerance 1e-8) converged in 99.99% of
random-action physics steps and fastrl's iterate matched 32 iterations' to 1e-4 everywhere
(``experiments/solver_iterations.py``): Ant 7, Walker2d 7, HalfCheetah 5, Hopper 5, Pusher 3,
Swimmer 3, Reacher 2, InvertedPendulum 2, InvertedDoublePendulum 2; the Humanoids and models
that name none take ``io.DEFAULT_SOLVER_ITERATIONS`` (8). The Ant is trained with 5
(``conf/experiment/ant_ppo.yaml``: 99.8% of MuJoCo's steps converge within 5). Conjugate
gradients and projected Gauss-Seidel have not been measured here yet.
Each step solves with ``H = M + J^T diag(D * active) J`` (see
``hessian_structure``) and then runs a few 1-D Newton steps on the exact piecewise-quadratic line
cost. The iteration counts are static (``Model.solver_iterations``, ``LINESEARCH_ITERATIONS``), so
the program has no data-dependent loop; a converged iterate stays put (zero step).
"""

from __future__ import annotations

import typing

import jax
import jax.numpy as jnp
import numpy as np

from fastrl.physics import constraint, smooth, tree
from fastrl.physics.collision_driver import contact_layout
from fastrl.physics.math import matvec
from fastrl.physics.types import Data, Model

LINESEARCH_ITERATIONS = 3


def hessian_structure(m: Model) -> tuple[tuple[int, ...], ...]:
    """Each dof's ancestors in the elimination order used to factorise the Newton Hessian.

    ``H = M + J^T D J`` keeps the kinematic tree's sparsity when every contact has a static side
    (a robot on the ground: each row's Jacobian lives on one root-to-body path), so the tree's
    fill-free L^T D L factorisation applies, as for M. Otherwise H is factorised densely.
    """
    moving = tree.body_dof_ancestors(m).any(axis=1)
    layout = contact_layout(m)
    b1 = m.geom_bodyid[m.pair_geom1[layout]]
    b2 = m.geom_bodyid[m.pair_geom2[layout]]
    if not np.any(moving[b1] & moving[b2]):
        return smooth.ancestors(m)
    return tuple(tuple(range(k - 1, -1, -1)) for k in range(m.nv))


class _Rows(typing.NamedTuple):
    """The constraint rows split the way the solver uses them (one environment).

    Limit rows are signed unit vectors ``sign * e_dof`` at static dofs, so products with them are
    reads of single dofs; contact rows are dense (ncon_rows, nv).
    """

    lim_dofs: np.ndarray  # (nlim,) static
    lim_sign: jax.Array  # (nlim,)
    lim_aref: jax.Array
    lim_D: jax.Array
    jac: jax.Array  # (nc, nv) contact rows
    aref: jax.Array
    dd: jax.Array

    def j(self, a: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``J a`` of the limit rows and of the contact rows."""
        return self.lim_sign * a[self.lim_dofs], self.jac @ a

    def jar(self, a: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``J a - aref`` of the limit rows and of the contact rows."""
        jl, jc = self.j(a)
        return jl - self.lim_aref, jc - self.aref

    def jt(self, lim: jax.Array, con: jax.Array) -> jax.Array:
        """``J^T f`` for row values ``(lim, con)``."""
        out = con @ self.jac if self.aref.size else 0.0
        if self.lim_dofs.size:
            out = out + jnp.zeros(self.jac.shape[-1], lim.dtype).at[self.lim_dofs].add(self.lim_sign * lim)
        return out


def _rows(m: Model, d: Data) -> _Rows:
    dofs = constraint.limit_dofs(m)
    n = dofs.size
    return _Rows(dofs, d.efc_J[np.arange(n), dofs], d.efc_aref[:n], d.efc_D[:n], d.efc_J[n:],
                 d.efc_aref[n:], d.efc_D[n:])  # fmt: skip


def _cost(rows: _Rows, d: Data, a: jax.Array) -> jax.Array:
    jl, jc = rows.jar(a)
    da = a - d.qacc_smooth
    return 0.5 * (
        jnp.sum(da * matvec(d.qM, da))
        + jnp.sum(rows.lim_D * jnp.minimum(jl, 0.0) ** 2)
        + jnp.sum(rows.dd * jnp.minimum(jc, 0.0) ** 2)
    )


def _quadratic(rows: _Rows, d: Data, a: jax.Array, jl: jax.Array, jc: jax.Array):
    """Gradient and Hessian of the cost at ``a``, given its row residuals ``J a - aref``.

    ``H = M + J^T diag(D * active) J``; limit rows (signed unit vectors) add to the diagonal.
    """
    quad_lim, quad = rows.lim_D * (jl < 0), rows.dd * (jc < 0)
    grad = matvec(d.qM, a - d.qacc_smooth) + rows.jt(quad_lim * jl, quad * jc)
    hess = d.qM
    if quad.size:
        # An unrolled sum of outer products: one fused elementwise loop, 4-5x faster on XLA:CPU
        # than the equivalent batched dot (tiny per-environment GEMMs). It must not be fused
        # into the factorisation's many scalar reads (each would recompute its sum: 5x slower
        # overall), which is why H is carried across the Newton loop (see ``solve``).
        scaled = rows.jac * quad[:, None]
        hess = hess + sum(scaled[r][:, None] * rows.jac[r][None, :] for r in range(quad.shape[0]))
    if rows.lim_dofs.size:
        nv = d.qM.shape[-1]
        hess = hess + jnp.diag(jnp.zeros(nv, quad_lim.dtype).at[rows.lim_dofs].add(quad_lim))
    return grad, hess


def _newton_step(structure, rows: _Rows, d: Data, carry):
    a, jl, jc, grad, hess = carry
    step = -smooth.solve_structured(structure, hess, grad)
    # Exact line search on phi(alpha) = cost(a + alpha step), piecewise quadratic and convex.
    sl, sc = rows.j(step)  # directly, not jar(step) + aref: that cancels to rounding noise
    s_m_s = jnp.sum(step * matvec(d.qM, step))
    s_m_a = jnp.sum(step * matvec(d.qM, a - d.qacc_smooth))
    alpha = jnp.ones((), a.dtype)
    for _ in range(LINESEARCH_ITERATIONS):
        slope, curve = alpha * s_m_s + s_m_a, s_m_s
        for jar, js, dd in ((jl, sl, rows.lim_D), (jc, sc, rows.dd)):
            trial = jar + alpha * js
            neg = dd * (trial < 0)
            slope = slope + jnp.sum(neg * trial * js)
            curve = curve + jnp.sum(neg * js * js)
        # curve >= step' M step > 0 unless the step is exactly zero (then slope is zero too). A
        # fixed floor such as 1e-30 is not safe: at convergence the step is at rounding level
        # (|step| ~ 1e-14 in float64, curve < 1e-30), and dividing the rounding noise of slope by
        # the floor gave alpha ~ 1e13, throwing a converged iterate far off.
        alpha = jnp.maximum(alpha - slope / jnp.maximum(curve, jnp.finfo(curve.dtype).tiny), 0.0)
    # The step length carries no gradient: where the iterate has converged the step is zero and
    # d(alpha) = d(slope) / curve is 0/0 (NaN in reverse mode). With alpha held fixed, the
    # derivative of a converged Newton iterate is the implicit-function derivative of the
    # minimiser (the full step is alpha = 1 there), which is what differentiating the solve means.
    alpha = jax.lax.stop_gradient(alpha)
    a, jl, jc = a + alpha * step, jl + alpha * sl, jc + alpha * sc  # residuals are linear in a
    return (a, jl, jc, *_quadratic(rows, d, a, jl, jc))


def solve(m: Model, d: Data) -> Data:
    """Constraint forces and the constrained acceleration: ``qacc``, ``efc_force``, ``qfrc_constraint``.

    Starts from the cheaper of ``qacc_warmstart`` (the last step's acceleration) and
    ``qacc_smooth``, as MuJoCo does, then takes ``m.solver_iterations`` Newton steps.
    """
    rows = _rows(m, d)
    warm = d.qacc_warmstart
    a = jnp.where(_cost(rows, d, warm) < _cost(rows, d, d.qacc_smooth), warm, d.qacc_smooth)
    structure = hessian_structure(m)
    # The loop carries the next step's gradient and Hessian: a loop boundary is the one place
    # where XLA is sure to materialise H rather than fuse it into its readers.
    jl, jc = rows.jar(a)
    carry = (a, jl, jc, *_quadratic(rows, d, a, jl, jc))
    carry = jax.lax.fori_loop(0, m.solver_iterations, lambda _, c: _newton_step(structure, rows, d, c), carry)
    a = carry[0]
    jl, jc = rows.jar(a)
    fl, fc = -rows.lim_D * jnp.minimum(jl, 0.0), -rows.dd * jnp.minimum(jc, 0.0)
    return d.replace(qacc=a, efc_force=jnp.concatenate([fl, fc]), qfrc_constraint=rows.jt(fl, fc))
