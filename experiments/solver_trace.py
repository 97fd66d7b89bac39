"""Where a robot task's constraint solve spends its time, XLA operation by operation.

    python -m experiments.solver_trace leap_cube_reorient
    python -m experiments.solver_trace panda_pick_cube --stage step --top 30

The task's batch is stepped for ``--warmup`` control steps of random actions (as
``experiments.stage_profile``), then ``--stage`` (``solver``: the Newton solve; ``step``: the
physics step) is compiled alone under ``vmap`` and run ``--calls`` times inside a JAX profiler
trace, with XLA:CPU's per-thunk trace events on (``--xla_cpu_enable_xprof_traceme``). Each
operation's time is summed over the trace and printed as microseconds per env per call, grouped
by how many times it runs per call: an operation that runs once per solve belongs to its setup,
one that runs once per Newton step to the step's Hessian and factor, one that runs many times to
the line search's passes. The tracing costs time of its own, so the totals exceed
``stage_profile``'s; the shares are what this is for. Prints only; writes nothing.
"""

from __future__ import annotations

import argparse
import collections
import gzip
import json
import os
import pathlib
import tempfile

FLAG = "--xla_cpu_enable_xprof_traceme=true"
if FLAG not in os.environ.get("XLA_FLAGS", ""):  # before JAX starts its CPU backend
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {FLAG}".strip()

import jax  # noqa: E402

from experiments import compile_time, stage_profile  # noqa: E402
from fastrl import physics  # noqa: E402

RUNTIME = ("ThunkExecutor", "$", "PjitFunction", "CommonPjRt")  # the runtime's own events


def trace(name: str, stage: str, batch: int, warmup: int, calls: int) -> tuple[dict, dict, int]:
    """Each operation's total microseconds and count over ``calls`` calls of the stage."""
    env, state, batch = stage_profile.task_states(name, batch, warmup)
    m = env.model
    d = jax.jit(jax.vmap(lambda d: physics.forward(m, d)))(state.data)
    fn = compile_time.stages(m)["solver"] if stage == "solver" else (lambda d: physics.step(m, d))
    run = jax.jit(jax.vmap(fn))
    jax.block_until_ready(run(d))
    with tempfile.TemporaryDirectory() as out:
        with jax.profiler.trace(out):
            for _ in range(calls):
                result = run(d)
            jax.block_until_ready(result)
        (path,) = pathlib.Path(out).rglob("*.trace.json.gz")
        events = json.load(gzip.open(path))["traceEvents"]
    total, count = collections.Counter(), collections.Counter()
    for e in events:
        if e.get("ph") == "X" and not e["name"].startswith(RUNTIME):
            total[e["name"]] += e["dur"]
            count[e["name"]] += 1
    return total, count, batch


def main() -> None:
    raw = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=raw)
    parser.add_argument("task", help="a robot task, e.g. leap_cube_reorient")
    parser.add_argument("--stage", choices=["solver", "step"], default="solver")
    parser.add_argument("--batch", type=int, default=1024)
    parser.add_argument("--warmup", type=int, default=40, help="control steps of random actions first")
    parser.add_argument("--calls", type=int, default=5)
    parser.add_argument("--top", type=int, default=15, help="operations to list")
    args = parser.parse_args()
    total, count, batch = trace(args.task, args.stage, args.batch, args.warmup, args.calls)

    def per_env(us: float) -> float:
        return us / args.calls / batch

    groups, ops = collections.Counter(), collections.Counter()
    for op, us in total.items():
        groups[count[op] // args.calls] += us
        ops[count[op] // args.calls] += 1
    whole = per_env(sum(total.values()))
    print(f"{args.task}, {args.stage}, batch {batch}: {whole:.1f} us/env per call (traced)")
    print("runs per call | us/env | operations")
    for runs, us in sorted(groups.items()):
        print(f"{runs:13d} | {per_env(us):6.2f} | {ops[runs]}")
    print(f"the {args.top} costliest operations (us/env, runs per call, name):")
    for op, us in total.most_common(args.top):
        print(f"{per_env(us):8.3f}  {count[op] // args.calls:5d}  {op}")


if __name__ == "__main__":
    main()
