"""fastrl: reinforcement learning on simulated robots, physics and learning in one compiled program."""

__version__ = "0.1.0"


def __getattr__(name):
    # Lazy, so ``import fastrl.physics`` does not pull in the learners and orbax.
    if name == "load_policy":
        from fastrl.policy import load_policy

        return load_policy
    raise AttributeError(f"module 'fastrl' has no attribute {name!r}")


__all__ = ["load_policy"]
