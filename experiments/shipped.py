"""The physics settings ``python -m fastrl.train env=<name>`` trains with, for experiments.

Shared by the experiment scripts (``from experiments.shipped import shipped_setting``) so that
"the shipped setting" means one thing everywhere. A helper module, not a script.
"""

from __future__ import annotations

from experiments.results import ROOT

PHYSICS_KEYS = ("integrator", "solver_iterations", "timestep", "frame_skip")


def shipped_overrides(name: str, algo: str = "ppo") -> dict:
    """Physics keys set in ``conf/experiment/<name>_<algo>.yaml`` (the env group sets none: it is
    each env's name and constructor options)."""
    from omegaconf import OmegaConf

    path = ROOT / "conf" / "experiment" / f"{name}_{algo}.yaml"
    if not path.exists():
        return {}
    conf = OmegaConf.to_container(OmegaConf.load(path)).get("env") or {}
    return {k: conf[k] for k in PHYSICS_KEYS if conf.get(k) is not None}


def shipped_setting(name: str, dt: float) -> dict:
    """Integrator, substeps per control step ``dt`` and solver iterations of the shipped setting."""
    import numpy as np

    from fastrl import envs
    from fastrl.physics import Integrator

    env = envs.make(name, **shipped_overrides(name))
    shipped_dt = float(np.float64(np.float32(env.model.timestep))) * env.frame_skip
    if not np.isclose(shipped_dt, dt, rtol=1e-5):
        raise ValueError(f"{name}: the shipped control step {shipped_dt} differs from the env's {dt}")
    return {"integrator": Integrator(env.model.integrator).name.lower(),
            "substeps": round(dt / float(env.model.timestep)),
            "solver_iterations": int(env.model.solver_iterations)}  # fmt: skip
