"""XLA:CPU flags that fastrl's programs run faster with, set before JAX starts its CPU backend.

XLA reads ``XLA_FLAGS`` once, when the first backend starts, so these must be in the environment
before any JAX computation. Importing fastrl sets nothing: the command-line entry points call
``apply()`` (``python -m fastrl.train`` with the CPU device count and the learner, in
``fastrl.cli.train``), and a library user opts in with
``fastrl.use_recommended_xla_flags()``. A flag that ``XLA_FLAGS`` already names is left as the
user set it, and ``FASTRL_XLA_FLAGS=0`` turns the defaults off altogether.

Why each flag (measured on this project's 2-core CPU; docs/training.md has the numbers):

- ``--xla_cpu_use_fusion_emitters=false``: XLA:CPU's newer fusion emitters compile the physics
  step more slowly and run it no faster.
- ``--xla_cpu_experimental_ynn_fusion_type=-reduce,-eltwise``: XLA:CPU would hand reductions
  and elementwise chains to YNNPACK, which runs the physics' many small per-environment sums
  slower than XLA's own loops. YNNPACK keeps the dots (the networks' matmuls).

Per learner (``NOT_FOR``): SAC's time goes to small dense networks, which XLA's fusion emitters
run faster, so the command line leaves the emitters on for SAC; APG (gradients through the
physics) runs fastest with both flags.
"""

from __future__ import annotations

import os
import sys

DEFAULTS = {
    "--xla_cpu_use_fusion_emitters": "false",
    "--xla_cpu_experimental_ynn_fusion_type": "-reduce,-eltwise",
}
# Default flags a learner runs slower with (see above); the command line leaves them out.
NOT_FOR = {"sac": ("--xla_cpu_use_fusion_emitters",)}
DEVICE_FLAG = "--xla_force_host_platform_device_count"
# The flags fastrl put into XLA_FLAGS, so that a child process (which inherits both) can tell them
# from the user's own: a learner may take out a default it runs slower with, never a user's flag.
ADDED_VAR = "FASTRL_XLA_FLAGS_ADDED"
_USER_FLAGS = os.environ.get("XLA_FLAGS")  # as the user set it, before ``apply()`` added to it


def names(flags: str) -> set[str]:
    """The flag names an ``XLA_FLAGS`` string sets."""
    return {f.split("=", 1)[0] for f in flags.split()}


def with_defaults(flags: str, devices: int | None = None, algo: str | None = None) -> str:
    """``flags`` (an ``XLA_FLAGS`` string) plus every default flag it does not name, and the
    CPU device count when ``devices`` is given and it names none. With ``algo``, the defaults
    that learner runs slower with (``NOT_FOR``) are left out, and taken out again where fastrl
    added them earlier (an earlier ``apply()``, here or in a parent process: ``ADDED_VAR``)."""
    skip = NOT_FOR.get(algo or "", ())
    added_earlier = set(os.environ.get(ADDED_VAR, "").split())
    out = [f for f in flags.split() if not (f in added_earlier and names(f) & set(skip))]
    named = names(" ".join(out))
    if devices is not None and DEVICE_FLAG not in named and devices > 1:
        out.append(f"{DEVICE_FLAG}={devices}")
    if os.environ.get("FASTRL_XLA_FLAGS", "1") != "0":
        out += [f"{k}={v}" for k, v in DEFAULTS.items() if k not in named and k not in skip]
    return " ".join(out)


def apply(devices: int | None = None, algo: str | None = None) -> bool:
    """Puts ``with_defaults`` into ``XLA_FLAGS`` if no JAX backend has started yet.

    Returns whether it could (after a backend starts, XLA no longer reads the flags).
    """
    if "jax" in sys.modules:
        from jax._src import xla_bridge

        if xla_bridge.backends_are_initialized():
            return False
    current = os.environ.get("XLA_FLAGS", "")
    new = with_defaults(current, devices, algo)
    added = set(os.environ.get(ADDED_VAR, "").split()) | (set(new.split()) - set(current.split()))
    os.environ[ADDED_VAR] = " ".join(sorted(added))
    os.environ["XLA_FLAGS"] = new
    return True


def peer_environ(**extra: str) -> dict[str, str]:
    """``os.environ`` with ``XLA_FLAGS`` as the user set it (without fastrl's defaults), plus
    ``extra``: for the benchmarks' peer processes (Brax), which run at their own defaults."""
    env = dict(os.environ, **extra)
    if _USER_FLAGS is None:
        env.pop("XLA_FLAGS", None)
    else:
        env["XLA_FLAGS"] = _USER_FLAGS
    return env
