"""fastrl: reinforcement learning on simulated robots, physics and learning in one compiled program."""

from fastrl import xla_flags

__version__ = "0.1.0"

# XLA:CPU flags measured faster for fastrl's programs (see fastrl/xla_flags.py); only takes
# effect if JAX has not started a backend yet, keeps any flag XLA_FLAGS names, and
# FASTRL_XLA_FLAGS=0 turns it off.
xla_flags.apply()


def __getattr__(name):
    # Lazy, so ``import fastrl.physics`` does not pull in the learners and orbax.
    if name == "load_policy":
        from fastrl.policy import load_policy

        return load_policy
    raise AttributeError(f"module 'fastrl' has no attribute {name!r}")


__all__ = ["load_policy"]
