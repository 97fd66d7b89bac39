"""The step: forward dynamics, then integration (mj_forward, mj_Euler, mj_RungeKutta).

    step = forward (kinematics -> com quantities -> tendons -> mass matrix -> bias forces
                    -> passive -> actuation -> qacc = M^-1 qfrc_smooth
                    [-> collision -> constraint rows -> solver [-> noslip]])
         + integrate (semi-implicit Euler with implicit joint damping, implicitfast, or RK4;
                      activations ``act`` advance with them)

As in MuJoCo, after ``step`` the derived fields (poses, forces, ``qacc``) describe the state the
step started from (for RK4, its last stage), while ``qpos``/``qvel``/``act``/``time`` are the new
state.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.physics import constraint, derivative, factor, math, newton, noslip, smooth, solver, tendon
from fastrl.physics.actuation import actuation, next_activation
from fastrl.physics.collision_driver import collision
from fastrl.physics.passive import passive
from fastrl.physics.types import Data, Integrator, JointType, Model

_DSBL = mujoco.mjtDisableBit
# Beyond this magnitude MuJoCo's mj_checkPos/mj_checkVel declare the state bad; so do we.
DIVERGENCE_BOUND = 1e10


def forward_forces(m: Model, d: Data) -> Data:
    """Every derived quantity up to the total smooth force ``qfrc_smooth`` (no solve)."""
    d = smooth.kinematics(m, d)
    d = smooth.com_pos(m, d)
    d = tendon.tendon(m, d)
    d = smooth.crb(m, d)
    d = smooth.com_vel(m, d)
    d = smooth.rne(m, d)
    d = tendon.armature(m, d)
    d = passive(m, d)
    d = actuation(m, d)
    return d.replace(qfrc_smooth=d.qfrc_passive - d.qfrc_bias + d.qfrc_actuator + d.qfrc_applied)


def has_constraints(m: Model) -> bool:
    """Whether the model has any constraint rows; without, no collision or solver is traced."""
    return constraint.sizes(m)[1] > 0


def forward(m: Model, d: Data) -> Data:
    """Computes every derived quantity and the acceleration ``qacc`` of the current state.

    Smooth dynamics, then (if the model has any) collisions, constraint rows and the solver.
    """
    d = forward_forces(m, d)
    qacc_smooth = smooth.solve_mass(m, d, d.qfrc_smooth)
    d = d.replace(qacc_smooth=qacc_smooth, qacc=qacc_smooth)
    if not has_constraints(m):
        return d
    d = collision(m, d)
    d = constraint.make_constraint(m, d)
    d = (newton.solve if m.linesearch == "mujoco" else solver.solve)(m, d)
    return noslip.solve(m, d) if m.noslip_iterations else d


def _implicit_damping(m: Model) -> bool:
    return not m.disableflags & (_DSBL.mjDSBL_EULERDAMP | _DSBL.mjDSBL_DAMPER)


def _activates(m: Model) -> bool:
    """Whether the step advances activations: the model has some, and actuation is enabled."""
    return bool(m.na) and not m.disableflags & _DSBL.mjDSBL_ACTUATION


def _advance_act(m: Model, d: Data, act_dot: jax.Array) -> jax.Array:
    """(na,) the activations after the step (mj_advance): ``next_activation`` at ``act_dot``."""
    return next_activation(m, d.act, act_dot) if _activates(m) else d.act


def integrate_pos(m: Model, qpos: jax.Array, qvel: jax.Array, dt: jax.Array) -> jax.Array:
    """Advances positions by velocities over ``dt``; quaternions rotate on the unit sphere."""
    jt = m.jnt_type
    lin_q, lin_v, quat_q, quat_v = [], [], [], []
    for j, t in enumerate(jt):
        qa, va = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
        if t in (JointType.HINGE, JointType.SLIDE):
            lin_q.append([qa])
            lin_v.append([va])
        elif t == JointType.FREE:
            lin_q.append([qa, qa + 1, qa + 2])
            lin_v.append([va, va + 1, va + 2])
            quat_q.append(qa + 3)
            quat_v.append(va + 3)
        else:
            quat_q.append(qa)
            quat_v.append(va)
    out = qpos
    if lin_q:
        iq, iv = np.concatenate(lin_q), np.concatenate(lin_v)
        out = out.at[iq].set(qpos[iq] + dt * qvel[iv])
    if quat_q:
        iq = np.asarray(quat_q)[:, None] + np.arange(4)
        iv = np.asarray(quat_v)[:, None] + np.arange(3)
        out = out.at[iq].set(math.quat_integrate(qpos[iq], qvel[iv], dt))
    return out


def _check(d: Data) -> jax.Array:
    state = jnp.concatenate([d.qpos, d.qvel])
    bad = ~jnp.all(jnp.isfinite(state)) | jnp.any(jnp.abs(state) > DIVERGENCE_BOUND)
    return d.diverged | bad


def euler(m: Model, d: Data) -> Data:
    """Semi-implicit Euler: velocity first, then position with the new velocity.

    Expects ``forward`` to have run. Joint damping is integrated implicitly,
    ``qacc = (M + h B)^-1 (qfrc_smooth + qfrc_constraint)``, as MuJoCo does for a model with
    damping unless ``eulerdamp`` is disabled: it keeps stiffly damped joints stable at large
    timesteps. As in MuJoCo, ``qacc`` stays forward's (the solver's, the next step's warm start;
    after a truncated solve it differs from ``M^-1 (qfrc_smooth + qfrc_constraint)``), except
    in a model without constraints, where ``step`` skips the smooth solve and ``qacc`` holds the
    damped acceleration.
    """
    h = m.timestep
    qacc = d.qacc
    if _implicit_damping(m):
        implicit = smooth.solve_mass(m, d, d.qfrc_smooth + d.qfrc_constraint, h * m.dof_damping)
        if has_constraints(m):  # as MuJoCo, only a model with damping integrates it implicitly
            qacc = jnp.where(jnp.any(m.dof_damping > 0), implicit, qacc)
        else:  # no solve ran: qacc is unset (and the damped one equals it where there is none)
            d = d.replace(qacc=implicit)
            qacc = implicit
    qvel = d.qvel + h * qacc
    qpos = integrate_pos(m, d.qpos, qvel, h)
    return d.replace(qpos=qpos, qvel=qvel, act=_advance_act(m, d, d.act_dot), time=d.time + h)


def implicitfast(m: Model, d: Data) -> Data:
    """MuJoCo's ``implicitfast``: Euler, implicit in the velocity-dependent smooth forces.

    ``qacc = (M - h D)^-1 (qfrc_smooth + qfrc_constraint)`` with ``D`` the velocity derivative of
    the passive and actuator forces (``derivative.smooth_vel``), so stiff dampers, velocity
    servos and fluid drag stay stable at large timesteps; trees that are one free joint also take
    their gyroscopic derivative (``derivative.free_tree_acc``), as MuJoCo 4.0 does. Positions then
    advance with the new velocity. Expects ``forward`` to have run; ``qacc`` stays forward's (as
    in MuJoCo), and so is the next step's warm start.
    """
    h = m.timestep
    qfrc = d.qfrc_smooth + d.qfrc_constraint
    deriv = derivative.smooth_vel(m, d)
    qh = d.qM - h * deriv
    free = m.jnt_dofadr[derivative.free_trees(m)][:, None] + np.arange(6)
    if free.size:  # those blocks are solved apart; keep the global factor's rows plain M (as MuJoCo)
        block = free[:, :, None], free[:, None, :]
        qh = qh.at[block].set(d.qM[block])
    qacc = derivative.free_tree_acc(m, d, deriv, qfrc, factor.solve(m, qh, qfrc))
    qvel = d.qvel + h * qacc
    qpos = integrate_pos(m, d.qpos, qvel, h)
    return d.replace(qpos=qpos, qvel=qvel, act=_advance_act(m, d, d.act_dot), time=d.time + h)


def _rotation_dofs(m: Model) -> np.ndarray:
    """(nblocks, 3) dof indices of every ball joint and of every free joint's rotation."""
    blocks = []
    for j, t in enumerate(m.jnt_type):
        if t == JointType.BALL:
            blocks.append(m.jnt_dofadr[j] + np.arange(3))
        elif t == JointType.FREE:
            blocks.append(m.jnt_dofadr[j] + np.arange(3, 6))
    return np.array(blocks, np.int64).reshape(-1, 3)


def _lie_velocity(m: Model, u: jax.Array, qvel: jax.Array) -> jax.Array:
    """Stage velocities in the Lie algebra: ``dexp^-1_u(omega)`` on each rotation, to 4th order.

    For an orientation written ``q0 exp(u)``, a body angular velocity omega moves u at
    ``omega + u x omega / 2 + u x (u x omega) / 12 + O(|u|^3)``: the Runge-Kutta-Munthe-Kaas
    correction that makes RK4 fourth order on orientations, as MuJoCo >= 4.0 does.
    """
    idx = _rotation_dofs(m)
    if not idx.size:
        return qvel
    ub, wb = u[idx], qvel[idx]
    c1 = math.cross(ub, wb)
    return qvel.at[idx].set(wb + 0.5 * c1 + math.cross(ub, c1) / 12.0)


def rk4(m: Model, d: Data) -> Data:
    """Fourth-order Runge-Kutta on (qpos, qvel), after ``forward`` at the start state.

    Stage i starts from the initial state advanced by ``a_i h`` along stage i-1's derivative.
    Positions advance on the joint manifold with ``integrate_pos``; ball and free-joint
    orientations use the Runge-Kutta-Munthe-Kaas form (stage velocities mapped into the Lie
    algebra by ``_lie_velocity``), which matches MuJoCo 4.0 to rounding. Stages are a
    ``lax.scan`` so ``forward`` is traced twice, not four times. Activations are integrated
    alongside (stages at ``act0 + a h act_dot``, unclamped), and advance at the weighted mean of
    the stages' ``act_dot`` by ``next_activation``, as MuJoCo's mj_RungeKutta does.
    """
    h = m.timestep
    q0, v0, act0, t0 = d.qpos, d.qvel, d.act, d.time
    coef = jnp.array([[0.5, 0.5, 2.0], [0.5, 0.5, 2.0], [1.0, 1.0, 1.0]], v0.dtype)  # (a, c, b)
    acts = _activates(m)

    def stage(carry, abc):
        di, k, sum_k, sum_a, sum_act = carry
        a, c, b = abc[0], abc[1], abc[2]
        qpos = integrate_pos(m, q0, k, a * h)  # q0 exp(u), u = a h k on rotations
        qvel = v0 + a * h * di.qacc
        act = act0 + a * h * di.act_dot if acts else di.act
        di = forward(m, di.replace(qpos=qpos, qvel=qvel, act=act, time=t0 + c * h))
        k = _lie_velocity(m, a * h * k, di.qvel)
        sum_act = sum_act + b * di.act_dot if acts else sum_act
        return (di, k, sum_k + b * k, sum_a + b * di.qacc, sum_act), None

    start = (d, d.qvel, d.qvel, d.qacc, d.act_dot if acts else ())
    (last, _, sum_k, sum_a, sum_act), _ = jax.lax.scan(stage, start, coef)
    qpos = integrate_pos(m, q0, sum_k, h / 6.0)
    qvel = v0 + (h / 6.0) * sum_a
    act = next_activation(m, act0, sum_act / 6.0) if acts else last.act
    return last.replace(qpos=qpos, qvel=qvel, act=act, time=t0 + h)


def step(m: Model, d: Data, ctrl: jax.Array | None = None) -> Data:
    """Advances the simulation by one timestep (mj_step). Jittable and vmappable.

    Args:
      m: the model.
      d: the data; its ``ctrl`` is used when ``ctrl`` is None.
      ctrl: (nu,) controls for this step.
    Returns:
      The data one timestep later; ``diverged`` turns True (and stays) if the state became
      non-finite or exceeded ``DIVERGENCE_BOUND``.
    """
    if ctrl is not None:
        d = d.replace(ctrl=jnp.asarray(ctrl, d.qvel.dtype))
    if m.integrator == Integrator.RK4:
        d = rk4(m, forward(m, d))
    elif m.integrator == Integrator.IMPLICITFAST:
        d = implicitfast(m, forward(m, d))
    elif _implicit_damping(m) and not has_constraints(m):
        d = euler(m, forward_forces(m, d))  # euler solves with M + hB itself
    else:
        d = euler(m, forward(m, d))
    return d.replace(diverged=_check(d), qacc_warmstart=d.qacc)
