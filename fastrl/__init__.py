"""fastrl: reinforcement learning on simulated robots, physics and learning in one compiled program.

Importing fastrl changes nothing in the process: no environment variable, no XLA flag, no JAX
setting. The command-line entry points (``python -m fastrl.train``, ``fastrl.evaluate``) set
the XLA:CPU flags fastrl's programs run faster with; a library user opts in with one call,
before JAX starts a backend::

    import fastrl
    fastrl.use_recommended_xla_flags()
"""

from fastrl.runtime import xla_flags

__version__ = "0.1.0"


def use_recommended_xla_flags(devices: int | None = None, algo: str | None = None) -> bool:
    """Adds fastrl's measured XLA:CPU flags (``fastrl/runtime/xla_flags.py``) to ``XLA_FLAGS``.

    Call it before the first JAX computation: XLA reads the flags once, when its backend starts.
    A flag that ``XLA_FLAGS`` already names is kept as the user set it, and
    ``FASTRL_XLA_FLAGS=0`` in the environment turns the defaults off.

    Args:
      devices: also split the CPU into this many XLA devices (unless ``XLA_FLAGS`` names a count).
      algo: leave out the defaults this learner runs slower with (``xla_flags.NOT_FOR``).
    Returns:
      Whether the flags could be set (False once a JAX backend has started).
    """
    return xla_flags.apply(devices, algo)


def __getattr__(name):
    # PEP 562 lazy attribute, so that ``import fastrl.physics`` does not pull in the learners,
    # orbax and the training layer; the one function-local import of a fastrl module, on purpose.
    if name == "load_policy":
        from fastrl.training.policy import load_policy

        return load_policy
    raise AttributeError(f"module 'fastrl' has no attribute {name!r}")


__all__ = ["load_policy", "use_recommended_xla_flags"]
