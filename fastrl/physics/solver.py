"""Constraint solver: Newton's method on MuJoCo's primal cost, with a static iteration count.

MuJoCo's soft constraints turn the constrained dynamics into the unconstrained convex problem

    qacc = argmin_a  1/2 (a - a0)^T M (a - a0) + sum_i 1/2 D_i min(J_i a - aref_i, 0)^2

with ``a0`` the unconstrained acceleration (pyramidal contacts and limits; ``D = 1/R``). The
cost is piecewise quadratic, so Newton's method finds the exact minimiser once it has the right
active set, usually in 2-4 steps from a warm start: better accuracy per unit of compute than
projected Gauss-Seidel or conjugate gradients, which need tens of cheaper iterations on the stiff
contact problems of locomotion. Each step solves with ``H = M + J^T diag(D * active) J`` (dense
Cholesky; nv is small) and then runs a few 1-D Newton steps on the exact piecewise-quadratic line
cost. The iteration counts are static (``Model.solver_iterations``, ``LINESEARCH_ITERATIONS``), so
the program has no data-dependent loop; a converged iterate stays put (zero step).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fastrl.physics.types import Data, Model

LINESEARCH_ITERATIONS = 3


def _cost(d: Data, a: jax.Array) -> jax.Array:
    jar = d.efc_J @ a - d.efc_aref
    da = a - d.qacc_smooth
    return 0.5 * da @ (d.qM @ da) + 0.5 * jnp.sum(d.efc_D * jnp.minimum(jar, 0.0) ** 2)


def _newton_step(d: Data, a: jax.Array) -> jax.Array:
    jac, dd = d.efc_J, d.efc_D
    jar = jac @ a - d.efc_aref
    quad = dd * (jar < 0)
    ma = d.qM @ (a - d.qacc_smooth)
    grad = ma + jac.T @ (quad * jar)
    hess = d.qM + (jac.T * quad) @ jac
    chol = jnp.linalg.cholesky(hess)
    step = -jax.scipy.linalg.cho_solve((chol, True), grad)
    # Exact line search on phi(alpha) = cost(a + alpha step), piecewise quadratic and convex.
    js = jac @ step
    s_m_s = step @ (d.qM @ step)
    s_m_a = step @ ma
    alpha = jnp.ones((), a.dtype)
    for _ in range(LINESEARCH_ITERATIONS):
        trial = jar + alpha * js
        neg = dd * (trial < 0)
        slope = alpha * s_m_s + s_m_a + jnp.sum(neg * trial * js)
        curve = s_m_s + jnp.sum(neg * js * js)
        alpha = jnp.maximum(alpha - slope / jnp.maximum(curve, 1e-30), 0.0)
    return a + alpha * step


def solve(m: Model, d: Data) -> Data:
    """Constraint forces and the constrained acceleration: ``qacc``, ``efc_force``, ``qfrc_constraint``.

    Starts from the cheaper of ``qacc_warmstart`` (the last step's acceleration) and
    ``qacc_smooth``, as MuJoCo does, then takes ``m.solver_iterations`` Newton steps.
    """
    warm = d.qacc_warmstart
    a = jnp.where(_cost(d, warm) < _cost(d, d.qacc_smooth), warm, d.qacc_smooth)
    a = jax.lax.fori_loop(0, m.solver_iterations, lambda _, a: _newton_step(d, a), a)
    jar = d.efc_J @ a - d.efc_aref
    force = -d.efc_D * jnp.minimum(jar, 0.0)
    return d.replace(qacc=a, efc_force=force, qfrc_constraint=d.efc_J.T @ force)
