"""``Model`` and ``Data``: the two pytrees every physics stage reads and writes.

Names and layouts follow MuJoCo's ``mjModel``/``mjData`` so the reference can be grepped. In
``Model``, ``np.ndarray`` and ``int`` fields are static topology (they decide the traced program);
``jax.Array`` fields are physical parameters, traced, so they can be randomised per environment under
``vmap`` and differentiated.
"""

from __future__ import annotations

import enum

import jax
import numpy as np

from fastrl.physics.dataclass import pytree_dataclass


class JointType(enum.IntEnum):
    """MuJoCo's ``mjtJoint``."""

    FREE = 0
    BALL = 1
    SLIDE = 2
    HINGE = 3


class GeomType(enum.IntEnum):
    """MuJoCo's ``mjtGeom`` values."""

    PLANE = 0
    HFIELD = 1
    SPHERE = 2
    CAPSULE = 3
    ELLIPSOID = 4
    CYLINDER = 5
    BOX = 6
    MESH = 7


class Integrator(enum.IntEnum):
    """MuJoCo's ``mjtIntegrator`` values that fastrl implements."""

    EULER = 0
    RK4 = 1
    IMPLICITFAST = 3


JOINT_NQ = {JointType.FREE: 7, JointType.BALL: 4, JointType.SLIDE: 1, JointType.HINGE: 1}
JOINT_NV = {JointType.FREE: 6, JointType.BALL: 3, JointType.SLIDE: 1, JointType.HINGE: 1}


@pytree_dataclass
class Model:
    """A compiled scene. Shapes: nbody bodies (body 0 is the world), njnt joints, nv dofs, nu actuators.

    Static topology (numpy / int):
      nq, nv, nu, nbody, njnt, ngeom, nsite    sizes
      body_parentid, body_rootid               (nbody,) parent; top-level ancestor
      body_jntnum, body_jntadr                 (nbody,) joints of each body
      body_dofnum, body_dofadr                 (nbody,) dofs of each body
      jnt_type, jnt_qposadr, jnt_dofadr        (njnt,)  JointType; addresses in qpos, qvel
      jnt_bodyid, jnt_limited                  (njnt,)
      dof_bodyid, dof_jntid, dof_parentid      (nv,)    dof_parentid is -1 at a tree root
      friction_dofs                            (nfric,) dofs with a friction-loss row
                                               (frictionloss > 0 when compiled)
      geom_bodyid, geom_type                   (ngeom,)
      geom_contype, geom_conaffinity           (ngeom,)
      site_bodyid                              (nsite,)
      body_fluid                               (nbody,) 1 where the inertia-box fluid model acts
      gravcomp_bodies                          (ngravcomp,) bodies with gravity compensation
      mocap_bodies                             (nmocap,) the mocap bodies, in mocap id order (their
                                               poses are Data.mocap_pos/mocap_quat)
      jnt_actgravcomp                          (njnt,)  1: the joint's gravcomp goes through its
                                               actuators (counted against actfrcrange)
                                               (body mass > 0, density or viscosity > 0)
      actuator_trntype, actuator_trnid         (nu,)    mjtTrn (0 joint, 3 tendon); the joint or
                                               tendon each actuator drives
      actuator_gaintype, actuator_biastype     (nu,)    0 fixed/none, 1 affine
      actuator_ctrllimited, forcelimited       (nu,)
      na                                       activation variables (one per actuator with
                                               activation dynamics)
      actuator_dyntype                         (nu,)    mjtDyn: 0 none (force from ctrl), 1
                                               integrator, 2 filter, 3 filterexact
      actuator_actadr                          (nu,)    each actuator's entry in Data.act (-1: none)
      actuator_actlimited, actuator_actearly   (nu,)    act clamped to actrange; force from the
                                               next step's act (MuJoCo's actearly)
      jnt_actfrclimited                        (njnt,)
      ntendon                                  tendons, MuJoCo's ids; 0 when none acts on the
                                               dynamics (inert tendons alone are dropped)
      tendon_adr, tendon_num                   (ntendon,) each tendon's entries in wrap_*
      wrap_type, wrap_objid, wrap_prm          (nwrap,) mjtWrap; joint/site/geom id; joint coef,
                                               side site of a geom, or pulley divisor
      tendon_limited                           (ntendon,) 1 where the length is limited (limits on)
      armature_tendons                         (ntendon_arm,) tendons with armature != 0 when
                                               compiled (tendon.py: inertia and bias traced)
      friction_tendons                         (nfric_ten,) tendons with a friction-loss row
      pair_geom1, pair_geom2, pair_condim      (npair,) geom pairs that can touch (type1 <= type2)
      pair_faceclip                            (npair,) box/mesh-mesh pairs with no margin: MuJoCo's
                                               face-clipping multi-contact (else perturbation)
      pair_window                              (npair,2) height-field pairs: the rows and columns
                                               of cells examined around the geom (else 0)
      geom_meshid                              (ngeom,) the geom's convex hull in mesh_* (-1: none)
      mesh_vertadr, mesh_vertnum               (nmesh,) each hull's vertices in mesh_vert (the
                                               compiler's convex hull, so maxhullvert holds)
      mesh_polyadr                             (nmesh,) each mesh's hull polygons in mesh_poly*
      mesh_polymap                             (nmeshvert, maxmap) the hull polygons each vertex
                                               lies on (mesh-local ids, -1 padded)
      mesh_polyvert                            (npoly, maxpolyvert) each polygon's vertices
                                               (hull-local ids, -1 padded)
      geom_hfieldid                            (ngeom,) the geom's height field (-1: none)
      hfield_nrow, hfield_ncol, hfield_adr     (nhfield,) grid sizes; offsets in hfield_data
      eq_type, eq_obj1id, eq_obj2id, eq_objtype (neq,) equality constraints: mjtEq kind, the two
                                               bodies/joints/sites (obj2 -1: none), mjtObj of the
                                               objects (body or site for connect/weld)
      eq_active0                               (neq,)   1: active at reset (Data.eq_active)
      cone                                     0 pyramidal, 1 elliptic friction cone
      noslip_iterations, noslip_tolerance      MuJoCo's noslip post-pass over the friction rows
                                               (noslip.py); 0 iterations: none traced
      multiccd                                 MuJoCo's multi-contact for convex pairs (False:
                                               <flag multiccd="disable"/>, one contact a pair)
      solver_iterations                        static iteration count of the constraint solver
      linesearch                               'exact': fixed Newton steps with exact line
                                               searches (solver.py); 'mujoco': MuJoCo's islands,
                                               tolerances and line search (newton.py)
      ls_iterations, solver_tolerance, ls_tolerance   MuJoCo's options, for 'mujoco'
      meaninertia                              MuJoCo's stat.meaninertia (solver scale when
                                               islands are disabled)
      ntree, dof_treeid                        kinematic trees and each dof's (islands)
      nconmax                                  contact slots: rows exist for the nconmax deepest
                                               candidate contacts (per condim group)
      max_geom_pairs                           MJX's broad-phase cap (-1: none): each pair group
                                               collides only this many pairs, those whose
                                               bounding spheres overlap most (not planes or
                                               height fields)
      integrator                               Integrator
      disableflags                             MuJoCo's mjtDisableBit mask
      body_names, jnt_names, geom_names, site_names, actuator_names   tuples of str
    Traced parameters (jax.Array):
      timestep ()   gravity (3,)
      body_pos (nbody,3), body_quat (nbody,4), body_ipos (nbody,3), body_iquat (nbody,4)
      body_mass (nbody,), body_inertia (nbody,3), body_gravcomp (nbody,)
      jnt_pos (njnt,3), jnt_axis (njnt,3), jnt_stiffness (njnt,), jnt_range (njnt,2)
      jnt_actfrcrange (njnt,2)
      qpos0 (nq,), qpos_spring (nq,)
      dof_armature (nv,), dof_damping (nv,)
      dof_frictionloss (nv,), dof_solref (nv,2), dof_solimp (nv,5)   friction loss and its softness
      geom_pos (ngeom,3), geom_quat (ngeom,4), geom_size (ngeom,3), geom_friction (ngeom,3)
      geom_rbound (ngeom,)   bounding-sphere radius (MuJoCo's)
      mesh_vert (nmeshvert,3)   vertices in each mesh's frame (only meshes that collide)
      mesh_polynormal (npoly,3)   outward unit normals of the hull polygons
      hfield_size (nhfield,4)   x and y half-extents, top and base heights; hfield_data (n,) the
                                elevations in [0, 1], row-major (only height fields that collide)
      site_pos (nsite,3), site_quat (nsite,4)
      actuator_gear (nu,6), actuator_ctrlrange (nu,2), actuator_forcerange (nu,2)
      actuator_gainprm (nu,10), actuator_biasprm (nu,10)
      actuator_dynprm (nu,10)   (dynprm[0] the filter's time constant), actuator_actrange (nu,2)
      pair_friction (npair,5), pair_solref (npair,2), pair_solimp (npair,5)
      pair_solreffriction (npair,2)                 the elliptic cone's friction solref; 0: solref
      pair_margin (npair,), pair_gap (npair,)       contact parameters, mixed as MuJoCo mixes them
      jnt_solref (njnt,2), jnt_solimp (njnt,5), jnt_margin (njnt,)   joint-limit softness
      tendon_stiffness, tendon_damping, tendon_armature (ntendon,)
      tendon_lengthspring (ntendon,2)               the spring's rest lengths: a dead band [lo, hi]
      tendon_range (ntendon,2), tendon_margin (ntendon,)   length limits
      tendon_solref_lim (ntendon,2), tendon_solimp_lim (ntendon,5)   their softness
      tendon_frictionloss (ntendon,), tendon_solref_fri (ntendon,2), tendon_solimp_fri (ntendon,5)
      tendon_invweight0 (ntendon,)                  MuJoCo's inverse weight of each tendon (for R)
      tendon_length0 (ntendon,)                     tendon lengths at qpos0 (tendon equality reference)
      eq_data (neq,11), eq_solref (neq,2), eq_solimp (neq,5)   MuJoCo's eq_data (anchors,
                                               relpose, torquescale, polynomial) and softness
      body_invweight0 (nbody,2), dof_invweight0 (nv,)   MuJoCo's inverse weights (for R)
      impratio ()
      density (), viscosity (), wind (3,)   the medium of the fluid model (only where body_fluid)
    """

    nq: int
    nv: int
    nu: int
    nbody: int
    njnt: int
    ngeom: int
    nsite: int
    ntendon: int
    body_parentid: np.ndarray
    body_rootid: np.ndarray
    body_jntnum: np.ndarray
    body_jntadr: np.ndarray
    body_dofnum: np.ndarray
    body_dofadr: np.ndarray
    jnt_type: np.ndarray
    jnt_qposadr: np.ndarray
    jnt_dofadr: np.ndarray
    jnt_bodyid: np.ndarray
    jnt_limited: np.ndarray
    dof_bodyid: np.ndarray
    dof_jntid: np.ndarray
    dof_parentid: np.ndarray
    friction_dofs: np.ndarray
    geom_bodyid: np.ndarray
    geom_type: np.ndarray
    geom_contype: np.ndarray
    geom_conaffinity: np.ndarray
    site_bodyid: np.ndarray
    body_fluid: np.ndarray
    gravcomp_bodies: np.ndarray
    mocap_bodies: np.ndarray
    jnt_actgravcomp: np.ndarray
    actuator_trntype: np.ndarray
    actuator_trnid: np.ndarray
    actuator_gaintype: np.ndarray
    actuator_biastype: np.ndarray
    na: int
    actuator_dyntype: np.ndarray
    actuator_actadr: np.ndarray
    actuator_actlimited: np.ndarray
    actuator_actearly: np.ndarray
    actuator_ctrllimited: np.ndarray
    actuator_forcelimited: np.ndarray
    jnt_actfrclimited: np.ndarray
    tendon_adr: np.ndarray
    tendon_num: np.ndarray
    wrap_type: np.ndarray
    wrap_objid: np.ndarray
    wrap_prm: np.ndarray
    tendon_limited: np.ndarray
    armature_tendons: np.ndarray
    friction_tendons: np.ndarray
    pair_geom1: np.ndarray
    pair_geom2: np.ndarray
    pair_condim: np.ndarray
    pair_faceclip: np.ndarray
    pair_window: np.ndarray
    geom_meshid: np.ndarray
    mesh_vertadr: np.ndarray
    mesh_vertnum: np.ndarray
    mesh_polyadr: np.ndarray
    mesh_polymap: np.ndarray
    mesh_polyvert: np.ndarray
    geom_hfieldid: np.ndarray
    hfield_nrow: np.ndarray
    hfield_ncol: np.ndarray
    hfield_adr: np.ndarray
    eq_type: np.ndarray
    eq_obj1id: np.ndarray
    eq_obj2id: np.ndarray
    eq_objtype: np.ndarray
    eq_active0: np.ndarray
    cone: int
    noslip_iterations: int
    noslip_tolerance: float
    multiccd: bool
    solver_iterations: int
    linesearch: str
    ls_iterations: int
    solver_tolerance: float
    ls_tolerance: float
    meaninertia: float
    ntree: int
    dof_treeid: np.ndarray
    nconmax: int
    max_geom_pairs: int
    integrator: int
    disableflags: int
    body_names: tuple
    jnt_names: tuple
    geom_names: tuple
    site_names: tuple
    actuator_names: tuple
    timestep: jax.Array
    gravity: jax.Array
    body_pos: jax.Array
    body_quat: jax.Array
    body_ipos: jax.Array
    body_iquat: jax.Array
    body_mass: jax.Array
    body_inertia: jax.Array
    body_gravcomp: jax.Array
    jnt_pos: jax.Array
    jnt_axis: jax.Array
    jnt_stiffness: jax.Array
    jnt_range: jax.Array
    jnt_actfrcrange: jax.Array
    qpos0: jax.Array
    qpos_spring: jax.Array
    dof_armature: jax.Array
    dof_damping: jax.Array
    dof_frictionloss: jax.Array
    dof_solref: jax.Array
    dof_solimp: jax.Array
    geom_pos: jax.Array
    geom_quat: jax.Array
    geom_size: jax.Array
    geom_friction: jax.Array
    geom_rbound: jax.Array
    mesh_vert: jax.Array
    mesh_polynormal: jax.Array
    hfield_size: jax.Array
    hfield_data: jax.Array
    site_pos: jax.Array
    site_quat: jax.Array
    actuator_gear: jax.Array
    actuator_ctrlrange: jax.Array
    actuator_forcerange: jax.Array
    actuator_gainprm: jax.Array
    actuator_biasprm: jax.Array
    actuator_dynprm: jax.Array
    actuator_actrange: jax.Array
    pair_friction: jax.Array
    pair_solref: jax.Array
    pair_solreffriction: jax.Array
    pair_solimp: jax.Array
    pair_margin: jax.Array
    pair_gap: jax.Array
    jnt_solref: jax.Array
    jnt_solimp: jax.Array
    jnt_margin: jax.Array
    tendon_stiffness: jax.Array
    tendon_damping: jax.Array
    tendon_armature: jax.Array
    tendon_lengthspring: jax.Array
    tendon_range: jax.Array
    tendon_margin: jax.Array
    tendon_solref_lim: jax.Array
    tendon_solimp_lim: jax.Array
    tendon_frictionloss: jax.Array
    tendon_solref_fri: jax.Array
    tendon_solimp_fri: jax.Array
    tendon_invweight0: jax.Array
    tendon_length0: jax.Array
    eq_data: jax.Array
    eq_solref: jax.Array
    eq_solimp: jax.Array
    body_invweight0: jax.Array
    dof_invweight0: jax.Array
    impratio: jax.Array
    density: jax.Array
    viscosity: jax.Array
    wind: jax.Array

    @property
    def npair(self) -> int:
        return int(self.pair_geom1.size)

    def summary(self) -> str:
        """A one-paragraph description of the scene's size."""
        types = [JointType(t).name.lower() for t in self.jnt_type]
        counts = {t: types.count(t) for t in dict.fromkeys(types)}
        joints = ", ".join(f"{n} {t}" for t, n in counts.items()) or "none"
        return (
            f"bodies {self.nbody - 1} (+world), joints {self.njnt} ({joints}), nq {self.nq}, "
            f"nv {self.nv}, actuators {self.nu}, geoms {self.ngeom}, sites {self.nsite}, "
            f"contact pairs {self.npair}, "
            f"integrator {Integrator(self.integrator).name}, timestep {float(self.timestep):g}"
        )


@pytree_dataclass
class Data:
    """Simulation state and the quantities the pipeline derives from it (MuJoCo's names).

    State:        qpos (nq,)  qvel (nv,)  ctrl (nu,)  act (na,)  time ()  qfrc_applied (nv,)
                  qacc_warmstart (nv,)  the last step's acceleration, the solver's starting point
                  mocap_pos (nmocap,3)  mocap_quat (nmocap,4)  poses of the mocap bodies (set them
                  between steps; a step holds them fixed)
                  eq_active (neq,) bool: which equality constraints act (MuJoCo's eq_active;
                  switch them between steps)
    Kinematics:   xpos (nbody,3)  xquat (nbody,4)  xmat (nbody,3,3)  xipos (nbody,3)
                  ximat (nbody,3,3)  xanchor (njnt,3)  xaxis (njnt,3)
                  geom_xpos (ngeom,3)  geom_xmat (ngeom,3,3)  site_xpos (nsite,3)  site_xmat (nsite,3,3)
    Com-based:    subtree_com (nbody,3)  cinert (nbody,10)  cdof (nv,6)  cvel (nbody,6)
                  cdof_dot (nv,6)
    Tendons:      ten_length (ntendon,)  ten_velocity (ntendon,)  ten_J (ntendon,nv) (dense ten_moment)
    Dynamics:     qM (nv,nv)  qfrc_bias (nv,)  qfrc_spring (nv,)  qfrc_damper (nv,)
                  qfrc_passive (nv,)  actuator_length (nu,)  actuator_velocity (nu,)
                  actuator_force (nu,)  act_dot (na,)  qfrc_actuator (nv,)  qfrc_smooth (nv,)
                  qacc (nv,)
                  qacc_smooth (nv,)  acceleration without constraints
    Contacts:     contact_dist (ncand,)  contact_pos (ncand,3)  contact_frame (ncand,3,3) (rows:
                  normal, tangents); candidates of the static pair table, active where
                  dist < margin.  contact_pair (ncand,) int32: the pair each candidate holds
                  (fixed, except in groups that MJX's broad-phase cap compacts: see
                  collision_driver.compacted).  ncon () int32: how many are active (mjData.ncon)
                  contact_id (nslot,) int32: the candidate held by each contact slot (the
                  nconmax deepest, see constraint.py); only slots have constraint rows
                  contact_overflow () int32: what the fixed budgets dropped this step (0: the
                  contacts are MuJoCo's): pairs whose bounding spheres, grown by the margin,
                  overlap but that a GJK group's budget left untested or unsolved
                  (collision_driver.gjk_slots) or MJX's max_geom_pairs left out, plus contacts
                  within their margin that found no slot (mjData's nconmax warning)
    Constraints:  efc_J (nefc,nv)  efc_pos (nefc,)  efc_aref (nefc,)  efc_D (nefc,) (= 1/R; 0 on
                  rows beyond their margin)  efc_force (nefc,)  qfrc_constraint (nv,); rows:
                  the equality constraints' (3 connect, 6 weld, 1 joint), one per friction-loss
                  dof, one per limited joint, then the contact slots' rows
    Health:       diverged ()  True once the state has been non-finite or beyond bounds
    """

    qpos: jax.Array
    qvel: jax.Array
    ctrl: jax.Array
    act: jax.Array
    time: jax.Array
    qfrc_applied: jax.Array
    qacc_warmstart: jax.Array
    mocap_pos: jax.Array
    mocap_quat: jax.Array
    eq_active: jax.Array
    xpos: jax.Array
    xquat: jax.Array
    xmat: jax.Array
    xipos: jax.Array
    ximat: jax.Array
    xanchor: jax.Array
    xaxis: jax.Array
    geom_xpos: jax.Array
    geom_xmat: jax.Array
    site_xpos: jax.Array
    site_xmat: jax.Array
    subtree_com: jax.Array
    cinert: jax.Array
    cdof: jax.Array
    cvel: jax.Array
    cdof_dot: jax.Array
    ten_length: jax.Array
    ten_velocity: jax.Array
    ten_J: jax.Array
    qM: jax.Array
    qfrc_bias: jax.Array
    qfrc_spring: jax.Array
    qfrc_damper: jax.Array
    qfrc_passive: jax.Array
    actuator_length: jax.Array
    actuator_velocity: jax.Array
    actuator_force: jax.Array
    act_dot: jax.Array
    qfrc_actuator: jax.Array
    qfrc_smooth: jax.Array
    qacc: jax.Array
    qacc_smooth: jax.Array
    contact_dist: jax.Array
    contact_pos: jax.Array
    contact_frame: jax.Array
    contact_pair: jax.Array
    ncon: jax.Array
    contact_id: jax.Array
    contact_overflow: jax.Array
    efc_J: jax.Array
    efc_pos: jax.Array
    efc_aref: jax.Array
    efc_D: jax.Array
    efc_force: jax.Array
    qfrc_constraint: jax.Array
    diverged: jax.Array
