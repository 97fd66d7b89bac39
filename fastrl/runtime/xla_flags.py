"""XLA:CPU flags that fastrl's programs run faster with, set before JAX starts its CPU backend.

XLA reads ``XLA_FLAGS`` once, when the first backend starts, so these must be in the environment
before any JAX computation. Importing fastrl sets nothing: the command-line entry points call
``apply()`` (``python -m fastrl.train`` with the CPU device count and the learner, in
``fastrl.cli.train``), and a library user opts in with
``fastrl.use_recommended_xla_flags()``. A flag that ``XLA_FLAGS`` already names is left as the
user set it, and ``FASTRL_XLA_FLAGS=0`` turns the defaults off altogether.

Measured on the 2-core development machine (jax 0.10.2), default vs with the flag:

- ``--xla_cpu_use_fusion_emitters=false``: XLA:CPU's newer fusion emitters compile the physics
  step more slowly and run it no faster. One jitted scan of batched steps at batch 1024
  (us/env/substep, compile s): Ant Euler 17.0/13.0 vs 16.8/8.6; HalfCheetah 9.9/9.8 vs 8.7/5.5;
  Hopper 33.9/10.4 vs 36.6/9.0; Walker2d 50.2/12.3 vs 46.4/10.1; Humanoid 458/40.9 vs 466/42.4.
  The default Ant PPO run's chunk compile: 30.3 s -> 19.7 s.
- ``--xla_cpu_experimental_ynn_fusion_type=-reduce,-eltwise``: XLA:CPU hands reductions and
  elementwise chains to YNNPACK, which runs the physics' many small per-environment sums (a
  3x3 inertia rotation over 1024 envs took 2.1 ms as a YNN fusion) slower than XLA's own loops.
  YNNPACK keeps the dots (the networks' matmuls). Ant RK4 at batch 1024, best of 3: 81.8 ->
  ~68-74 us/env/substep; Ant Euler with 5 iterations 19.4 -> 18.4; the default Ant PPO run
  10.7k -> 12.4-13.0k env steps/s.

Per learner (``NOT_FOR``): SAC's time goes to small dense networks (16 gradient steps of 2x256
networks per 64 env steps), which XLA's fusion emitters run faster: hopper SAC made 620 env
steps/s with both flags, 750 with the YNNPACK flag alone and 770 with neither, so the command
line leaves the emitters on for SAC. APG (gradients through the physics) wants both: reacher APG
8.3k env steps/s with both, 7.8k with the YNNPACK flag alone, 5.6k with neither.
"""

from __future__ import annotations

import os
import sys

DEFAULTS = {
    "--xla_cpu_use_fusion_emitters": "false",
    "--xla_cpu_experimental_ynn_fusion_type": "-reduce,-eltwise",
}
# Default flags a learner runs slower with (measured: see above); the command line leaves them out.
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
