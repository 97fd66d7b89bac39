"""Constraint solver: Newton's method on MuJoCo's primal cost, with a static iteration count.

MuJoCo's soft constraints turn the constrained dynamics into the unconstrained convex problem

    qacc = argmin_a  1/2 (a - a0)^T M (a - a0) + sum_i 1/2 D_i min(J_i a - aref_i, 0)^2

with ``a0`` the unconstrained acceleration (pyramidal contacts and limits; ``D = 1/R``), plus,
for each friction-loss row, the Huber-like ``1/2 D jar^2`` inside ``|D jar| < loss`` and
``loss |jar| - loss^2 / 2D`` outside it (a force bounded by the friction loss). The
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

This is ``Model.linesearch == "exact"``, how fastrl's environments step. ``newton.py`` follows
MuJoCo's own algorithm instead (islands, tolerances, its inexact line search, and a loop that
stops when they say so): where a scene's solve is truncated, only that one stops where MuJoCo
does.
"""

from __future__ import annotations

import typing

import jax
import jax.numpy as jnp
import numpy as np

from fastrl.physics import constraint, equality, factor, tree
from fastrl.physics.collision_driver import candidate_pairs
from fastrl.physics.math import matvec
from fastrl.physics.types import Data, Model

LINESEARCH_ITERATIONS = 3
# Up to this many multiply-adds per env (rows x nv^2) the fixed-budget solver adds a row set to H
# as an unrolled sum of outer products, beyond it as a matrix product. Measured, physics step at
# batch 256, us/env, unrolled vs product: Hopper (32 rows x 6^2) 21.4 vs 29.8, Walker2d (32 x 9^2)
# 25.8 vs 44.7, Ant (32 x 14^2) 51.9 vs 65.8; Humanoid (48 x 23^2) 208 vs 179, HumanoidStandup
# (140 x 23^2) 469 vs 254. A long unrolled sum also compiles slowly: an add chain thousands deep
# (a hand of 360 box-box pairs has 5764 rows) compiled for minutes and crashed XLA, hence the cap
# on rows too.
UNROLLED_HESSIAN_MAX_WORK = 8192
UNROLLED_HESSIAN_MAX_ROWS = 256
# With friction-loss rows (see ``_bracketed_newton``).
BRACKETED_LINESEARCH_ITERATIONS = 10


def hessian_structure(m: Model) -> tuple[tuple[int, ...], ...]:
    """Each dof's ancestors in the elimination order used to factorise the Newton Hessian.

    ``H = M + J^T D J`` keeps the kinematic tree's sparsity when every contact and equality has
    a static side (a robot on the ground: each row's Jacobian lives on one root-to-body path),
    so the tree's
    fill-free L^T D L factorisation applies, as for M. Otherwise H is factorised densely.
    """
    moving = tree.body_dof_ancestors(m).any(axis=1)
    b1 = m.geom_bodyid[m.pair_geom1]  # every pair that can hold a contact
    b2 = m.geom_bodyid[m.pair_geom2]
    coupled = np.any(moving[b1] & moving[b2]) or equality.couples_branches(m, moving)
    # a tendon's row may span branches too (its Jacobian reaches every joint it crosses)
    coupled = coupled or constraint.friction_tendons(m).size or constraint.limited_tendons(m).size
    if not coupled:
        return factor.ancestors(m)
    return tuple(tuple(range(k - 1, -1, -1)) for k in range(m.nv))


class _Cones(typing.NamedTuple):
    """One condim's elliptic-cone contacts: ``n`` blocks of ``dim`` rows (normal, friction dirs).

    MuJoCo's cost of a block, in the scaled residual ``U = (mu jar_0, f_1 jar_1, ...)`` with
    ``N = U_0`` and ``T = |U_1..|``: zero in the top zone ``N >= mu T`` (separating or sticking
    inside the cone), ``sum D_j jar_j^2 / 2`` in the bottom zone ``mu N + T <= 0``, and
    ``Dm (N - mu T)^2 / 2`` with ``Dm = D_0 / (mu^2 (1 + mu^2))`` between (sliding on the cone).
    ``mu = f_1 / sqrt(impratio)`` is the regularised cone's friction.
    """

    jac: jax.Array  # (n, dim, nv)
    aref: jax.Array  # (n, dim)
    dd: jax.Array  # (n, dim)
    mu: jax.Array  # (n,)
    fric: jax.Array  # (n, dim - 1)

    def zones(self, jar: jax.Array):
        """``(U, N, T, top, bottom, middle)`` of the blocks at residual ``jar`` (n, dim)."""
        u = jar * jnp.concatenate([self.mu[:, None], self.fric], 1)
        n, t = u[:, 0], jnp.sqrt(jnp.sum(u[:, 1:] ** 2, -1))
        top = n >= self.mu * t
        bottom = ~top & (self.mu * n + t <= 0)
        return u, n, t, top, bottom, ~top & ~bottom

    def dm(self) -> jax.Array:
        return self.dd[:, 0] / (self.mu**2 * (1 + self.mu**2))

    def cost(self, jar: jax.Array) -> jax.Array:
        _, n, t, _, bottom, middle = self.zones(jar)
        quad = 0.5 * jnp.sum(self.dd * jar**2, -1)
        return jnp.sum(
            jnp.where(bottom, quad, jnp.where(middle, 0.5 * self.dm() * (n - self.mu * t) ** 2, 0.0))
        )

    def grad_hess(self, jar: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The cost's gradient (n, dim) and Hessian (n, dim, dim) in ``jar`` (MuJoCo's cone
        Hessian in the middle zone)."""
        u, n, t, _, bottom, middle = self.zones(jar)
        mu, dim = self.mu[:, None], jar.shape[-1]
        ts = jnp.where(middle, t, 1.0)[:, None]
        s = (n - self.mu * t)[:, None]
        ds = jnp.concatenate([mu, -mu * self.fric * u[:, 1:] / ts], 1)  # d(N - mu T)/d jar
        dm = self.dm()[:, None]
        grad = jnp.where(bottom[:, None], self.dd * jar, jnp.where(middle[:, None], dm * s * ds, 0.0))
        # d^2 T / d jar^2 on the friction rows: f_j f_k (delta_jk / T - U_j U_k / T^3)
        ut = u[:, 1:] / ts
        curv_t = (jnp.eye(dim - 1, dtype=jar.dtype) - ut[:, :, None] * ut[:, None, :]) / ts[..., None]
        curv_t = curv_t * self.fric[:, :, None] * self.fric[:, None, :]
        hm = ds[:, :, None] * ds[:, None, :]
        hm = hm.at[:, 1:, 1:].add(-mu[..., None] * s[..., None] * curv_t)
        quad = self.dd[:, :, None] * jnp.eye(dim, dtype=jar.dtype)
        hess = jnp.where(
            bottom[:, None, None], quad, jnp.where(middle[:, None, None], dm[..., None] * hm, 0.0)
        )
        return grad, hess

    def slope_curve(self, jar: jax.Array, s: jax.Array, alpha: jax.Array):
        """phi'(alpha), phi''(alpha) of the blocks' cost along ``jar + alpha s`` (MuJoCo's forms)."""
        trial = jar + alpha * s
        _, n, t, _, bottom, middle = self.zones(trial)
        scale = jnp.concatenate([self.mu[:, None], self.fric], 1)
        v = s * scale
        v0 = v[:, 0]
        u = trial * scale
        uv, vv = jnp.sum(u[:, 1:] * v[:, 1:], -1), jnp.sum(v[:, 1:] ** 2, -1)
        ts = jnp.where(middle, t, 1.0)
        t1 = uv / ts
        t2 = vv / ts - uv * t1 / ts**2
        g = n - self.mu * t
        g1 = v0 - self.mu * t1
        dm = self.dm()
        slope_mid, curve_mid = dm * g * g1, dm * (g1**2 - g * self.mu * t2)
        slope_bot, curve_bot = jnp.sum(self.dd * trial * s, -1), jnp.sum(self.dd * s * s, -1)
        slope = jnp.where(bottom, slope_bot, jnp.where(middle, slope_mid, 0.0))
        curve = jnp.where(bottom, curve_bot, jnp.where(middle, curve_mid, 0.0))
        return jnp.sum(slope), jnp.sum(curve)


class Rows(typing.NamedTuple):
    """The constraint rows split the way the solver uses them (one environment).

    Friction-loss rows are unit vectors ``e_dof`` and limit rows signed unit vectors
    ``sign * e_dof``, both at static dofs, so products with them are reads of single dofs;
    scalar contact rows (pyramid edges, frictionless contacts) are dense (nc, nv), and
    elliptic-cone contacts are blocks (``_Cones``, one per condim).
    """

    eq_jac: jax.Array  # (ne, nv) equality rows
    eq_aref: jax.Array
    eq_D: jax.Array
    fr_dofs: np.ndarray  # (nfric_dof,) static: the dof friction rows, unit vectors
    tf_jac: jax.Array  # (nfric_ten, nv): the tendon friction rows, after the dofs'
    fr_aref: jax.Array  # (nfric,) all friction-loss rows, dofs' then tendons'
    fr_D: jax.Array
    fr_loss: jax.Array  # (nfric,) the friction loss: the most force a row can give
    lim_dofs: np.ndarray  # (nlim,) static
    lim_sign: jax.Array  # (nlim,)
    lim_aref: jax.Array
    lim_D: jax.Array
    jac: jax.Array  # (nc, nv) scalar contact rows
    aref: jax.Array
    dd: jax.Array
    cones: tuple[_Cones, ...]

    def j(self, a: jax.Array) -> tuple[jax.Array, ...]:
        """``J a`` of the friction-loss, limit, scalar contact rows and each cone group."""
        cones = tuple(matvec(c.jac, a) for c in self.cones)
        fric = (
            jnp.concatenate([a[self.fr_dofs], self.tf_jac @ a]) if self.tf_jac.shape[0] else a[self.fr_dofs]
        )
        return (fric, self.lim_sign * a[self.lim_dofs], self.jac @ a, self.eq_jac @ a, *cones)

    def jar(self, a: jax.Array) -> tuple[jax.Array, ...]:
        """``J a - aref``, split as ``j``."""
        arefs = (self.fr_aref, self.lim_aref, self.aref, self.eq_aref, *(c.aref for c in self.cones))
        return tuple(x - r for x, r in zip(self.j(a), arefs, strict=True))

    def jt(
        self, fr: jax.Array, lim: jax.Array, con: jax.Array, eq: jax.Array, *cones: jax.Array
    ) -> jax.Array:
        """``J^T f`` for row values split as ``j``."""
        nv = self.jac.shape[-1]
        out = con @ self.jac if self.aref.size else jnp.zeros(nv, fr.dtype)
        if self.eq_aref.size:
            out = out + eq @ self.eq_jac
        for c, f in zip(self.cones, cones, strict=True):
            out = out + jnp.einsum("nd,ndv->v", f, c.jac)
        if self.lim_dofs.size:
            out = out.at[self.lim_dofs].add(self.lim_sign * lim)
        if self.fr_dofs.size:
            out = out.at[self.fr_dofs].add(fr[: self.fr_dofs.size])
        if self.tf_jac.shape[0]:
            out = out + fr[self.fr_dofs.size :] @ self.tf_jac
        return out

    def friction_force(self, jf: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The friction-loss rows' ``-force`` at residual ``jf`` and their quadratic-zone mask.

        MuJoCo's friction-loss cost is Huber-like: ``D jar^2 / 2`` while ``|D jar| < loss``
        (the quadratic zone), else linear with slope ``loss`` (the force saturates at the
        friction loss, the zones MuJoCo calls LINEARNEG/LINEARPOS).
        """
        quad = jnp.abs(self.fr_D * jf) < self.fr_loss
        return jnp.clip(self.fr_D * jf, -self.fr_loss, self.fr_loss), quad

    def piecewise_linear(self) -> bool:
        """Whether the line cost has non-quadratic pieces (friction loss, cones)."""
        return bool(self.fr_aref.size or self.cones)


def make_rows(m: Model, d: Data) -> Rows:
    fr = constraint.friction_dofs(m)
    dofs = constraint.limit_dofs(m)
    ne = equality.nrows(m)
    nf = ne + constraint.nfriction(m)
    n = nf + dofs.size
    blocks = constraint.elliptic_blocks(m)
    end = blocks[0][1] if blocks else d.efc_aref.shape[0]
    cones = []
    pairs = candidate_pairs(m, d)
    for dim, row, slot, nslot in blocks:
        rows = slice(row, row + nslot * dim)
        fric = m.pair_friction[pairs[d.contact_id[slot : slot + nslot]], : dim - 1]
        mu = fric[:, 0] / jnp.sqrt(jnp.maximum(1e-15, m.impratio))
        cones.append(_Cones(d.efc_J[rows].reshape(nslot, dim, -1), d.efc_aref[rows].reshape(nslot, dim),
                            d.efc_D[rows].reshape(nslot, dim), mu, fric))  # fmt: skip
    ft = constraint.friction_tendons(m)
    loss = jnp.concatenate([m.dof_frictionloss[fr], m.tendon_frictionloss[ft]])
    return Rows(d.efc_J[:ne], d.efc_aref[:ne], d.efc_D[:ne],
                 fr, d.efc_J[ne + fr.size : nf], d.efc_aref[ne:nf], d.efc_D[ne:nf], loss,
                 dofs, d.efc_J[np.arange(nf, n), dofs], d.efc_aref[nf:n], d.efc_D[nf:n],
                 d.efc_J[n:end], d.efc_aref[n:end], d.efc_D[n:end], tuple(cones))  # fmt: skip


def primal_cost(rows: Rows, d: Data, a: jax.Array) -> jax.Array:
    jf, jl, jc, jq, *je = rows.jar(a)
    da = a - d.qacc_smooth
    f, dd = rows.fr_loss, rows.fr_D
    friction = jnp.where(jnp.abs(dd * jf) < f, 0.5 * dd * jf**2, f * jnp.abs(jf) - 0.5 * f**2 / dd)
    cones = sum((c.cost(r) for c, r in zip(rows.cones, je, strict=True)), jnp.zeros((), a.dtype))
    return (
        0.5
        * (
            jnp.sum(da * matvec(d.qM, da))
            + jnp.sum(rows.lim_D * jnp.minimum(jl, 0.0) ** 2)
            + jnp.sum(rows.dd * jnp.minimum(jc, 0.0) ** 2)
            + jnp.sum(rows.eq_D * jq**2)
        )
        + jnp.sum(friction)
        + cones
    )


def _add_outer(hess: jax.Array, left: jax.Array, right: jax.Array, product: bool) -> jax.Array:
    """``hess + left^T right`` for (r, nv) row sets: a matrix product where ``product`` is set or
    the rows are many (``UNROLLED_HESSIAN_MAX_WORK``), else an unrolled sum of outer products, one
    fused elementwise loop that XLA:CPU runs faster than tiny per-environment GEMMs. Such a sum
    must not meet a factorisation that XLA fuses it into (each of the factor's scalar reads would
    recompute it): the fixed-budget solver carries H across its loop, and ``newton`` always asks
    for the product (``gradient_hessian``)."""
    rows, nv = left.shape
    if product or rows > UNROLLED_HESSIAN_MAX_ROWS or rows * nv * nv > UNROLLED_HESSIAN_MAX_WORK:
        return hess + left.T @ right
    return hess + sum(left[r][:, None] * right[r][None, :] for r in range(rows))


def gradient_hessian(rows: Rows, d: Data, a: jax.Array, res: tuple[jax.Array, ...], product: bool = False):
    """Gradient and Hessian of the cost at ``a``, given its row residuals ``res = J a - aref``;
    ``product``: every row set's part of H as a matrix product (``_add_outer``).

    ``H = M + J^T diag(D * quadratic) J`` plus each cone block's ``J^T H_cone J``; friction-loss
    and limit rows (unit vectors) add to the diagonal.
    """
    jf, jl, jc, jq, *je = res
    quad_lim, quad = rows.lim_D * (jl < 0), rows.dd * (jc < 0)
    neg_fr, quad_fr = rows.friction_force(jf)
    cone_grads, hess = [], d.qM
    for c, r in zip(rows.cones, je, strict=True):
        g, h = c.grad_hess(r)
        cone_grads.append(g)
        hj = jnp.einsum("nij,njv->niv", h, c.jac)
        hess = _add_outer(hess, c.jac.reshape(-1, c.jac.shape[-1]), hj.reshape(-1, c.jac.shape[-1]), product)
    grad = matvec(d.qM, a - d.qacc_smooth) + rows.jt(
        neg_fr, quad_lim * jl, quad * jc, rows.eq_D * jq, *cone_grads
    )
    if rows.eq_D.size:
        hess = _add_outer(hess, rows.eq_jac * rows.eq_D[:, None], rows.eq_jac, product)
    if quad.size:
        hess = _add_outer(hess, rows.jac * quad[:, None], rows.jac, product)
    if rows.lim_dofs.size or rows.fr_dofs.size:
        nv = d.qM.shape[-1]
        diag = jnp.zeros(nv, hess.dtype).at[rows.lim_dofs].add(quad_lim)
        diag = diag.at[rows.fr_dofs].add((rows.fr_D * quad_fr)[: rows.fr_dofs.size])
        hess = hess + jnp.diag(diag)
    if rows.tf_jac.shape[0]:
        weight = (rows.fr_D * quad_fr)[rows.fr_dofs.size :]
        hess = _add_outer(hess, rows.tf_jac * weight[:, None], rows.tf_jac, product)
    return grad, hess


def _newton_1d(slope_curve, dtype) -> jax.Array:
    """1-D Newton steps on phi from alpha = 1, kept >= 0: exact in a few steps where every row's
    cost is quadratic or zero along the search line (limits and contacts)."""
    alpha = jnp.ones((), dtype)
    for _ in range(LINESEARCH_ITERATIONS):
        slope, curve = slope_curve(alpha)
        # curve >= step' M step > 0 unless the step is exactly zero (then slope is zero too). A
        # fixed floor such as 1e-30 is not safe: at convergence the step is at rounding level
        # (|step| ~ 1e-14 in float64, curve < 1e-30), and dividing the rounding noise of slope by
        # the floor gave alpha ~ 1e13, throwing a converged iterate far off.
        alpha = jnp.maximum(alpha - slope / jnp.maximum(curve, jnp.finfo(curve.dtype).tiny), 0.0)
    return alpha


def _bracketed_newton(slope_curve, dtype) -> jax.Array:
    """1-D Newton steps on phi kept inside a bracket of the minimiser, bisecting when a step
    leaves it. Friction-loss rows make phi linear in places (their force saturates), where
    the curvature drops and plain Newton steps overshoot back and forth past the kink (seen
    stalling Newton's method at alpha = 0 with the gradient far from zero)."""
    alpha = jnp.ones((), dtype)
    lo, hi = jnp.zeros((), dtype), jnp.full((), jnp.inf, dtype)
    for _ in range(BRACKETED_LINESEARCH_ITERATIONS):
        slope, curve = slope_curve(alpha)
        lo = jnp.where(slope < 0, alpha, lo)
        hi = jnp.where(slope > 0, alpha, hi)
        newton = alpha - slope / jnp.maximum(curve, jnp.finfo(curve.dtype).tiny)
        inside = (newton > lo) & (newton < hi)
        bisect = jnp.where(jnp.isfinite(hi), 0.5 * (lo + hi), 2 * alpha)
        alpha = jnp.where(slope == 0, alpha, jnp.where(inside, newton, bisect))
    return alpha


def _newton_step(structure, rows: Rows, d: Data, carry, last: bool = False):
    """One Newton step from ``carry = (a, res, grad, hess)``: the new ``(a, res, grad, hess)``, or
    ``(a, res)`` for the ``last`` step, whose gradient and Hessian nothing would read."""
    a, res, grad, hess = carry
    step = -factor.solve_structured(structure, hess, grad)
    # Exact line search on phi(alpha) = cost(a + alpha step), piecewise quadratic and convex.
    js = rows.j(step)  # directly, not jar(step) + aref: that cancels to rounding noise
    s_m_s = jnp.sum(step * matvec(d.qM, step))
    s_m_a = jnp.sum(step * matvec(d.qM, a - d.qacc_smooth))

    def slope_curve(alpha):
        """phi'(alpha) and phi''(alpha) (one-sided where a row changes zone)."""
        slope, curve = alpha * s_m_s + s_m_a, s_m_s
        for c, jar, s in zip(rows.cones, res[4:], js[4:], strict=True):
            sc, cc = c.slope_curve(jar, s, alpha)
            slope, curve = slope + sc, curve + cc
        if rows.eq_D.size:  # always quadratic
            slope = slope + jnp.sum(rows.eq_D * (res[3] + alpha * js[3]) * js[3])
            curve = curve + jnp.sum(rows.eq_D * js[3] ** 2)
        for jar, s, dd in ((res[1], js[1], rows.lim_D), (res[2], js[2], rows.dd)):
            trial = jar + alpha * s
            neg = dd * (trial < 0)
            slope = slope + jnp.sum(neg * trial * s)
            curve = curve + jnp.sum(neg * s * s)
        if rows.fr_aref.size:
            neg_fr, quad_fr = rows.friction_force(res[0] + alpha * js[0])
            slope = slope + jnp.sum(neg_fr * js[0])
            curve = curve + jnp.sum(rows.fr_D * quad_fr * js[0] ** 2)
        return slope, curve

    search = _bracketed_newton if rows.piecewise_linear() else _newton_1d
    alpha = search(slope_curve, a.dtype)
    # The step length carries no gradient: where the iterate has converged the step is zero and
    # d(alpha) = d(slope) / curve is 0/0 (NaN in reverse mode). With alpha held fixed, the
    # derivative of a converged Newton iterate is the implicit-function derivative of the
    # minimiser (the full step is alpha = 1 there), which is what differentiating the solve means.
    alpha = jax.lax.stop_gradient(alpha)
    a = a + alpha * step
    res = tuple(r + alpha * s for r, s in zip(res, js, strict=True))  # residuals are linear in a
    if last:
        return a, res
    return (a, res, *gradient_hessian(rows, d, a, res))


def solve(m: Model, d: Data) -> Data:
    """Constraint forces and the constrained acceleration: ``qacc``, ``efc_force``, ``qfrc_constraint``.

    Starts from the cheaper of ``qacc_warmstart`` (the last step's acceleration) and
    ``qacc_smooth``, as MuJoCo does, then takes ``m.solver_iterations`` Newton steps.
    """
    rows = make_rows(m, d)
    warm = d.qacc_warmstart
    a = jnp.where(primal_cost(rows, d, warm) < primal_cost(rows, d, d.qacc_smooth), warm, d.qacc_smooth)
    structure = hessian_structure(m)
    if m.solver_iterations == 0:
        return finish(rows, d, a)
    # The loop carries the next step's gradient and Hessian: a loop boundary is the one place
    # where XLA is sure to materialise H rather than fuse it into its readers.
    res = rows.jar(a)
    carry = (a, res, *gradient_hessian(rows, d, a, res))
    # The last step runs outside the loop: the gradient and Hessian a step ends with are the next
    # step's, and the last step's would go unread (a quarter of the Humanoid's Hessian work at 3
    # iterations).
    step = lambda _, c: _newton_step(structure, rows, d, c)  # noqa: E731
    carry = jax.lax.fori_loop(0, m.solver_iterations - 1, step, carry)
    return finish(rows, d, _newton_step(structure, rows, d, carry, last=True)[0])


def finish(rows: Rows, d: Data, a: jax.Array) -> Data:
    """``d`` with the solver's result ``qacc = a`` and the constraint forces it implies."""
    jf, jl, jc, jq, *je = rows.jar(a)
    ff = -rows.friction_force(jf)[0]
    fq = -rows.eq_D * jq
    fl, fc = -rows.lim_D * jnp.minimum(jl, 0.0), -rows.dd * jnp.minimum(jc, 0.0)
    fe = [-c.grad_hess(r)[0] for c, r in zip(rows.cones, je, strict=True)]
    force = jnp.concatenate([fq, ff, fl, fc, *(f.reshape(-1) for f in fe)])
    return d.replace(qacc=a, efc_force=force, qfrc_constraint=rows.jt(ff, fl, fc, fq, *fe))
