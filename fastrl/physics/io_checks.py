"""What of a compiled MuJoCo model fastrl simulates: the checks that refuse the rest
(``UnsupportedFeatureError``, naming each element and feature), and which of MuJoCo's features a
model's disable flags leave on (``contacts_enabled``, ``limits_enabled``...).
"""

from __future__ import annotations

import mujoco
import numpy as np

from fastrl.physics.collision_driver import SUPPORTED
from fastrl.physics.io_contacts import candidate_geom_pairs
from fastrl.physics.types import JointType

_DSBL = mujoco.mjtDisableBit
# The activation dynamics fastrl simulates (actuation.py); muscles, DC motors and PID servos not.
_DYNTYPES = tuple(
    int(getattr(mujoco.mjtDyn, f"mjDYN_{k}")) for k in ("NONE", "INTEGRATOR", "FILTER", "FILTEREXACT")
)


class UnsupportedFeatureError(ValueError):
    """The MJCF model uses something fastrl does not simulate; the message names it."""


def _nonzero(m: mujoco.MjModel, field: str) -> bool:
    value = getattr(m, field, None)
    return value is not None and np.size(value) > 0 and bool(np.any(np.asarray(value) != 0))


def _first(m: mujoco.MjModel, mask: np.ndarray, objtype: mujoco.mjtObj) -> str:
    i = int(np.flatnonzero(mask)[0])
    return f"{mujoco.mjtObj(objtype).name[6:].lower()} {mujoco.mj_id2name(m, objtype, i) or i!r}"


def _actuator_problems(m: mujoco.MjModel) -> list[str]:
    """Actuators fastrl does not simulate (their transmission, dynamics, gain or bias), each named
    with the reason, after the actuator features no actuator may use."""
    problems = []
    for field in ("actuator_damping", "actuator_armature", "actuator_delay", "actuator_dampingpoly"):
        if _nonzero(m, field):
            problems.append(f"actuator {field[9:]}")
    for i in range(m.nu):
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, i) or str(i)
        trn, jid = m.actuator_trntype[i], m.actuator_trnid[i, 0]
        joint = trn == int(mujoco.mjtTrn.mjTRN_JOINT)
        site = trn == int(mujoco.mjtTrn.mjTRN_SITE)
        if not joint and not site and trn != int(mujoco.mjtTrn.mjTRN_TENDON):
            problems.append(f"actuator {name!r}: transmission {mujoco.mjtTrn(trn).name}")
        elif site and m.actuator_trnid[i, 1] >= 0:
            problems.append(f"actuator {name!r}: transmission mjTRN_SITE with a refsite")
        elif joint and m.jnt_type[jid] not in (JointType.HINGE, JointType.SLIDE):
            problems.append(f"actuator {name!r}: drives a free/ball joint")
        if m.actuator_dyntype[i] not in _DYNTYPES:
            dyn = mujoco.mjtDyn(m.actuator_dyntype[i]).name
            problems.append(
                f"actuator {name!r}: activation dynamics {dyn} (fastrl simulates integrator, "
                "filter and filterexact)"
            )
        elif m.actuator_actnum[i] != (m.actuator_dyntype[i] != int(mujoco.mjtDyn.mjDYN_NONE)):
            problems.append(f"actuator {name!r}: {m.actuator_actnum[i]} activation variables (actdim)")
        if m.actuator_gaintype[i] > int(mujoco.mjtGain.mjGAIN_AFFINE):
            problems.append(f"actuator {name!r}: gain {mujoco.mjtGain(m.actuator_gaintype[i]).name}")
        if m.actuator_biastype[i] > int(mujoco.mjtBias.mjBIAS_AFFINE):
            problems.append(f"actuator {name!r}: bias {mujoco.mjtBias(m.actuator_biastype[i]).name}")
    return problems


def check_supported(m: mujoco.MjModel) -> None:
    """Raises ``UnsupportedFeatureError`` for anything that would make a silently wrong model."""
    obj = mujoco.mjtObj
    flags = m.opt.disableflags
    problems = []
    problems.extend(_tendon_problems(m))
    problems.extend(_equality_problems(m))
    for count, what in [
        (m.nflex, "flexes"),
        (m.nplugin, "plugins"),
    ]:
        if count:
            problems.append(f"{what} ({count} in the model)")
    if contacts_enabled(m) and (_nonzero(m, "geom_adhesion") or _nonzero(m, "pair_adhesion")):
        problems.append("contact adhesion (geom or pair adhesion)")
    condims = np.concatenate([m.geom_condim, m.pair_dim])
    if contacts_enabled(m) and not np.isin(condims, (1, 3, 4, 6)).all():
        problems.append("contact condim other than 1, 3, 4 or 6")
    ellipsoid = (m.geom_fluid[:, 0] > 0) & (m.body_mass[m.geom_bodyid] >= mujoco.mjMINVAL)
    if fluid_enabled(m) and ellipsoid.any():
        where = _first(m, ellipsoid, obj.mjOBJ_GEOM)
        problems.append(f"the ellipsoid fluid model ({where} has fluidshape='ellipsoid')")
    for field in ("dof_dampingpoly", "jnt_stiffnesspoly", "jnt_springyield"):
        if _nonzero(m, field):
            problems.append(f"nonlinear joint passive forces ({field})")
    stiff_3d = (m.jnt_stiffness != 0) & (m.jnt_type <= JointType.BALL)
    if stiff_3d.any():
        problems.append(f"stiffness on a free/ball joint ({_first(m, stiff_3d, obj.mjOBJ_JOINT)})")
    problems.extend(_actuator_problems(m))
    limited = m.jnt_limited.astype(bool) & (m.jnt_type <= JointType.BALL)
    if limited.any() and not flags & (_DSBL.mjDSBL_LIMIT | _DSBL.mjDSBL_CONSTRAINT):
        problems.append(f"limits on a free/ball joint ({_first(m, limited, obj.mjOBJ_JOINT)})")
    narrow = m.jnt_limited.astype(bool) & (m.jnt_range[:, 1] - m.jnt_range[:, 0] < 2 * m.jnt_margin)
    if narrow.any() and not flags & (_DSBL.mjDSBL_LIMIT | _DSBL.mjDSBL_CONSTRAINT):
        where = _first(m, narrow, obj.mjOBJ_JOINT)
        problems.append(f"a joint range narrower than twice its margin ({where}: both limits active)")
    if contacts_enabled(m):
        for g1, g2 in candidate_geom_pairs(m):
            key = (int(m.geom_type[g1]), int(m.geom_type[g2]))
            if key not in SUPPORTED:
                n1 = mujoco.mj_id2name(m, obj.mjOBJ_GEOM, g1) or g1
                n2 = mujoco.mj_id2name(m, obj.mjOBJ_GEOM, g2) or g2
                t1, t2 = (mujoco.mjtGeom(t).name[7:].lower() for t in key)
                problems.append(f"collision {t1}-{t2} (geoms {n1!r}, {n2!r}) is not implemented")
                break
    if problems:
        raise UnsupportedFeatureError("fastrl cannot simulate this model yet: " + "; ".join(problems))


def _tendon_roles(m: mujoco.MjModel) -> dict[str, np.ndarray]:
    """(ntendon,) bool for each way a tendon can act on the dynamics (disabled ones left out)."""
    flags = m.opt.disableflags
    spring, damper = not flags & _DSBL.mjDSBL_SPRING, not flags & _DSBL.mjDSBL_DAMPER
    actuated = np.zeros(m.ntendon, bool)
    by_tendon = m.actuator_trntype == int(mujoco.mjtTrn.mjTRN_TENDON)
    actuated[m.actuator_trnid[by_tendon, 0]] = True
    coupled = np.zeros(m.ntendon, bool)
    if equalities_enabled(m):
        by_eq = m.eq_type == int(mujoco.mjtEq.mjEQ_TENDON)
        for ids in (m.eq_obj1id[by_eq], m.eq_obj2id[by_eq]):
            coupled[ids[ids >= 0]] = True
    nonlinear_spring = (m.tendon_springyield != 0) | np.any(m.tendon_stiffnesspoly != 0, axis=-1)
    return {
        "limited": m.tendon_limited.astype(bool) & limits_enabled(m),
        "stiffness": (m.tendon_stiffness != 0) & spring,
        "nonlinear stiffness (stiffnesspoly, springyield)": nonlinear_spring & spring,
        "damping": (m.tendon_damping != 0) & damper,
        "nonlinear damping (dampingpoly)": np.any(m.tendon_dampingpoly != 0, axis=-1) & damper,
        "frictionloss": (m.tendon_frictionloss != 0) & (not flags & _DSBL.mjDSBL_FRICTIONLOSS),
        "armature": m.tendon_armature != 0,
        "an actuator": actuated,
        "actuatorfrcrange": m.tendon_actfrclimited.astype(bool) & actuated,
        "an equality constraint": coupled,
        "a range narrower than twice its margin (both limits active)": m.tendon_limited.astype(bool)
        & limits_enabled(m)
        & (m.tendon_range[:, 1] - m.tendon_range[:, 0] < 2 * m.tendon_margin),
    }


# What fastrl does not simulate yet about a tendon (the rest of _tendon_roles it does).
_TENDON_REFUSED = (
    "nonlinear stiffness (stiffnesspoly, springyield)", "nonlinear damping (dampingpoly)",
    "actuatorfrcrange", "a range narrower than twice its margin (both limits active)",
)  # fmt: skip


def tendons_act(m: mujoco.MjModel) -> bool:
    """Whether any tendon acts on the dynamics. If none does, ``Model`` keeps no tendons: they
    would only measure lengths (Gymnasium's humanoid has two such fixed tendons), and the
    compiled step stays that of a model without them."""
    return bool(any(mask.any() for mask in _tendon_roles(m).values()))


def _tendon_problems(m: mujoco.MjModel) -> list[str]:
    """Tendons that act on the dynamics in a way fastrl does not simulate, each named with it.

    Springs (with a dead band), dampers, armature and actuators are simulated (``tendon.py``).
    Armature on a spatial tendon that wraps a geom is refused, as MuJoCo's compiler refuses it
    (mj_tendonDot has no derivative of the wrap), for a model whose armature was set after
    compiling.
    """
    roles = _tendon_roles(m)
    geoms = (int(mujoco.mjtWrap.mjWRAP_SPHERE), int(mujoco.mjtWrap.mjWRAP_CYLINDER))
    wraps_geom = np.zeros(m.ntendon, bool)
    for i in range(m.ntendon):
        types = m.wrap_type[m.tendon_adr[i] : m.tendon_adr[i] + m.tendon_num[i]]
        wraps_geom[i] = np.isin(types, geoms).any()
    refused = {name: roles[name] for name in _TENDON_REFUSED}
    refused["armature on a tendon wrapping a geom"] = roles["armature"] & wraps_geom
    out = []
    for i in range(m.ntendon):
        what = [name for name, mask in refused.items() if mask[i]]
        if what:
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_TENDON, i) or str(i)
            out.append(f"tendon {name!r} ({', '.join(what)})")
    return out


_EQ_KINDS = tuple(int(getattr(mujoco.mjtEq, f"mjEQ_{k}")) for k in ("CONNECT", "WELD", "JOINT", "TENDON"))


def equalities_enabled(m: mujoco.MjModel) -> bool:
    return not m.opt.disableflags & (_DSBL.mjDSBL_EQUALITY | _DSBL.mjDSBL_CONSTRAINT)


def _equality_problems(m: mujoco.MjModel) -> list[str]:
    """Equality constraints of a kind fastrl does not simulate (tendon, flex), each named."""
    if not equalities_enabled(m):
        return []
    out = []
    for i in range(m.neq):
        if int(m.eq_type[i]) not in _EQ_KINDS:
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_EQUALITY, i) or str(i)
            out.append(f"equality {name!r} ({mujoco.mjtEq(m.eq_type[i]).name} constraint)")
    return out


def fluid_enabled(m: mujoco.MjModel) -> bool:
    """Whether MuJoCo applies fluid forces: a medium, and not both springs and dampers disabled."""
    off = _DSBL.mjDSBL_SPRING | _DSBL.mjDSBL_DAMPER
    medium = m.opt.density > 0 or m.opt.viscosity > 0
    return bool(medium and (m.opt.disableflags & off) != off)


def constraints_enabled(m: mujoco.MjModel) -> bool:
    return not m.opt.disableflags & _DSBL.mjDSBL_CONSTRAINT


def contacts_enabled(m: mujoco.MjModel) -> bool:
    return not m.opt.disableflags & (_DSBL.mjDSBL_CONTACT | _DSBL.mjDSBL_CONSTRAINT)


def limits_enabled(m: mujoco.MjModel) -> bool:
    return not m.opt.disableflags & (_DSBL.mjDSBL_LIMIT | _DSBL.mjDSBL_CONSTRAINT)


def frictionloss_enabled(m: mujoco.MjModel) -> bool:
    return not m.opt.disableflags & (_DSBL.mjDSBL_FRICTIONLOSS | _DSBL.mjDSBL_CONSTRAINT)
