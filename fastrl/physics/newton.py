"""MuJoCo's Newton solver as written: islands, tolerances and its inexact line search.

``solver.solve`` takes a fixed number of Newton steps, each with an exact line search; once the
iterate has converged the two agree with MuJoCo to rounding. A scene tuned for a truncated solve
(MuJoCo Playground's scenes take 1 to 5 iterations with 5 to 10 line-search evaluations) does not
converge in one step, and where MuJoCo stops then depends on the details of its algorithm. This
module follows them (``mj_solNewton`` in MuJoCo's ``engine_solver.c``):

- **Islands** (``island.py``). Trees that share a constraint row form an island; each island is
  solved on its own, with its own scale, line search and termination. Dofs in no island take
  ``qacc_smooth``.
- **Start and early exit.** The better of the warm start and ``qacc_smooth`` (ties keep the warm
  start); an island whose duality gap ``grad' M^-1 grad / 2`` and gradient are already below
  ``tolerance`` (scaled) takes no step, nor one whose Newton decrement is. After each step an
  island stops when its improvement, gradient or Newton decrement falls below ``tolerance``, or
  when its line search finds no improvement.
- **Line search** (``linesearch.py``, ``PrimalSearch``): MuJoCo's Newton-then-bracket search
  on each island's piecewise-quadratic line cost.

The solve runs until every island has stopped, at most ``Model.solver_iterations`` Newton
steps (MuJoCo's ``iterations``, see ``io.asset_solver_iterations``); under ``vmap`` a batch runs
until all its elements' islands have. The loop is not differentiated: the solve's derivative is
that of one Newton step at its solution (``_solve_jvp``), so the solve stays differentiable.
"""

from __future__ import annotations

import typing

import jax
import jax.numpy as jnp

from fastrl.physics import factor, linesearch
from fastrl.physics.island import Islands, each, islands
from fastrl.physics.solver import Rows, finish, gradient_hessian, hessian_structure, make_rows, primal_cost
from fastrl.physics.types import Data, Model


def solve(m: Model, d: Data) -> Data:
    """``qacc``, ``efc_force`` and ``qfrc_constraint`` by MuJoCo's Newton solver (module docstring)."""
    return _solve(m, d)


@jax.custom_jvp
def _solve(m: Model, d: Data) -> Data:
    rows = make_rows(m, d)
    return finish(rows, d, _iterate(m, d, rows))


@_solve.defjvp
def _solve_jvp(primals, tangents):
    """Differentiates the solve at its solution (the implicit function theorem): one full Newton
    step from the solution ``a*``, ``a* - H^-1 grad(a*)``, has the derivative
    ``-H^-1 d grad`` with the active rows held, which is how the solution moves; its value is
    replaced by the solve's own. The loop that found ``a*`` is not differentiated (a
    ``while_loop`` has no transpose, and its step lengths carry no gradient anyway)."""
    m, d = primals
    out = _solve(m, d)
    a = jax.lax.stop_gradient(out.qacc)
    structure = hessian_structure(m)

    def newton_step(m, d):
        rows = make_rows(m, d)
        grad, hess = gradient_hessian(rows, d, a, rows.jar(a), product=True)
        return finish(rows, d, a - factor.solve_structured(structure, hess, grad))

    _, tangent = jax.jvp(newton_step, primals, tangents)
    return out, tangent


class _Iterate(typing.NamedTuple):
    """The Newton loop's state."""

    k: jax.Array  # () steps taken
    a: jax.Array  # (nv,) qacc
    res: tuple[jax.Array, ...]  # J a - aref, per row group
    mgrad: jax.Array  # (nv,) H^-1 grad at a
    stopped: jax.Array  # (ntree,) whether each island has stopped


def _start(m: Model, d: Data, rows: Rows, isl: Islands) -> _Iterate:
    """The start (the better of the warm start and ``qacc_smooth``), its Newton direction, and
    which islands need no step: no island, or a duality gap and gradient, or a Newton decrement
    and gradient, already below the tolerance (scaled)."""
    tol = m.solver_tolerance
    constrained = jnp.any(isl.dof > 0, axis=0)
    warm = d.qacc_warmstart
    a = jnp.where(primal_cost(rows, d, warm) > primal_cost(rows, d, d.qacc_smooth), d.qacc_smooth, warm)
    a = jnp.where(constrained, a, d.qacc_smooth)
    res = rows.jar(a)
    # H as matrix products: unrolled sums of outer products measured slower here, even for few
    # rows (physics step at batch 1024, us/env: Go1 flat, 16 contact rows, 9.9 -> 8.6; Go1 rough,
    # 160, 42.8 -> 20.4; the Berkeley humanoid, Panda and Leap unchanged)
    grad, hess = gradient_hessian(rows, d, a, res, product=True)
    real = isl.scale > 0
    gradient_ok = isl.scale * isl.norm(grad) < tol
    gap = jnp.maximum(0.0, 0.5 * isl.scale * isl.per(grad * factor.solve(m, d.qM, grad))) < tol
    mgrad = factor.solve_structured(hessian_structure(m), hess, grad)
    decrement = jnp.maximum(0.0, 0.5 * isl.scale * isl.per(grad * mgrad))
    stopped = ~real | (gap & gradient_ok) | (gradient_ok & (decrement < tol))
    return _Iterate(0, a, res, mgrad, stopped)


def _iterate(m: Model, d: Data, rows: Rows) -> jax.Array:
    """The solution ``qacc``: Newton steps until every island has stopped, at most
    ``m.solver_iterations`` (MuJoCo's ``iterations``); under ``vmap``, until every element's
    islands have."""
    isl = islands(m, rows, d.qM)
    tol = m.solver_tolerance
    structure = hessian_structure(m)

    def move(it: _Iterate):
        """One Newton step of every island that has not stopped: the new ``a`` and its
        residuals, whether each island moved, and its cost improvement."""
        search = -it.mgrad * each(isl.dof, (~it.stopped).astype(it.a.dtype))
        cost = linesearch.line(rows, isl, d, it.a, it.res, search)
        ls_tol = tol * m.ls_tolerance
        alpha, improvement = linesearch.line_search(cost, search, ~it.stopped, ls_tol, m.ls_iterations)
        moved = ~it.stopped & (alpha != 0)
        alpha = jnp.where(moved, alpha, 0.0)
        a = it.a + each(isl.dof, alpha) * search
        js = rows.j(search)
        res = tuple(r + each(o, alpha) * s for r, s, o in zip(it.res, js, isl.row_maps(), strict=True))
        return a, res, moved, improvement

    def step(it: _Iterate) -> _Iterate:
        """A step, then the Hessian and direction at the new point and the stopping tests."""
        a, res, moved, improvement = move(it)
        grad, hess = gradient_hessian(rows, d, a, res, product=True)
        mgrad = factor.solve_structured(structure, hess, grad)
        improvement = isl.scale * improvement
        gradient = isl.scale * isl.norm(grad)
        decrement = jnp.maximum(0.0, 0.5 * isl.scale * isl.per(grad * mgrad))
        converged = ((improvement > 0) & (improvement < tol)) | (gradient < tol) | (decrement < tol)
        return _Iterate(it.k + 1, a, res, mgrad, it.stopped | ~moved | converged)

    def last(it: _Iterate) -> _Iterate:
        """The last allowed step: nothing follows it, so no Hessian after it."""
        a, res, _, _ = move(it)
        return _Iterate(it.k + 1, a, res, it.mgrad, jnp.ones_like(it.stopped))

    def before(steps):
        return lambda it: (it.k < steps) & ~jnp.all(it.stopped)

    # Leap's solve takes its 5 steps in most of a batch: 5 Hessians and factors instead of 6. The
    # last step is a loop of at most one pass, so a batch whose islands have all stopped skips it.
    it = _start(m, d, rows, isl)
    if m.solver_iterations == 1:  # MJX-tuned scenes: one step needs no loop (a loop costs ~25%)
        return last(it).a
    it = jax.lax.while_loop(before(m.solver_iterations - 1), step, it)
    return jax.lax.while_loop(before(m.solver_iterations), last, it).a
