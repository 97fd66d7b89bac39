"""Domain randomisation: per-env model parameters, drawn at every reset and applied in every step.

``sample`` draws an episode's parameters into ``State.params`` (a dict of arrays, empty when
randomisation is off); ``apply`` scales the nominal model by them. Both are pure and traced, so
a batch of envs steps a batch of models in one program, and new draws never recompile.
"""

from __future__ import annotations

import dataclasses

import jax

from fastrl.physics import Model


@dataclasses.dataclass(frozen=True)
class Randomization:
    """Domain randomisation ranges (0 width = off).

    Scales are multiplicative and uniform in ``[1 - w, 1 + w]``. Mass scales each body's mass
    and rotational inertia together (a density change); friction scales every contact pair's
    friction coefficients; damping scales every dof's damping; gain scales each actuator's
    gain and its position feedback together (a position servo's ``kp``; a motor's gear).
    Quantities MuJoCo precomputes at compile time from the nominal model (``body_invweight0``,
    which sets contact softness) are not recomputed, as in MJX.

    Fields:
      mass        half-width of the per-body mass scale
      friction    half-width of the per-env friction scale
      damping     half-width of the per-dof damping scale
      gain        half-width of the per-actuator gain scale
    """

    mass: float = 0.0
    friction: float = 0.0
    damping: float = 0.0
    gain: float = 0.0

    def __post_init__(self):
        for name in ("mass", "friction", "damping", "gain"):
            w = getattr(self, name)
            if not 0.0 <= w < 1.0:
                raise ValueError(f"randomization.{name}={w}: the half-width must be in [0, 1)")

    @property
    def enabled(self) -> bool:
        return bool(self.mass or self.friction or self.damping or self.gain)


def sample(r: Randomization, model: Model, key: jax.Array) -> dict:
    """One episode's parameters: ``mass_scale`` (nbody,), ``friction_scale`` (),
    ``damping_scale`` (nv,) and ``gain_scale`` (nu,), each present where its width is not 0."""
    params = {}
    if not r.enabled:
        return params
    k1, k2, k3 = jax.random.split(key, 3)  # the gain's key folds in: earlier draws unchanged
    dtype = model.body_mass.dtype
    if r.mass:
        params["mass_scale"] = jax.random.uniform(k1, (model.nbody,), dtype, 1 - r.mass, 1 + r.mass)
    if r.friction:
        params["friction_scale"] = jax.random.uniform(k2, (), dtype, 1 - r.friction, 1 + r.friction)
    if r.damping:
        params["damping_scale"] = jax.random.uniform(k3, (model.nv,), dtype, 1 - r.damping, 1 + r.damping)
    if r.gain:
        k4 = jax.random.fold_in(key, 4)
        params["gain_scale"] = jax.random.uniform(k4, (model.nu,), dtype, 1 - r.gain, 1 + r.gain)
    return params


def apply(model: Model, params: dict) -> Model:
    """``model`` with an episode's parameters (``sample``) applied."""
    m = model
    if "mass_scale" in params:
        s = params["mass_scale"]
        m = m.replace(body_mass=m.body_mass * s, body_inertia=m.body_inertia * s[:, None])
    if "friction_scale" in params:
        m = m.replace(pair_friction=m.pair_friction * params["friction_scale"])
    if "damping_scale" in params:
        m = m.replace(dof_damping=m.dof_damping * params["damping_scale"])
    if "gain_scale" in params:  # gain and position feedback (biasprm[1] = -kp) together
        s = params["gain_scale"]
        m = m.replace(
            actuator_gainprm=m.actuator_gainprm.at[:, 0].multiply(s),
            actuator_biasprm=m.actuator_biasprm.at[:, 1].multiply(s),
        )
    return m
