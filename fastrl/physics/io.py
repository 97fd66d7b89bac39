"""Building a ``Model`` from MJCF with MuJoCo's own compiler, and a fresh ``Data``.

What the loader refuses is decided in ``io_checks``; the contact-pair table is built in ``io_contacts``.
"""

from __future__ import annotations

import os

import jax.numpy as jnp
import mujoco
import numpy as np

from fastrl.physics import smooth, tree
from fastrl.physics.collision_driver import contact_layout
from fastrl.physics.constraint import contact_slots
from fastrl.physics.constraint import sizes as constraint_sizes
from fastrl.physics.io_checks import (
    UnsupportedFeatureError,
    check_supported,
    constraints_enabled,
    contacts_enabled,
    equalities_enabled,
    fluid_enabled,
    frictionloss_enabled,
    limits_enabled,
    tendons_act,
)
from fastrl.physics.io_contacts import candidate_geom_pairs, contact_fields
from fastrl.physics.types import Data, Integrator, Model

_DSBL = mujoco.mjtDisableBit
_INTEGRATORS = {"euler": Integrator.EULER, "rk4": Integrator.RK4, "implicitfast": Integrator.IMPLICITFAST}


def _names(m: mujoco.MjModel, objtype: mujoco.mjtObj, n: int) -> tuple[str, ...]:
    return tuple(mujoco.mj_id2name(m, objtype, i) or f"<unnamed {i}>" for i in range(n))


def _compile(path_or_xml: str | os.PathLike) -> mujoco.MjModel:
    text = str(path_or_xml)
    if text.lstrip().startswith("<"):
        return mujoco.MjModel.from_xml_string(text)
    if not os.path.exists(text):
        raise FileNotFoundError(f"MJCF file not found: {text!r}")
    return mujoco.MjModel.from_xml_path(text)


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
    """Checks the arguments and the model (``check_supported``); returns the integrator and the
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
    check_supported(m)
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
    """``Model``'s activation-dynamics fields (``check_supported`` allows one act per actuator
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


def _contact_fields(m: mujoco.MjModel, nconmax: int | None, mjx_caps: bool) -> dict:
    """``Model``'s contact fields (``io_contacts.contact_fields``) for the geom pairs MuJoCo's
    broadphase could let touch (none with contacts disabled), with the scene's MJX caps where
    ``mjx_caps``."""
    pairs = candidate_geom_pairs(m) if contacts_enabled(m) else []
    caps = scene_mjx_caps(m) if mjx_caps else (-1, -1)
    return contact_fields(m, pairs, nconmax, caps)


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


def _index_fields(m: mujoco.MjModel, eqs: np.ndarray) -> dict:
    """``Model``'s static index tables (int32): the tree's topology, the geoms', sites',
    actuators' and equalities' ids and types, and the dofs, bodies and joints that features act
    on; ``eqs``: the equality constraints kept."""
    jnt_limited = m.jnt_limited if limits_enabled(m) else np.zeros(m.njnt, np.int32)
    i32 = lambda x: np.asarray(x, dtype=np.int32).copy()  # noqa: E731
    return dict(
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
        eq_type=i32(m.eq_type[eqs]), eq_obj1id=i32(m.eq_obj1id[eqs]), eq_obj2id=i32(m.eq_obj2id[eqs]),
        eq_objtype=i32(m.eq_objtype[eqs]), eq_active0=i32(m.eq_active0[eqs]),
        dof_treeid=i32(np.maximum(m.dof_treeid, 0)),
    )  # fmt: skip


def _parameter_fields(m: mujoco.MjModel, eqs: np.ndarray) -> dict:
    """``Model``'s physical parameters (float arrays, traced): options, bodies, joints, dofs,
    geoms, sites, actuators and the equality constraints ``eqs``."""
    f = lambda x: jnp.asarray(np.asarray(x, dtype=np.float64))  # noqa: E731
    gravity = m.opt.gravity * (0.0 if m.opt.disableflags & _DSBL.mjDSBL_GRAVITY else 1.0)
    return dict(
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
    eqs = np.arange(m.neq) if equalities_enabled(m) else np.zeros(0, np.int64)
    model = Model(
        nq=m.nq, nv=m.nv, nu=m.nu, nbody=m.nbody, njnt=m.njnt, ngeom=m.ngeom, nsite=m.nsite,
        **_tendon_fields(m), **_contact_fields(m, nconmax, mjx_caps),
        **_index_fields(m, eqs), **_parameter_fields(m, eqs),
        cone=int(m.opt.cone), **_activation_fields(m),
        noslip_iterations=int(m.opt.noslip_iterations) if constraints_enabled(m) else 0,
        noslip_tolerance=float(m.opt.noslip_tolerance),
        solver_iterations=int(solver_iterations), linesearch=linesearch,
        ls_iterations=int(m.opt.ls_iterations), solver_tolerance=float(m.opt.tolerance),
        ls_tolerance=float(m.opt.ls_tolerance), meaninertia=float(m.stat.meaninertia),
        ntree=max(1, int(m.ntree)),
        integrator=int(integ), disableflags=int(m.opt.disableflags),
        body_names=_names(m, obj.mjOBJ_BODY, m.nbody), jnt_names=_names(m, obj.mjOBJ_JOINT, m.njnt),
        geom_names=_names(m, obj.mjOBJ_GEOM, m.ngeom), site_names=_names(m, obj.mjOBJ_SITE, m.nsite),
        actuator_names=_names(m, obj.mjOBJ_ACTUATOR, m.nu),
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
