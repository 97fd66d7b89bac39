"""Building a ``Model`` from MJCF with MuJoCo's own compiler, and a fresh ``Data``."""

from __future__ import annotations

import os

import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.physics import smooth, tree
from fastrl.physics.collision_driver import FACES, GJK_PAIRS, SUPPORTED, contact_layout
from fastrl.physics.constraint import contact_slots, default_nconmax
from fastrl.physics.constraint import sizes as constraint_sizes
from fastrl.physics.types import Data, GeomType, Integrator, JointType, Model

_DSBL = mujoco.mjtDisableBit
_INTEGRATORS = {"euler": Integrator.EULER, "rk4": Integrator.RK4, "implicitfast": Integrator.IMPLICITFAST}
# The activation dynamics fastrl simulates (actuation.py); muscles, DC motors and PID servos not.
_DYNTYPES = tuple(
    int(k)
    for k in (
        mujoco.mjtDyn.mjDYN_NONE,
        mujoco.mjtDyn.mjDYN_INTEGRATOR,
        mujoco.mjtDyn.mjDYN_FILTER,
        mujoco.mjtDyn.mjDYN_FILTEREXACT,
    )
)


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
    for field in ("actuator_damping", "actuator_armature", "actuator_delay", "actuator_dampingpoly"):
        if _nonzero(m, field):
            problems.append(f"actuator {field[9:]}")
    for i in range(m.nu):
        name = mujoco.mj_id2name(m, obj.mjOBJ_ACTUATOR, i) or str(i)
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


_EQ_KINDS = tuple(
    int(k)
    for k in (
        mujoco.mjtEq.mjEQ_CONNECT,
        mujoco.mjtEq.mjEQ_WELD,
        mujoco.mjtEq.mjEQ_JOINT,
        mujoco.mjtEq.mjEQ_TENDON,
    )
)


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


def _geom_pairs_off_world(m: mujoco.MjModel, chunk: int = 1 << 22) -> tuple[np.ndarray, np.ndarray]:
    """Every geom pair ``g1 < g2`` with at least one geom off the world body's weld, unordered.

    Two world-welded geoms never collide, so a scene of many static geoms costs O(moving x
    ngeom), not O(ngeom^2); the pairs are built in blocks of about ``chunk`` to bound the memory.
    """
    weld = m.body_weldid[m.geom_bodyid]
    moving = np.flatnonzero(weld != 0)
    static = np.flatnonzero(weld == 0)
    rows = max(1, chunk // max(1, m.ngeom))
    g1s, g2s = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for start in range(0, moving.size, rows):
        part = moving[start : start + rows]
        later = moving[start:]  # a moving partner pairs with the lower of the two only
        a = np.concatenate([np.repeat(part, static.size), np.repeat(part, later.size)])
        b = np.concatenate([np.tile(static, part.size), np.tile(later, part.size)])
        keep = (weld[b] == 0) | (b > a)
        g1s.append(np.minimum(a, b)[keep])
        g2s.append(np.maximum(a, b)[keep])
    return np.concatenate(g1s), np.concatenate(g2s)


def candidate_geom_pairs(m: mujoco.MjModel) -> list[tuple[int, int]]:
    """Geom pairs that MuJoCo's broadphase filter could let touch (contype/conaffinity, exclusions).

    Excludes pairs in one welded body, pairs of two world-welded geoms, parent-child pairs (unless
    filterparent is disabled) and ``<exclude>``d body pairs; adds explicit ``<pair>`` elements,
    which bypass those filters and replace the filtered pair of the same two geoms (MuJoCo keeps
    the other geom pairs of the same two bodies). The filtered pairs come in ascending
    ``(g1, g2)`` order, then the explicit ones. The filters are numpy masks over the pairs with a
    moving geom, so a scene of many static geoms loads in time linear in their number.
    """
    explicit = _explicit_pairs(m)
    g1, g2 = _geom_pairs_off_world(m)
    ctype, caff = m.geom_contype, m.geom_conaffinity
    ok = ((ctype[g1] & caff[g2]) != 0) | ((ctype[g2] & caff[g1]) != 0)
    b1, b2 = m.geom_bodyid[g1], m.geom_bodyid[g2]
    weld, parent = m.body_weldid, m.body_parentid
    w1, w2 = weld[b1], weld[b2]
    ok &= w1 != w2
    if not m.opt.disableflags & _DSBL.mjDSBL_FILTERPARENT:
        ok &= ~((w1 != 0) & (w2 != 0) & ((weld[parent[w1]] == w2) | (weld[parent[w2]] == w1)))
    # An <exclude> signature is (lower body id << 16) | higher body id.
    low, high = np.minimum(b1, b2).astype(np.int64), np.maximum(b1, b2).astype(np.int64)
    signature = np.asarray(m.exclude_signature, np.int64)
    ok &= ~((high < 1 << 16) & np.isin(low << 16 | high, signature))
    key = g1 * m.ngeom + g2
    ok &= ~np.isin(key, np.array([min(p) * m.ngeom + max(p) for p in explicit], np.int64))
    order = np.argsort(key[ok], kind="stable")
    pairs = list(zip(g1[ok][order].tolist(), g2[ok][order].tolist(), strict=True))
    pairs.extend(tuple(sorted(p)) for p in explicit)
    # MuJoCo's collision table is indexed with the lower geom type first.
    return [(a, b) if m.geom_type[a] <= m.geom_type[b] else (b, a) for a, b in pairs]


def _explicit_pairs(m: mujoco.MjModel) -> dict[frozenset, int]:
    """``{frozenset((geom1, geom2)): pair id}`` of the model's explicit ``<contact><pair>``s."""
    return {
        frozenset((int(a), int(b))): i
        for i, (a, b) in enumerate(zip(m.pair_geom1, m.pair_geom2, strict=True))
    }


def _mix_pair_params(m: mujoco.MjModel, pairs: list[tuple[int, int]]) -> dict[str, np.ndarray]:
    """Contact parameters of each pair, mixed from its two geoms as MuJoCo mixes them.

    An explicit ``<pair>`` takes its own condim, friction, solref, solreffriction (the elliptic
    cone's friction rows; other pairs have none and use solref), solimp, margin and gap. Other
    pairs: condim and friction take the maximum (friction per component, expanded to MuJoCo's
    5-vector: tangential, tangential, torsional, rolling, rolling, each at least 1e-5); margins
    and gaps add up (MuJoCo >= 4.0); solref and solimp are a weighted mean with weights from
    ``solmix``; a geom with higher ``priority`` supplies condim, friction, solref and solimp.
    """
    n = len(pairs)
    out = {
        "condim": np.zeros(n, np.int32), "friction": np.zeros((n, 5)), "solref": np.zeros((n, 2)),
        "solimp": np.zeros((n, 5)), "margin": np.zeros(n), "gap": np.zeros(n),
        "solreffriction": np.zeros((n, 2)),
    }  # fmt: skip
    explicit = _explicit_pairs(m)
    for k, (g1, g2) in enumerate(pairs):
        pid = explicit.get(frozenset((int(g1), int(g2))))
        if pid is not None:  # an explicit <pair> states its own parameters
            out["condim"][k] = m.pair_dim[pid]
            out["friction"][k] = np.maximum(m.pair_friction[pid], mujoco.mjMINMU)
            out["solref"][k], out["solimp"][k] = m.pair_solref[pid], m.pair_solimp[pid]
            out["margin"][k], out["gap"][k] = m.pair_margin[pid], m.pair_gap[pid]
            out["solreffriction"][k] = m.pair_solreffriction[pid]
            continue
        p1, p2 = m.geom_priority[g1], m.geom_priority[g2]
        if p1 != p2:
            win = g1 if p1 > p2 else g2
            condim, fric = m.geom_condim[win], m.geom_friction[win]
            solref, solimp = m.geom_solref[win], m.geom_solimp[win]
        else:
            condim = max(m.geom_condim[g1], m.geom_condim[g2])
            fric = np.maximum(m.geom_friction[g1], m.geom_friction[g2])
            s1, s2 = m.geom_solmix[g1], m.geom_solmix[g2]
            small1, small2 = s1 < mujoco.mjMINVAL, s2 < mujoco.mjMINVAL
            mix = 0.5 if small1 and small2 else 0.0 if small1 else 1.0 if small2 else s1 / (s1 + s2)
            if m.geom_solref[g1][0] > 0 and m.geom_solref[g2][0] > 0:
                solref = mix * m.geom_solref[g1] + (1 - mix) * m.geom_solref[g2]
            else:  # direct (negative) solref: the stiffer of the two
                solref = np.minimum(m.geom_solref[g1], m.geom_solref[g2])
            solimp = mix * m.geom_solimp[g1] + (1 - mix) * m.geom_solimp[g2]
        out["condim"][k] = condim
        out["friction"][k] = np.maximum([fric[0], fric[0], fric[1], fric[2], fric[2]], mujoco.mjMINMU)
        out["solref"][k], out["solimp"][k] = solref, solimp
        out["margin"][k] = m.geom_margin[g1] + m.geom_margin[g2]
        out["gap"][k] = m.geom_gap[g1] + m.geom_gap[g2]
    return out


def _fluid_bodies(m: mujoco.MjModel) -> np.ndarray:
    """(nbody,) bool: bodies MuJoCo's inertia-box fluid model acts on (massless ones are skipped)."""
    if not fluid_enabled(m):
        return np.zeros(m.nbody, bool)
    return (np.arange(m.nbody) > 0) & (m.body_mass >= mujoco.mjMINVAL)


# Newton steps per solve, for a model that does not name its own count. With 8, the Ant under
# random controls stays within 1 cm of MuJoCo's torso over 1 s in all of 32 sequences (both
# integrators); with 4 the RK4 median is 1.1 cm with decimetre outliers, with 2 it is 45 cm. More
# than 8 changes nothing measurable.
DEFAULT_SOLVER_ITERATIONS = 8
# An MJCF names its own count with <custom><numeric name="fastrl_solver_iterations" data="N"/>
# (MuJoCo keeps custom numerics as user data and ignores them). fastrl's assets set it from how
# many Newton iterations MuJoCo's own solver needs on that model (see fastrl/assets/README.md).
SOLVER_ITERATIONS_NUMERIC = "fastrl_solver_iterations"


def _numeric(m: mujoco.MjModel, name: str) -> int:
    """A whole-number ``<custom><numeric>`` of the model, or -1 where it has none."""
    i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_NUMERIC, name)
    if i < 0:
        return -1
    value = float(m.numeric_data[m.numeric_adr[i]])
    if value != int(value) or value < 1:
        raise ValueError(f"custom numeric {name}={value}; use a whole number >= 1")
    return int(value)


def asset_solver_iterations(m: mujoco.MjModel, linesearch: str | None = None) -> int:
    """The model's own solver iteration count: its custom numeric if it names one. Else, for
    MuJoCo's solver (``linesearch="mujoco"``, the default for such a model), MuJoCo's own cap
    ``<option iterations>``: that solver stops early at the scene's ``tolerance``, as MuJoCo's
    does. For the exact-line-search solver, which runs its count, ``iterations`` where that is
    below ``DEFAULT_SOLVER_ITERATIONS``, else the default.

    A scene tuned for a fixed budget (MuJoCo Playground's MJX scenes set 1 or 3) is stepped with
    that budget, as MJX steps it: at 8 iterations the feet-only H1 parted from MuJoCo C by 5e-3
    in qpos within 10 steps, at its own 1 by 2e-15. A scene that keeps MuJoCo's 100 needs them
    now and then: capped at 8, the Leap hands blew up under random controls where MuJoCo C took
    9 iterations.
    """
    named = _numeric(m, SOLVER_ITERATIONS_NUMERIC)
    if named > 0:
        return named
    if (linesearch or asset_linesearch(m)) == "mujoco":
        return max(1, int(m.opt.iterations))
    return max(1, min(int(m.opt.iterations), DEFAULT_SOLVER_ITERATIONS))


LINESEARCHES = ("exact", "mujoco")

# MJX's broad-phase caps, which MuJoCo Playground's hand and full-collision scenes set in
# <custom>: at most MAX_GEOM_PAIRS pairs of each pair group are collided (those whose bounding
# spheres overlap most) and at most MAX_CONTACT_POINTS contacts of each condim get rows (the
# deepest). MuJoCo C ignores them.
MAX_GEOM_PAIRS, MAX_CONTACT_POINTS = "max_geom_pairs", "max_contact_points"


def scene_mjx_caps(m: mujoco.MjModel) -> tuple[int, int]:
    """The scene's ``(max_geom_pairs, max_contact_points)``, -1 for each it does not set."""
    return _numeric(m, MAX_GEOM_PAIRS), _numeric(m, MAX_CONTACT_POINTS)


def asset_linesearch(m: mujoco.MjModel) -> str:
    """``"exact"`` for a model that names its own ``fastrl_solver_iterations`` (fastrl's tuned
    assets: a fixed budget of Newton steps with exact line searches), else ``"mujoco"`` (MuJoCo's
    algorithm with the scene's own tolerances, so a truncated solve stops where MuJoCo's does)."""
    named = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_NUMERIC, SOLVER_ITERATIONS_NUMERIC) >= 0
    return "exact" if named else "mujoco"


def _checked(m: mujoco.MjModel, integrator, solver_iterations, nconmax, linesearch) -> tuple[Integrator, int]:
    """Checks the arguments and the model (``_check_supported``); returns the integrator and the
    solver's iteration count to use."""
    if solver_iterations is None:
        solver_iterations = asset_solver_iterations(m, linesearch)
    if solver_iterations < 1:
        raise ValueError(f"solver_iterations={solver_iterations}; it must be at least 1")
    if nconmax is not None and nconmax < 1:
        raise ValueError(f"nconmax={nconmax}; it must be at least 1")
    if m.nv == 0:  # a world of static geoms only: nothing can move, so there is nothing to step
        raise ValueError(
            "the model has no degrees of freedom (no joints or free bodies): there is nothing to "
            "simulate; give at least one body a <joint> or <freejoint>"
        )
    _check_supported(m)
    if integrator is not None:
        if integrator not in _INTEGRATORS:
            raise ValueError(f"integrator={integrator!r}; choose one of {sorted(_INTEGRATORS)}")
        return _INTEGRATORS[integrator], solver_iterations
    if m.opt.integrator in set(Integrator):
        return Integrator(m.opt.integrator), solver_iterations
    name = mujoco.mjtIntegrator(m.opt.integrator).name
    raise UnsupportedFeatureError(
        f"integrator {name} is not implemented; pass integrator='euler', 'rk4' or 'implicitfast' to load_mjcf"
    )


def _activation_fields(m: mujoco.MjModel) -> dict:
    """``Model``'s activation-dynamics fields (``_check_supported`` allows one act per actuator
    with dynamics and none without)."""
    i32 = lambda x: np.asarray(x, dtype=np.int32).copy()  # noqa: E731
    f = lambda x: jnp.asarray(np.asarray(x, dtype=np.float64))  # noqa: E731
    return dict(
        na=int(m.na), actuator_dyntype=i32(m.actuator_dyntype), actuator_actadr=i32(m.actuator_actadr),
        actuator_actlimited=i32(m.actuator_actlimited), actuator_actearly=i32(m.actuator_actearly),
        actuator_dynprm=f(m.actuator_dynprm), actuator_actrange=f(m.actuator_actrange),
    )  # fmt: skip


def _tendon_fields(m: mujoco.MjModel) -> dict:
    """``Model``'s tendon fields: every tendon with MuJoCo's ids if any acts, else none."""
    tens = np.arange(m.ntendon) if tendons_act(m) else np.zeros(0, np.int64)
    wraps = np.arange(m.nwrap) if tens.size else np.zeros(0, np.int64)
    limited = m.tendon_limited[tens] if limits_enabled(m) else np.zeros(tens.size, np.int32)
    friction = np.flatnonzero(m.tendon_frictionloss[tens] > 0) if frictionloss_enabled(m) else []
    i32 = lambda x: np.asarray(x, dtype=np.int32).copy()  # noqa: E731
    f = lambda x: jnp.asarray(np.asarray(x, dtype=np.float64))  # noqa: E731
    return dict(
        ntendon=int(tens.size), tendon_adr=i32(m.tendon_adr[tens]), tendon_num=i32(m.tendon_num[tens]),
        wrap_type=i32(m.wrap_type[wraps]), wrap_objid=i32(m.wrap_objid[wraps]),
        wrap_prm=np.asarray(m.wrap_prm[wraps], np.float64).copy(), tendon_limited=i32(limited),
        armature_tendons=i32(np.flatnonzero(m.tendon_armature[tens] != 0)), friction_tendons=i32(friction),
        tendon_stiffness=f(m.tendon_stiffness[tens]), tendon_damping=f(m.tendon_damping[tens]),
        tendon_armature=f(m.tendon_armature[tens]), tendon_lengthspring=f(m.tendon_lengthspring[tens]),
        tendon_range=f(m.tendon_range[tens]), tendon_margin=f(m.tendon_margin[tens]),
        tendon_solref_lim=f(m.tendon_solref_lim[tens]), tendon_solimp_lim=f(m.tendon_solimp_lim[tens]),
        tendon_frictionloss=f(m.tendon_frictionloss[tens]),
        tendon_solref_fri=f(m.tendon_solref_fri[tens]), tendon_solimp_fri=f(m.tendon_solimp_fri[tens]),
        tendon_invweight0=f(m.tendon_invweight0[tens]), tendon_length0=f(m.tendon_length0[tens]),
    )  # fmt: skip


def _hull_vertices(m: mujoco.MjModel, mesh: int) -> np.ndarray:
    """Mesh-local ids, ascending, of the vertices of the convex hull MuJoCo's compiler built (its
    ``mesh_graph``: vertex count, face count, each vertex's edge address, then its mesh id), so
    that ``maxhullvert`` holds and no interior vertex is searched; every vertex without a hull."""
    adr = m.mesh_graphadr[mesh]
    if adr < 0:
        return np.arange(m.mesh_vertnum[mesh])
    num = int(m.mesh_graph[adr])
    return np.sort(m.mesh_graph[adr + 2 + num : adr + 2 + 2 * num]).astype(np.int64)


def _geometry_fields(m: mujoco.MjModel, pairs: list[tuple[int, int]]) -> dict:
    """``Model``'s mesh and height-field fields, for the geoms of the colliding pairs only.

    Meshes: the convex hull's vertices and polygons MuJoCo's compiler built (``mesh_poly*``):
    each vertex's polygons, each polygon's vertices (-1 padded) and normal. Height fields: elevation
    data (0..1, scaled by ``hfield_size[2]``) and the cell window examined around each geom.
    """
    geoms = sorted({g for pair in pairs for g in pair})
    mesh_geoms = [g for g in geoms if m.geom_type[g] == GeomType.MESH]
    meshes = sorted({int(m.geom_dataid[g]) for g in mesh_geoms})
    geom_meshid = np.full(m.ngeom, -1, np.int32)
    verts, maps, polys, normals, vadr, vnum, padr = [], [], [], [], [], [], []
    for k, mid in enumerate(meshes):
        v0, p0, npoly = m.mesh_vertadr[mid], m.mesh_polyadr[mid], m.mesh_polynum[mid]
        hull = _hull_vertices(m, mid)
        local = np.full(m.mesh_vertnum[mid], -1, np.int64)
        local[hull] = np.arange(hull.size)
        vadr.append(sum(vnum))
        vnum.append(hull.size)
        padr.append(len(polys))
        verts.append(m.mesh_vert[v0 + hull])
        for v in hull:  # the polygons each vertex lies on (mesh-local polygon ids)
            a, n = m.mesh_polymapadr[v0 + v], m.mesh_polymapnum[v0 + v]
            maps.append(m.mesh_polymap[a : a + n])
        for q in range(p0, p0 + npoly):  # each polygon's vertices (hull-local vertex ids)
            a, n = m.mesh_polyvertadr[q], m.mesh_polyvertnum[q]
            polys.append(local[m.mesh_polyvert[a : a + n]])
        normals.append(m.mesh_polynormal[p0 : p0 + npoly].reshape(-1, 3))
        geom_meshid[[g for g in mesh_geoms if m.geom_dataid[g] == mid]] = k

    def padded(rows: list) -> np.ndarray:
        out = np.full((len(rows), max((len(r) for r in rows), default=0)), -1, np.int32)
        for i, r in enumerate(rows):
            out[i, : len(r)] = r
        return out

    hfields = sorted({int(m.geom_dataid[g]) for g in geoms if m.geom_type[g] == GeomType.HFIELD})
    geom_hfieldid = np.full(m.ngeom, -1, np.int32)
    for k, hid in enumerate(hfields):
        geom_hfieldid[(m.geom_type == GeomType.HFIELD) & (m.geom_dataid == hid)] = k
    window = np.zeros((len(pairs), 2), np.int32)
    for k, (g1, g2) in enumerate(pairs):
        if m.geom_type[g1] == GeomType.HFIELD:
            hid = m.geom_dataid[g1]
            reach = 2 * (m.geom_rbound[g2] + m.geom_margin[g1] + m.geom_margin[g2])
            step = np.array(
                [
                    2 * m.hfield_size[hid, 1] / (m.hfield_nrow[hid] - 1),  # rows: y
                    2 * m.hfield_size[hid, 0] / (m.hfield_ncol[hid] - 1),
                ]
            )  # cols: x
            cells = np.floor(reach / step * (1 + 1e-9)).astype(np.int32) + 2
            window[k] = np.minimum(cells, [m.hfield_nrow[hid] - 1, m.hfield_ncol[hid] - 1])
    f = lambda x: jnp.asarray(np.asarray(x, dtype=np.float64))  # noqa: E731
    hf_data = [
        m.hfield_data[m.hfield_adr[h] : m.hfield_adr[h] + m.hfield_nrow[h] * m.hfield_ncol[h]]
        for h in hfields
    ]
    hf_num = [m.hfield_nrow[h] * m.hfield_ncol[h] for h in hfields]
    return dict(
        geom_meshid=geom_meshid, mesh_vertadr=np.asarray(vadr, np.int32),
        mesh_vertnum=np.asarray(vnum, np.int32), mesh_polyadr=np.asarray(padr, np.int32),
        mesh_polymap=padded(maps), mesh_polyvert=padded(polys),
        mesh_polynormal=f(np.concatenate(normals) if normals else np.zeros((0, 3))),
        geom_hfieldid=geom_hfieldid,
        hfield_nrow=np.asarray([m.hfield_nrow[h] for h in hfields], np.int32),
        hfield_ncol=np.asarray([m.hfield_ncol[h] for h in hfields], np.int32),
        hfield_adr=np.asarray(np.cumsum([0] + hf_num)[:-1], np.int32), pair_window=window,
        mesh_vert=f(np.concatenate(verts) if verts else np.zeros((0, 3))),
        hfield_size=f(np.asarray([m.hfield_size[h] for h in hfields]).reshape(-1, 4)),
        hfield_data=f(np.concatenate(hf_data) if hf_data else np.zeros(0)),
        geom_rbound=f(m.geom_rbound),
    )  # fmt: skip


def _faceclip(m: mujoco.MjModel, g1: np.ndarray, g2: np.ndarray, margin: np.ndarray) -> dict:
    """``multiccd`` (False: ``<flag multiccd="disable"/>``, one contact per convex pair) and
    ``pair_faceclip``: the pairs MuJoCo gives its face-clipping multi-contact, a mesh against a
    mesh or a box with no margin (with a margin it searches by perturbation)."""
    flat = lambda g: np.isin(m.geom_type[g], [GeomType.BOX, GeomType.MESH])  # noqa: E731
    mesh = (m.geom_type[g1] == GeomType.MESH) | (m.geom_type[g2] == GeomType.MESH)
    multi = not m.opt.disableflags & _DSBL.mjDSBL_MULTICCD
    return {
        "multiccd": multi,
        "pair_faceclip": flat(g1) & flat(g2) & mesh & (np.asarray(margin) == 0) & multi,
    }


def _default_slots(m: mujoco.MjModel, pairs: list[tuple[int, int]], geometry: dict) -> int:
    """Contact slots when the scene does not set ``nconmax``: ``default_nconmax`` of the candidates
    (as ``collision_driver.contact_layout`` lays them out from ``geometry``'s pair window and
    face-clipping flags), plus one slot per height-field
    candidate. On rough terrain a foot often touches several prisms at once (MuJoCo C reports 9
    contacts for the Barkour's four feet on its terrain at rest), so those candidates all keep a
    slot rather than share a quarter of one."""
    window, faceclip = geometry["pair_window"], geometry["pair_faceclip"]
    groups: dict[tuple, list[int]] = {}
    for k, (a, b) in enumerate(pairs):
        key = (int(m.geom_type[a]), int(m.geom_type[b])) + ((FACES,) if faceclip[k] else ())
        groups.setdefault(key, []).append(k)
    other = terrain = 0
    single = m.opt.disableflags & _DSBL.mjDSBL_MULTICCD
    for key, ks in groups.items():
        count = 1 if single and key in GJK_PAIRS else SUPPORTED[key][1]
        if count is None:  # a height field: two prisms per cell of the group's window
            terrain += len(ks) * 2 * int(np.prod(window[ks].max(axis=0)))
        else:
            other += len(ks) * count
    return default_nconmax(other) + terrain


def _contact_fields(m: mujoco.MjModel, nconmax: int | None, mjx_caps: bool) -> dict:
    """``Model``'s pair table (each pair's geoms, mixed parameters and shape data), its contact
    slots and MJX's pair cap."""
    pairs = candidate_geom_pairs(m) if contacts_enabled(m) else []
    mixed = _mix_pair_params(m, pairs)
    g1 = np.array([p[0] for p in pairs], np.int32)
    g2 = np.array([p[1] for p in pairs], np.int32)
    geometry = _geometry_fields(m, pairs) | _faceclip(m, g1, g2, mixed["margin"])
    max_pairs, max_points = scene_mjx_caps(m) if mjx_caps else (-1, -1)
    if nconmax is None:  # <size nconmax>, else MJX's max_contact_points, else the rule
        named = [n for n in (m.nconmax, max_points) if n > 0]
        nconmax = named[0] if named else _default_slots(m, pairs, geometry)
    f = lambda x: jnp.asarray(np.asarray(x, dtype=np.float64))  # noqa: E731
    return dict(
        **geometry, pair_geom1=g1, pair_geom2=g2, pair_condim=mixed["condim"],
        nconmax=int(nconmax), max_geom_pairs=int(max_pairs),
        pair_friction=f(mixed["friction"]), pair_solref=f(mixed["solref"]),
        pair_solimp=f(mixed["solimp"]), pair_solreffriction=f(mixed["solreffriction"]),
        pair_margin=f(mixed["margin"]), pair_gap=f(mixed["gap"]),
    )  # fmt: skip


def _check_float32_mass(m: mujoco.MjModel, model: Model) -> None:
    """Refuses a float32 model with a tree ``smooth.ARTICULATED_MIN_DEPTH`` or more dofs deep
    whose mass matrix at ``qpos0`` float32 cannot factorise, where fastrl must factorise M's
    float32 entries: the constraint solver's ``M + J^T D J``, implicitfast's ``M - h D``, or M
    with tendon armature. (``smooth.solve_mass`` factorises a deep tree's M alone from its
    articulated inertias, which float32 holds.) Such a model's first step would be NaN."""
    depth = len(tree.dof_levels(model))
    if np.dtype(model.body_mass.dtype).itemsize >= 8 or depth < smooth.ARTICULATED_MIN_DEPTH:
        return
    needs = {
        "its constraint solver": constraint_sizes(model)[1] > 0,
        "the implicitfast integrator": model.integrator == Integrator.IMPLICITFAST,
        "a solve with its tendon armature": model.armature_tendons.size > 0,
    }
    if not any(needs.values()):
        return
    d = mujoco.MjData(m)
    for stage in (mujoco.mj_kinematics, mujoco.mj_comPos, mujoco.mj_crb):
        stage(m, d)
    qm = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, qm)
    try:
        np.linalg.cholesky(qm.astype(np.float32))
    except np.linalg.LinAlgError:
        deepest = int(m.dof_jntid[tree.dof_levels(model)[-1][0]])
        joint = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, deepest) or str(deepest)
        raise UnsupportedFeatureError(
            "fastrl cannot simulate this model in float32: "
            + " and ".join(name for name, used in needs.items() if used)
            + f" must factorise the mass matrix from its float32 entries, and for a kinematic chain"
            f" {depth} dofs deep (down to joint {joint!r}) float32 cannot hold it (its Cholesky"
            " factorisation at qpos0 breaks down); enable float64 (jax_enable_x64)"
        ) from None


def model_from_mujoco(
    m: mujoco.MjModel,
    integrator: str | None = None,
    solver_iterations: int | None = None,
    nconmax: int | None = None,
    linesearch: str | None = None,
    mjx_caps: bool = False,
) -> Model:
    """Converts a compiled ``mujoco.MjModel`` into fastrl's ``Model`` (see ``load_mjcf``)."""
    if linesearch is None:
        linesearch = asset_linesearch(m)
    if linesearch not in LINESEARCHES:
        raise ValueError(f"linesearch={linesearch!r}; choose one of {LINESEARCHES}")
    integ, solver_iterations = _checked(m, integrator, solver_iterations, nconmax, linesearch)
    obj = mujoco.mjtObj
    jnt_limited = m.jnt_limited if limits_enabled(m) else np.zeros(m.njnt, np.int32)
    eqs = np.arange(m.neq) if equalities_enabled(m) else np.zeros(0, np.int64)
    i32 = lambda x: np.asarray(x, dtype=np.int32).copy()  # noqa: E731
    f = lambda x: jnp.asarray(np.asarray(x, dtype=np.float64))  # noqa: E731
    gravity = m.opt.gravity * (0.0 if m.opt.disableflags & _DSBL.mjDSBL_GRAVITY else 1.0)
    model = Model(
        nq=m.nq, nv=m.nv, nu=m.nu, nbody=m.nbody, njnt=m.njnt, ngeom=m.ngeom, nsite=m.nsite,
        **_tendon_fields(m), **_contact_fields(m, nconmax, mjx_caps),
        body_parentid=i32(m.body_parentid), body_rootid=i32(m.body_rootid),
        body_jntnum=i32(m.body_jntnum), body_jntadr=i32(m.body_jntadr),
        body_dofnum=i32(m.body_dofnum), body_dofadr=i32(m.body_dofadr),
        jnt_type=i32(m.jnt_type), jnt_qposadr=i32(m.jnt_qposadr), jnt_dofadr=i32(m.jnt_dofadr),
        jnt_bodyid=i32(m.jnt_bodyid), jnt_limited=i32(jnt_limited),
        dof_bodyid=i32(m.dof_bodyid), dof_jntid=i32(m.dof_jntid), dof_parentid=i32(m.dof_parentid),
        friction_dofs=i32(np.flatnonzero(m.dof_frictionloss > 0) if frictionloss_enabled(m) else []),
        geom_bodyid=i32(m.geom_bodyid), geom_type=i32(m.geom_type),
        geom_contype=i32(m.geom_contype), geom_conaffinity=i32(m.geom_conaffinity),
        site_bodyid=i32(m.site_bodyid), body_fluid=i32(_fluid_bodies(m)),
        gravcomp_bodies=i32(np.flatnonzero(m.body_gravcomp != 0)), jnt_actgravcomp=i32(m.jnt_actgravcomp),
        mocap_bodies=i32(np.argsort(np.where(m.body_mocapid >= 0, m.body_mocapid, m.nbody))[: m.nmocap]),
        actuator_trntype=i32(m.actuator_trntype), actuator_trnid=i32(m.actuator_trnid[:, 0]),
        actuator_gaintype=i32(m.actuator_gaintype), actuator_biastype=i32(m.actuator_biastype),
        actuator_ctrllimited=i32(m.actuator_ctrllimited),
        actuator_forcelimited=i32(m.actuator_forcelimited),
        jnt_actfrclimited=i32(m.jnt_actfrclimited),
        cone=int(m.opt.cone), **_activation_fields(m),
        noslip_iterations=int(m.opt.noslip_iterations) if constraints_enabled(m) else 0,
        noslip_tolerance=float(m.opt.noslip_tolerance),
        eq_type=i32(m.eq_type[eqs]), eq_obj1id=i32(m.eq_obj1id[eqs]), eq_obj2id=i32(m.eq_obj2id[eqs]),
        eq_objtype=i32(m.eq_objtype[eqs]), eq_active0=i32(m.eq_active0[eqs]),
        solver_iterations=int(solver_iterations), linesearch=linesearch,
        ls_iterations=int(m.opt.ls_iterations), solver_tolerance=float(m.opt.tolerance),
        ls_tolerance=float(m.opt.ls_tolerance), meaninertia=float(m.stat.meaninertia),
        ntree=max(1, int(m.ntree)), dof_treeid=i32(np.maximum(m.dof_treeid, 0)),
        integrator=int(integ), disableflags=int(m.opt.disableflags),
        body_names=_names(m, obj.mjOBJ_BODY, m.nbody), jnt_names=_names(m, obj.mjOBJ_JOINT, m.njnt),
        geom_names=_names(m, obj.mjOBJ_GEOM, m.ngeom), site_names=_names(m, obj.mjOBJ_SITE, m.nsite),
        actuator_names=_names(m, obj.mjOBJ_ACTUATOR, m.nu),
        timestep=f(m.opt.timestep), gravity=f(gravity),
        body_pos=f(m.body_pos), body_quat=f(m.body_quat), body_ipos=f(m.body_ipos),
        body_iquat=f(m.body_iquat), body_mass=f(m.body_mass), body_inertia=f(m.body_inertia),
        body_gravcomp=f(m.body_gravcomp),
        jnt_pos=f(m.jnt_pos), jnt_axis=f(m.jnt_axis), jnt_stiffness=f(m.jnt_stiffness),
        jnt_range=f(m.jnt_range), jnt_actfrcrange=f(m.jnt_actfrcrange),
        qpos0=f(m.qpos0), qpos_spring=f(m.qpos_spring),
        dof_armature=f(m.dof_armature), dof_damping=f(m.dof_damping),
        dof_frictionloss=f(m.dof_frictionloss), dof_solref=f(m.dof_solref), dof_solimp=f(m.dof_solimp),
        geom_pos=f(m.geom_pos), geom_quat=f(m.geom_quat), geom_size=f(m.geom_size),
        geom_friction=f(m.geom_friction), site_pos=f(m.site_pos), site_quat=f(m.site_quat),
        actuator_gear=f(m.actuator_gear), actuator_ctrlrange=f(m.actuator_ctrlrange),
        actuator_forcerange=f(m.actuator_forcerange),
        actuator_gainprm=f(m.actuator_gainprm), actuator_biasprm=f(m.actuator_biasprm),
        jnt_solref=f(m.jnt_solref), jnt_solimp=f(m.jnt_solimp), jnt_margin=f(m.jnt_margin),
        eq_data=f(m.eq_data[eqs]), eq_solref=f(m.eq_solref[eqs]), eq_solimp=f(m.eq_solimp[eqs]),
        body_invweight0=f(m.body_invweight0), dof_invweight0=f(m.dof_invweight0),
        impratio=f(m.opt.impratio),
        density=f(m.opt.density), viscosity=f(m.opt.viscosity), wind=f(m.opt.wind),
    )  # fmt: skip
    _check_float32_mass(m, model)
    return model


def load_mjcf(
    path_or_xml: str | os.PathLike,
    integrator: str | None = None,
    solver_iterations: int | None = None,
    nconmax: int | None = None,
    linesearch: str | None = None,
    mjx_caps: bool = False,
) -> Model:
    """Compiles an MJCF file (or XML string) with MuJoCo's compiler into a fastrl ``Model``.

    Defaults, inertias from geoms and actuator gains are exactly as MuJoCo computes them. Features
    fastrl does not simulate raise ``UnsupportedFeatureError`` naming the element and feature.

    Args:
      path_or_xml: a path to an ``.xml`` file, or the XML text itself.
      integrator: ``"euler"``, ``"rk4"`` or ``"implicitfast"`` to override the model's
        ``<option integrator>``.
      solver_iterations: the constraint solver's most Newton steps; default the MJCF's
        ``<custom><numeric name="fastrl_solver_iterations">`` if it sets one, else its ``<option
        iterations>`` for ``linesearch="mujoco"`` (which stops early at ``tolerance``, as MuJoCo
        does) and at most ``DEFAULT_SOLVER_ITERATIONS`` for ``"exact"`` (which runs its count).
      nconmax: contact slots, the most contacts that get constraint rows at once (the deepest
        candidates); default ``<size nconmax>`` if the MJCF sets it, else
        ``constraint.default_nconmax``.
      linesearch: the constraint solver's algorithm. ``"mujoco"`` (the default unless the MJCF
        names ``fastrl_solver_iterations``): MuJoCo's Newton solver as written, with its
        islands, ``tolerance``, ``ls_iterations`` and ``ls_tolerance``, so that a truncated solve
        (a scene with few ``iterations``) stops where MuJoCo's does. ``"exact"``: each Newton step
        takes an exact line search, the faster choice for a fixed budget of iterations that
        converges (fastrl's own environments).
      mjx_caps: honour the broad-phase caps MJX reads from the scene's ``<custom>`` numerics, as
        MuJoCo Playground's hand and full-collision scenes set them: ``max_geom_pairs`` (each
        pair group collides only that many pairs, those whose bounding spheres overlap most;
        planes and height fields are never culled) and ``max_contact_points`` (the default
        ``nconmax``). Off by default: MuJoCo C ignores both, and where a cap binds the two
        engines part (Playground's Leap-hand cube, at its keyframe, by 3e-2 in qpos over 2 s).
    Returns:
      The ``Model``; float parameters are float32 unless ``jax_enable_x64`` is on.
    """
    m = _compile(path_or_xml)
    return model_from_mujoco(m, integrator, solver_iterations, nconmax, linesearch, mjx_caps)


def make_data(model: Model, qpos=None, qvel=None, ctrl=None, act=None) -> Data:
    """A ``Data`` at ``qpos0`` (or ``qpos``) with zero velocity and activations (or ``act``);
    derived fields are zero.

    Call ``physics.forward`` to fill the derived fields, as after ``mj_forward``.
    """
    dtype = model.body_mass.dtype
    z = lambda *s: jnp.zeros(s, dtype)  # noqa: E731
    nb, nj, ng, ns, nv, nu = model.nbody, model.njnt, model.ngeom, model.nsite, model.nv, model.nu
    qpos = model.qpos0 if qpos is None else jnp.asarray(qpos, dtype)
    qvel = z(nv) if qvel is None else jnp.asarray(qvel, dtype)
    ctrl = z(nu) if ctrl is None else jnp.asarray(ctrl, dtype)
    act = z(model.na) if act is None else jnp.asarray(act, dtype)
    given = (("qpos", qpos, model.nq), ("qvel", qvel, nv), ("ctrl", ctrl, nu), ("act", act, model.na))
    for name, value, n in given:
        if value.shape != (n,):
            raise ValueError(f"{name} has shape {value.shape}; this model needs ({n},)")
    eye = jnp.broadcast_to(jnp.eye(3, dtype=dtype), (nb, 3, 3))
    ncon, nefc = constraint_sizes(model)
    nslot = contact_slots(model)
    return Data(
        qpos=qpos, qvel=qvel, ctrl=ctrl, act=act, act_dot=z(model.na), time=z(), qfrc_applied=z(nv),
        qacc_warmstart=z(nv),
        mocap_pos=model.body_pos[model.mocap_bodies],
        mocap_quat=model.body_quat[model.mocap_bodies],
        eq_active=jnp.asarray(model.eq_active0.astype(bool)),
        xpos=z(nb, 3), xquat=z(nb, 4).at[:, 0].set(1.0), xmat=eye, xipos=z(nb, 3), ximat=eye,
        xanchor=z(nj, 3), xaxis=z(nj, 3), geom_xpos=z(ng, 3), geom_xmat=z(ng, 3, 3),
        site_xpos=z(ns, 3), site_xmat=z(ns, 3, 3), subtree_com=z(nb, 3), cinert=z(nb, 10),
        cdof=z(nv, 6), cvel=z(nb, 6), cdof_dot=z(nv, 6),
        ten_length=z(model.ntendon), ten_velocity=z(model.ntendon), ten_J=z(model.ntendon, nv),
        qM=z(nv, nv), qfrc_bias=z(nv),
        qfrc_spring=z(nv), qfrc_damper=z(nv), qfrc_passive=z(nv), actuator_length=z(nu),
        actuator_velocity=z(nu), actuator_force=z(nu), qfrc_actuator=z(nv), qfrc_smooth=z(nv),
        qacc=z(nv), qacc_smooth=z(nv), contact_dist=z(ncon), contact_pos=z(ncon, 3),
        contact_frame=z(ncon, 3, 3), contact_pair=jnp.asarray(contact_layout(model), jnp.int32),
        ncon=jnp.zeros((), jnp.int32),
        contact_id=jnp.zeros(nslot, jnp.int32), contact_overflow=jnp.zeros((), jnp.int32),
        efc_J=z(nefc, nv), efc_pos=z(nefc), efc_aref=z(nefc), efc_D=z(nefc), efc_force=z(nefc),
        qfrc_constraint=z(nv),
        diverged=jnp.zeros((), bool),
    )  # fmt: skip
