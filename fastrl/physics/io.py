"""Building a ``Model`` from MJCF with MuJoCo's own compiler, and a fresh ``Data``."""

from __future__ import annotations

import os

import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.physics.types import Data, Integrator, JointType, Model

_DSBL = mujoco.mjtDisableBit
_INTEGRATORS = {"euler": Integrator.EULER, "rk4": Integrator.RK4}


class UnsupportedFeatureError(ValueError):
    """The MJCF model uses something fastrl does not simulate; the message names it."""


def _names(m: mujoco.MjModel, objtype: mujoco.mjtObj, n: int) -> tuple[str, ...]:
    return tuple(mujoco.mj_id2name(m, objtype, i) or f"<unnamed {i}>" for i in range(n))


def _compile(path_or_xml: str | os.PathLike) -> mujoco.MjModel:
    text = str(path_or_xml)
    if text.lstrip().startswith("<"):
        return mujoco.MjModel.from_xml_string(text)
    if not os.path.exists(text):
        raise FileNotFoundError(f"MJCF file not found: {text!r}")
    return mujoco.MjModel.from_xml_path(text)


def _nonzero(m: mujoco.MjModel, field: str) -> bool:
    value = getattr(m, field, None)
    return value is not None and np.size(value) > 0 and bool(np.any(np.asarray(value) != 0))


def _first(m: mujoco.MjModel, mask: np.ndarray, objtype: mujoco.mjtObj) -> str:
    i = int(np.flatnonzero(mask)[0])
    return f"{mujoco.mjtObj(objtype).name[6:].lower()} {mujoco.mj_id2name(m, objtype, i) or i!r}"


def _check_supported(m: mujoco.MjModel) -> None:
    """Raises ``UnsupportedFeatureError`` for anything that would make a silently wrong model."""
    obj = mujoco.mjtObj
    flags = m.opt.disableflags
    problems = []
    for count, what in [
        (m.ntendon, "tendons"),
        (m.neq, "equality constraints"),
        (m.nflex, "flexes"),
        (m.nplugin, "plugins"),
        (m.nmocap, "mocap bodies"),
    ]:
        if count:
            problems.append(f"{what} ({count} in the model)")
    if m.opt.density > 0 or m.opt.viscosity > 0:
        problems.append("fluid forces (option density/viscosity > 0)")
    if _nonzero(m, "body_gravcomp"):
        problems.append(f"gravity compensation ({_first(m, m.body_gravcomp != 0, obj.mjOBJ_BODY)})")
    if _nonzero(m, "dof_frictionloss") and not flags & _DSBL.mjDSBL_FRICTIONLOSS:
        mask = np.zeros(m.njnt, bool)
        mask[m.dof_jntid[m.dof_frictionloss > 0]] = True
        problems.append(f"dof friction loss ({_first(m, mask, obj.mjOBJ_JOINT)})")
    for field in ("dof_dampingpoly", "jnt_stiffnesspoly", "jnt_springyield"):
        if _nonzero(m, field):
            problems.append(f"nonlinear joint passive forces ({field})")
    stiff_3d = (m.jnt_stiffness != 0) & (m.jnt_type <= JointType.BALL)
    if stiff_3d.any():
        problems.append(f"stiffness on a free/ball joint ({_first(m, stiff_3d, obj.mjOBJ_JOINT)})")
    for field in ("actuator_damping", "actuator_armature", "actuator_delay", "actuator_dampingpoly"):
        if _nonzero(m, field):
            problems.append(f"actuator {field[9:]}")
    for i in range(m.nu):
        name = mujoco.mj_id2name(m, obj.mjOBJ_ACTUATOR, i) or str(i)
        trn, jid = m.actuator_trntype[i], m.actuator_trnid[i, 0]
        if trn != int(mujoco.mjtTrn.mjTRN_JOINT):
            problems.append(f"actuator {name!r}: transmission {mujoco.mjtTrn(trn).name}")
        elif m.jnt_type[jid] not in (JointType.HINGE, JointType.SLIDE):
            problems.append(f"actuator {name!r}: drives a free/ball joint")
        if m.actuator_dyntype[i] != int(mujoco.mjtDyn.mjDYN_NONE):
            dyn = mujoco.mjtDyn(m.actuator_dyntype[i]).name
            problems.append(f"actuator {name!r}: activation dynamics {dyn} (use timeconst=0)")
        if m.actuator_gaintype[i] > int(mujoco.mjtGain.mjGAIN_AFFINE):
            problems.append(f"actuator {name!r}: gain {mujoco.mjtGain(m.actuator_gaintype[i]).name}")
        if m.actuator_biastype[i] > int(mujoco.mjtBias.mjBIAS_AFFINE):
            problems.append(f"actuator {name!r}: bias {mujoco.mjtBias(m.actuator_biastype[i]).name}")
    limited = m.jnt_limited.astype(bool)
    if limited.any() and not flags & (_DSBL.mjDSBL_LIMIT | _DSBL.mjDSBL_CONSTRAINT):
        problems.append(
            f"joint limits ({_first(m, limited, obj.mjOBJ_JOINT)}); the constraint solver is not "
            "built yet: remove the range or add <flag limit='disable'/>"
        )
    pairs = candidate_geom_pairs(m)
    if pairs and not flags & (_DSBL.mjDSBL_CONTACT | _DSBL.mjDSBL_CONSTRAINT):
        g1, g2 = pairs[0]
        n1 = mujoco.mj_id2name(m, obj.mjOBJ_GEOM, g1) or g1
        n2 = mujoco.mj_id2name(m, obj.mjOBJ_GEOM, g2) or g2
        problems.append(
            f"contacts ({len(pairs)} geom pairs can touch, e.g. {n1!r}-{n2!r}); collision is not "
            "built yet: set contype/conaffinity to 0 or add <flag contact='disable'/>"
        )
    if problems:
        raise UnsupportedFeatureError("fastrl cannot simulate this model yet: " + "; ".join(problems))


def candidate_geom_pairs(m: mujoco.MjModel) -> list[tuple[int, int]]:
    """Geom pairs that MuJoCo's broadphase filter could let touch (contype/conaffinity, exclusions).

    Excludes pairs in one welded body, pairs of two world-welded geoms, parent-child pairs (unless
    filterparent is disabled) and ``<exclude>``d body pairs; adds explicit ``<pair>`` elements.
    """
    weld = m.body_weldid
    parent = m.body_parentid
    filterparent = not m.opt.disableflags & _DSBL.mjDSBL_FILTERPARENT
    excluded = {(int(s) >> 16, int(s) & 0xFFFF) for s in m.exclude_signature}
    pairs = []
    for g1 in range(m.ngeom):
        for g2 in range(g1 + 1, m.ngeom):
            if not (m.geom_contype[g1] & m.geom_conaffinity[g2]) and not (
                m.geom_contype[g2] & m.geom_conaffinity[g1]
            ):
                continue
            b1, b2 = m.geom_bodyid[g1], m.geom_bodyid[g2]
            w1, w2 = weld[b1], weld[b2]
            if w1 == w2 or (w1 == 0 and w2 == 0):
                continue
            if filterparent and w1 != 0 and w2 != 0:
                if weld[parent[w1]] == w2 or weld[parent[w2]] == w1:
                    continue
            if (min(b1, b2), max(b1, b2)) in excluded or (b1 << 16 | b2) in excluded:
                continue
            pairs.append((g1, g2))
    pairs += [(int(a), int(b)) for a, b in zip(m.pair_geom1, m.pair_geom2, strict=True)]
    return pairs


def model_from_mujoco(m: mujoco.MjModel, integrator: str | None = None) -> Model:
    """Converts a compiled ``mujoco.MjModel`` into fastrl's ``Model`` (see ``load_mjcf``)."""
    _check_supported(m)
    if integrator is not None:
        if integrator not in _INTEGRATORS:
            raise ValueError(f"integrator={integrator!r}; choose one of {sorted(_INTEGRATORS)}")
        integ = _INTEGRATORS[integrator]
    elif m.opt.integrator in (Integrator.EULER, Integrator.RK4):
        integ = Integrator(m.opt.integrator)
    else:
        name = mujoco.mjtIntegrator(m.opt.integrator).name
        raise UnsupportedFeatureError(
            f"integrator {name} is not implemented; pass integrator='euler' or 'rk4' to load_mjcf"
        )
    obj = mujoco.mjtObj
    i32 = lambda x: np.asarray(x, dtype=np.int32).copy()  # noqa: E731
    f = lambda x: jnp.asarray(np.asarray(x, dtype=np.float64))  # noqa: E731
    gravity = m.opt.gravity * (0.0 if m.opt.disableflags & _DSBL.mjDSBL_GRAVITY else 1.0)
    return Model(
        nq=m.nq, nv=m.nv, nu=m.nu, nbody=m.nbody, njnt=m.njnt, ngeom=m.ngeom, nsite=m.nsite,
        body_parentid=i32(m.body_parentid), body_rootid=i32(m.body_rootid),
        body_jntnum=i32(m.body_jntnum), body_jntadr=i32(m.body_jntadr),
        body_dofnum=i32(m.body_dofnum), body_dofadr=i32(m.body_dofadr),
        jnt_type=i32(m.jnt_type), jnt_qposadr=i32(m.jnt_qposadr), jnt_dofadr=i32(m.jnt_dofadr),
        jnt_bodyid=i32(m.jnt_bodyid), jnt_limited=i32(m.jnt_limited),
        dof_bodyid=i32(m.dof_bodyid), dof_jntid=i32(m.dof_jntid), dof_parentid=i32(m.dof_parentid),
        geom_bodyid=i32(m.geom_bodyid), geom_type=i32(m.geom_type),
        geom_contype=i32(m.geom_contype), geom_conaffinity=i32(m.geom_conaffinity),
        site_bodyid=i32(m.site_bodyid),
        actuator_trnid=i32(m.actuator_trnid[:, 0]),
        actuator_gaintype=i32(m.actuator_gaintype), actuator_biastype=i32(m.actuator_biastype),
        actuator_ctrllimited=i32(m.actuator_ctrllimited),
        actuator_forcelimited=i32(m.actuator_forcelimited),
        jnt_actfrclimited=i32(m.jnt_actfrclimited),
        integrator=int(integ), disableflags=int(m.opt.disableflags),
        body_names=_names(m, obj.mjOBJ_BODY, m.nbody), jnt_names=_names(m, obj.mjOBJ_JOINT, m.njnt),
        geom_names=_names(m, obj.mjOBJ_GEOM, m.ngeom), site_names=_names(m, obj.mjOBJ_SITE, m.nsite),
        actuator_names=_names(m, obj.mjOBJ_ACTUATOR, m.nu),
        timestep=f(m.opt.timestep), gravity=f(gravity),
        body_pos=f(m.body_pos), body_quat=f(m.body_quat), body_ipos=f(m.body_ipos),
        body_iquat=f(m.body_iquat), body_mass=f(m.body_mass), body_inertia=f(m.body_inertia),
        jnt_pos=f(m.jnt_pos), jnt_axis=f(m.jnt_axis), jnt_stiffness=f(m.jnt_stiffness),
        jnt_range=f(m.jnt_range), jnt_actfrcrange=f(m.jnt_actfrcrange),
        qpos0=f(m.qpos0), qpos_spring=f(m.qpos_spring),
        dof_armature=f(m.dof_armature), dof_damping=f(m.dof_damping),
        geom_pos=f(m.geom_pos), geom_quat=f(m.geom_quat), geom_size=f(m.geom_size),
        geom_friction=f(m.geom_friction), site_pos=f(m.site_pos), site_quat=f(m.site_quat),
        actuator_gear=f(m.actuator_gear), actuator_ctrlrange=f(m.actuator_ctrlrange),
        actuator_forcerange=f(m.actuator_forcerange),
        actuator_gainprm=f(m.actuator_gainprm), actuator_biasprm=f(m.actuator_biasprm),
    )  # fmt: skip


def load_mjcf(path_or_xml: str | os.PathLike, integrator: str | None = None) -> Model:
    """Compiles an MJCF file (or XML string) with MuJoCo's compiler into a fastrl ``Model``.

    Defaults, inertias from geoms and actuator gains are exactly as MuJoCo computes them. Features
    fastrl does not simulate raise ``UnsupportedFeatureError`` naming the element and feature.

    Args:
      path_or_xml: a path to an ``.xml`` file, or the XML text itself.
      integrator: ``"euler"`` or ``"rk4"`` to override the model's ``<option integrator>``.
    Returns:
      The ``Model``; float parameters are float32 unless ``jax_enable_x64`` is on.
    """
    return model_from_mujoco(_compile(path_or_xml), integrator)


def make_data(model: Model, qpos=None, qvel=None, ctrl=None) -> Data:
    """A ``Data`` at ``qpos0`` (or ``qpos``) with zero velocity; derived fields are zero.

    Call ``physics.forward`` to fill the derived fields, as after ``mj_forward``.
    """
    dtype = model.body_mass.dtype
    z = lambda *s: jnp.zeros(s, dtype)  # noqa: E731
    nb, nj, ng, ns, nv, nu = model.nbody, model.njnt, model.ngeom, model.nsite, model.nv, model.nu
    qpos = model.qpos0 if qpos is None else jnp.asarray(qpos, dtype)
    qvel = z(nv) if qvel is None else jnp.asarray(qvel, dtype)
    ctrl = z(nu) if ctrl is None else jnp.asarray(ctrl, dtype)
    for name, value, n in (("qpos", qpos, model.nq), ("qvel", qvel, nv), ("ctrl", ctrl, nu)):
        if value.shape != (n,):
            raise ValueError(f"{name} has shape {value.shape}; this model needs ({n},)")
    eye = jnp.broadcast_to(jnp.eye(3, dtype=dtype), (nb, 3, 3))
    return Data(
        qpos=qpos, qvel=qvel, ctrl=ctrl, time=z(), qfrc_applied=z(nv),
        xpos=z(nb, 3), xquat=z(nb, 4).at[:, 0].set(1.0), xmat=eye, xipos=z(nb, 3), ximat=eye,
        xanchor=z(nj, 3), xaxis=z(nj, 3), geom_xpos=z(ng, 3), geom_xmat=z(ng, 3, 3),
        site_xpos=z(ns, 3), site_xmat=z(ns, 3, 3), subtree_com=z(nb, 3), cinert=z(nb, 10),
        cdof=z(nv, 6), cvel=z(nb, 6), cdof_dot=z(nv, 6), qM=z(nv, nv), qfrc_bias=z(nv),
        qfrc_spring=z(nv), qfrc_damper=z(nv), qfrc_passive=z(nv), actuator_length=z(nu),
        actuator_velocity=z(nu), actuator_force=z(nu), qfrc_actuator=z(nv), qfrc_smooth=z(nv),
        qacc=z(nv), diverged=jnp.zeros((), bool),
    )  # fmt: skip
