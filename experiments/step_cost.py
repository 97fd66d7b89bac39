"""Physics step cost per env, for before/after comparisons of engine changes.

    python -m experiments.step_cost ant,hopper,...          # {env: microseconds per env-step}
    python -m experiments.step_cost ant,hopper,... --hlo    # {env: digest of the compiled step}

jax.jit(jax.vmap(physics.step)) at batch 256 from each env's reset states, zero controls; the best of
5 repeats of 10 steps. Run it from two checkouts alternately (PYTHONPATH=<checkout>) for a ratio.

``--hlo`` times nothing: it digests XLA's optimised program for one env's step, its instructions
with names, metadata and numbering stripped and sorted. Equal digests from two checkouts mean the
change compiled to the same program for that env, so its step cost cannot have moved.
``--without contact_overflow`` leaves a ``Data`` field out of the digested program (held at the
reset state's value, and not returned), to compare with a checkout that lacks the field.
"""

import argparse
import dataclasses
import hashlib
import json
import re
import time

import jax
import jax.numpy as jnp

import fastrl
from fastrl import envs, physics


def program_digest(m, d, without: tuple[str, ...] = ()) -> str:
    """A digest of the optimised HLO of ``physics.step``: its instructions, names dropped; the
    fields ``without`` neither inputs nor outputs of the program."""

    def fields(d):
        return {f.name: getattr(d, f.name) for f in dataclasses.fields(d) if f.name not in without}

    text = (
        jax.jit(lambda rest: fields(physics.step(m, d.replace(**rest)))).lower(fields(d)).compile().as_text()
    )
    ops = []
    for line in text.splitlines():
        if " = " not in line:
            continue
        line = re.sub(r", metadata=\{[^}]*\}", "", line)
        line = re.sub(r"%[\w.-]+", "%x", line)
        if re.search(r"\[(\d+,)*0[,\]]", line.split(" = ")[1].split(" ")[0]):
            continue  # a zero-size array (a feature the model lacks): no work
        line = re.sub(r"parameter\(\d+\)", "parameter", line)
        line = re.sub(r"/\*index=\d+\*/", "", line)  # tuples: drop zero-size members and numbering
        line = re.sub(r"\w+\[(\d+,)*0(,\d+)*\](\{[\d,]*\})?(, )?", "", line)
        line = re.sub(r"tuple\([^)]*\)", "tuple", line)
        ops.append(re.sub(r"\.\d+", "", line))
    return hashlib.sha256("\n".join(sorted(ops)).encode()).hexdigest()[:16]


def step_cost(name: str) -> float:
    """Microseconds per env-step of ``name``'s physics step at batch 256: the best of 5 repeats."""
    env = envs.make(name)
    m = env.model
    keys = jax.random.split(jax.random.PRNGKey(0), 256)
    s = jax.vmap(env.reset)(keys)
    d = s.data
    f = jax.jit(jax.vmap(lambda d, u, m=m: physics.step(m, d, u)))
    u = jnp.zeros((256, m.nu))
    d = f(d, u)
    jax.block_until_ready(d.qpos)
    best = 1e9
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(10):
            d = f(d, u)
        jax.block_until_ready(d.qpos)
        best = min(best, (time.perf_counter() - t) / 10)
    return best * 1e6 / 256


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("envs", help="env names, comma-separated (ant,hopper,...)")
    parser.add_argument("--hlo", action="store_true", help="digest each env's compiled step; time nothing")
    parser.add_argument("--without", nargs="*", default=(), help="--hlo: Data fields left out of the program")
    args = parser.parse_args()
    out = {}
    for name in args.envs.split(","):
        if args.hlo:
            env = envs.make(name)
            out[name] = program_digest(env.model, env.reset(jax.random.PRNGKey(0)).data, tuple(args.without))
        else:
            out[name] = step_cost(name)
    print(json.dumps(out))


if __name__ == "__main__":
    fastrl.use_recommended_xla_flags()  # the XLA:CPU flags fastrl's command line runs with
    main()
