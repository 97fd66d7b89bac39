"""The measured tables of the README and of ``docs/``, built from ``experiments/results/``.

    python -m experiments.docs           # rewrite every generated block
    python -m experiments.docs --check   # exit 1, naming the blocks, if one is not what the results say

A page marks a generated block with a pair of HTML comments::

    <!-- results: NAME -->
    ...replaced by BLOCKS[NAME]()...
    <!-- /results -->

and keeps its prose outside them. A block reads the JSON records the experiments wrote
(:func:`experiments.results.load`), so a number in the docs is the number of a committed run, and
``tests/test_docs.py`` fails when a record changes without the docs being rebuilt.
"""

from __future__ import annotations

import argparse
import re
import statistics
import sys
from collections.abc import Callable
from pathlib import Path

from experiments import results
from experiments.results import load, number, table
from experiments.sb3_compare import LABELS, time_ratio

PAGES = [results.ROOT / "README.md", *sorted((results.ROOT / "docs").glob("*.md"))]
BLOCK = re.compile(r"(<!-- results: (\S+) -->\n)(.*?)(<!-- /results -->)", re.S)
TASKS = (
    "inverted_pendulum",
    "ant",
    "hopper_sac",
    "halfcheetah_sac",
    "halfcheetah_es",
    "swimmer_es",
    "reacher_apg",
    "inverted_pendulum_apg",
)


def ratio(a: float | None, b: float | None) -> str:
    return f"{a / b:.2f}x" if a and b else "–"


def date(record: dict) -> str:
    return record.get("date") or (record.get("meta") or {}).get("date") or "–"


def link(stem: str) -> str:
    return f"[{stem}](experiments/results/{stem}.md)"


def source(stem: str) -> str:
    """The line under a block: its record's date and a link to its full page."""
    return f"\n\n{date(load(stem))}; {link(stem)}"


# --------------------------------------------------------------------------- the blocks


def physics_throughput() -> list[list]:
    """Best steps/s per integrator: fastrl against MuJoCo C's rollout on both threads."""
    rows = load("physics_throughput")["rows"]
    out = []
    for integrator in ("euler", "rk4"):
        mine = [r for r in rows if r["integrator"] == integrator]
        fastrl = max((r for r in mine if r["engine"] == "fastrl"), key=lambda r: r["steps_per_s"])
        peer = max((r for r in mine if "2 thread" in r["engine"]), key=lambda r: r["steps_per_s"])
        out.append(
            [
                integrator,
                fastrl["steps_per_s"],
                fastrl["batch"],
                peer["steps_per_s"],
                ratio(fastrl["steps_per_s"], peer["steps_per_s"]),
            ]
        )
    return out


def physics_block() -> str:
    header = ["integrator", "fastrl steps/s", "at batch", "MuJoCo C rollout, 2 threads", "ratio"]
    return table(header, physics_throughput()) + source("physics_throughput")


def contacts_best() -> dict[str, dict]:
    """Each engine's best batch in the Ant-with-contacts benchmark."""
    best: dict[str, dict] = {}
    for r in load("contacts_throughput")["rows"]:
        if r["engine"] not in best or r["control_steps_per_s"] > best[r["engine"]]["control_steps_per_s"]:
            best[r["engine"]] = r
    return best


def contacts_block() -> str:
    best = contacts_best()
    envpool = next(r for e, r in best.items() if e.startswith("EnvPool"))["control_steps_per_s"]
    rows = sorted(best.values(), key=lambda r: -r["control_steps_per_s"])
    body = [
        [r["engine"], r["control_steps_per_s"], r["batch"], ratio(r["control_steps_per_s"], envpool)]
        for r in rows
    ]
    return table(["engine", "best control steps/s", "at batch", "vs EnvPool"], body) + source(
        "contacts_throughput"
    )


def env_block() -> str:
    record = load("env_throughput")
    best: dict[str, dict] = {}
    for r in record["envs"]:
        two = r["split_2_devices"]["control_steps_per_s"]
        if r["env"] not in best or two > best[r["env"]]["two"]:
            best[r["env"]] = {
                "one": r["control_steps_per_s"],
                "two": two,
                "batch": r["batch"],
                "envpool": r["envpool_control_steps_per_s"],
            }
    rows = [
        [env, b["batch"], b["one"], b["two"], b["envpool"], ratio(b["two"], b["envpool"])]
        for env, b in sorted(best.items(), key=lambda kv: -kv[1]["two"] / kv[1]["envpool"])
    ]
    header = [
        "env",
        "batch",
        "fastrl, 1 device",
        "fastrl, 2 devices",
        "EnvPool, 2 threads",
        "ratio (2 devices)",
    ]
    return table(header, rows) + source("env_throughput")


def vector_block() -> str:
    record = load("env_throughput_ant")
    rows = []
    for v in record["vector"]:
        rows.append(
            [
                v["num_envs"],
                v["gymnasium_sync_steps_per_s"],
                ratio(v["fastrl_make_vec_steps_per_s"], v["gymnasium_sync_steps_per_s"]),
                ratio(v["fastrl_make_vec_2_devices_steps_per_s"], v["gymnasium_sync_steps_per_s"]),
                ratio(
                    v["fastrl_make_vec_training_settings_2_devices_steps_per_s"],
                    v["gymnasium_sync_steps_per_s"],
                ),
            ]
        )
    header = [
        "envs",
        "SyncVectorEnv(Ant-v5) steps/s",
        "make_vec, RK4, 1 device",
        "RK4, 2 devices",
        "training settings, 2 devices",
    ]
    return table(header, rows) + source("env_throughput_ant")


def time_to_return(task: str) -> dict:
    """One task's fastrl-vs-Brax summary: target, median seconds, seeds that reached it, ratio."""
    record = load(f"time_to_return_{task}")
    mine, brax = record["summary"]["fastrl"], record["summary"]["brax"]
    if mine["median_s"] and brax["median_s"]:
        r = ratio(mine["median_s"], brax["median_s"])
    elif mine["median_s"]:  # Brax's median seed did not get there within its time
        r = f"< {mine['median_s'] / brax['median_wall_s']:.2f}x"
    else:
        r = "not reached"
    return {
        "task": task,
        "target": record["target"],
        "fastrl": mine,
        "brax": brax,
        "ratio": r,
        "date": date(record),
    }


def _seconds(side: dict) -> str:
    reached = f"{side['reached']} of {side['runs']}"
    if side["median_s"]:
        return f"{side['median_s']:.0f} s ({reached})"
    return f"{reached} (median final {side['median_final_return']:.0f} at {side['median_wall_s']:.0f} s)"


def time_to_return_block() -> str:
    rows = []
    for t in map(time_to_return, TASKS):
        task = t["task"] if t["task"].endswith(("_sac", "_es", "_apg")) else f"{t['task']}_ppo"
        rows.append([task, t["target"], _seconds(t["fastrl"]), _seconds(t["brax"]), t["ratio"], t["date"]])
    header = ["task / learner", "target", "fastrl: median time (seeds reaching)", "Brax", "time ratio", "run"]
    return (
        table(header, rows, align="lrllll") + "\n\n" + ", ".join(link(f"time_to_return_{t}") for t in TASKS)
    )


def first_minute_block() -> str:
    record = load("first_minute")
    rows = []
    for env, runs in record["results"].items():
        for kind in ("cold", "cached"):
            r = runs[kind]
            rows.append(
                [env, kind, r["first_line_s"], r["compile_s"], r["tracing_s"], r["train_steps_per_s"]]
            )
    header = [
        "env (PPO)",
        "launch",
        "first progress line, s",
        "chunk compile, s",
        "of it tracing, s",
        "env steps/s",
    ]
    return table(header, rows, align="llrrrr") + source("first_minute")


def sb3_block() -> str:
    record = load("sb3_compare")
    rows = []
    for env, summary in record["summary"].items():
        for learner, r in summary["learners"].items():
            reach = "not reached" if r["seconds_to_target"] is None else f"{r['seconds_to_target']:.0f}"
            last = f"{r['last_return']:.0f} ± {r['last_std']:.0f}"
            rows.append([env, LABELS[learner], r["env_steps"], last, round(r["best_return"]),
                         round(summary["target"]), reach])  # fmt: skip
    header = ["env (Gymnasium v5)", "learner", "env steps", f"return at {record['seconds']:g} s",
              "best snapshot", "target", "s to the target"]  # fmt: skip
    return table(header, rows, align="llrrrrr") + source("sb3_compare")


def robot_speed(rows: list[dict]) -> tuple[int, float, float]:
    timed = [r for r in rows if r.get("fastrl_sps") and r.get("mujoco_sps")]
    ratios = [r["fastrl_sps"] / r["mujoco_sps"] for r in timed]
    return len(timed), min(ratios), max(ratios)


def robot_block() -> str:
    record = load("robot_coverage")
    s = record["summary"]
    timed, low, high = robot_speed(record["rows"])
    rows = [
        ["load (`fastrl.physics.load_mjcf`)", f"{s['loads']} of {s['scenes']}"],
        [
            "track MuJoCo C within 1e-4 over 2 s (float64), solver as written",
            f"{s['tracks']['default']} of {s['scenes']}",
        ],
        ["... with both solvers converged", f"{s['tracks']['converged']} of {s['scenes']}"],
        ["stay finite over 1000 random-control steps", f"{s['random_finite']} of {s['scenes']}"],
        ["float32 free root within 1 cm of MuJoCo C", f"{s['root_f32_within_1cm']} of {s['with_root']}"],
        [
            "batch-1024 speed against `mujoco.rollout` (2 threads)",
            f"{timed} timed: {number(low, 2)}x to {number(high, 2)}x",
        ],
    ]
    return table(["MuJoCo Menagerie and Playground scenes", "count"], rows) + source("robot_coverage")


def speed_accuracy_rows() -> list[list]:
    """Per model: fastrl's shipped setting, and MuJoCo C's fastest setting at equal or lower error."""
    record = load("speed_accuracy")
    out = []
    for name, model in record["models"].items():
        shipped = next(r for r in model["rows"] if r["shipped"])
        peers = [
            r
            for r in model["rows"]
            if r["engine"] == "MuJoCo C" and r["error"] is not None and r["error"] <= shipped["error"]
        ]
        peer = max(peers, key=lambda r: r["control_steps_per_s"]) if peers else None
        setting = f"{shipped['integrator']} x{shipped['substeps']}, {shipped['solver_iterations']} iters"
        out.append(
            [
                name,
                setting,
                shipped["error"],
                shipped["control_steps_per_s"],
                peer["control_steps_per_s"] if peer else None,
                ratio(shipped["control_steps_per_s"], peer["control_steps_per_s"] if peer else None),
            ]
        )
    return out


def speed_accuracy_block() -> str:
    header = [
        "model",
        "fastrl's shipped setting",
        "its error, m",
        "control steps/s",
        "MuJoCo C at equal or lower error",
        "ratio",
    ]
    body = table(header, speed_accuracy_rows(), align="llrrrr")
    return body + source("speed_accuracy")


def reference_block() -> str:
    record = load("reference_scores")
    rows = []
    for r in record["rows"]:
        cell = lambda side: f"{side['mean']:.0f} ± {side['std']:.0f}"  # noqa: E731
        rows.append([r["run"], r["env_steps"], cell(r["fastrl"]), cell(r["reference"]), r["episodes"]])
    header = [
        "run",
        "env steps",
        "fastrl's evaluation (training physics)",
        "Gymnasium v5 (MuJoCo C)",
        "episodes",
    ]
    return table(header, rows, align="lrllr") + source("reference_scores")


def scale_block() -> str:
    rows = []
    for env in ("ant", "inverted_pendulum"):
        record = load(f"scale_throughput_{env}")
        runs = record["runs"]
        one = runs["one run, 1 device"]["env_steps_per_s"]
        for name, run in runs.items():
            if name != "one run, 1 device" and "seed 1" not in name:
                rows.append([env, name, run["env_steps_per_s"], ratio(run["env_steps_per_s"], one)])
    header = ["env (PPO)", "layout", "env steps/s (all agents)", "vs one run, 1 device"]
    return (
        table(header, rows)
        + "\n\n"
        + ", ".join(link(f"scale_throughput_{e}") for e in ("ant", "inverted_pendulum"))
    )


def _speed_rows() -> list[tuple[str, str, str, str]]:
    """Headline rows on speed: (measure, peer, fastrl's ratio, record stem)."""
    physics = {r[0]: r for r in physics_throughput()}
    best = contacts_best()
    envpool = next(r for e, r in best.items() if e.startswith("EnvPool"))["control_steps_per_s"]
    train = best["fastrl euler 0.01x5, 5 iters, 2 devices"]["control_steps_per_s"]
    rk4 = best["fastrl rk4 0.01x5, 7 iters, 2 devices"]["control_steps_per_s"]
    vec = max(load("env_throughput_ant")["vector"], key=lambda v: v["num_envs"])
    sync = vec["gymnasium_sync_steps_per_s"]
    vec_rk4 = ratio(vec["fastrl_make_vec_2_devices_steps_per_s"], sync)
    vec_train = ratio(vec["fastrl_make_vec_training_settings_2_devices_steps_per_s"], sync)
    humanoid = {r[0]: r for r in speed_accuracy_rows()}["humanoid"][5]
    timed, low, high = robot_speed(load("robot_coverage")["rows"])
    return [
        ("Smooth dynamics, Ant-like model, Euler / RK4", "MuJoCo C `rollout`, 2 threads",
         f"{physics['euler'][4]} / {physics['rk4'][4]}", "physics_throughput"),
        ("Ant with contacts, 2 CPU devices: training settings / Gymnasium's RK4", "EnvPool Ant-v4, 2 threads",
         f"{ratio(train, envpool)} / {ratio(rk4, envpool)}", "contacts_throughput"),
        ("`make_vec('ant')`, 1024 envs, 2 devices: RK4 / training settings", "Gymnasium `SyncVectorEnv`",
         f"{vec_rk4} / {vec_train}", "env_throughput_ant"),
        ("Humanoid at its training setting, equal or lower error", "MuJoCo C", humanoid, "speed_accuracy"),
        (f"Robot scenes at batch 1024 ({timed} timed)", "MuJoCo C `rollout`, 2 threads",
         f"{number(low, 2)}x to {number(high, 2)}x", "robot_coverage"),
        robot_tasks_row(),
        robot_ports_row(),
    ]  # fmt: skip


def robot_tasks_row() -> tuple[str, str, str, str]:
    """The robot tasks' full env step on one device against MuJoCo C's physics-only rollout."""
    rows = load("robot_throughput")["rows"]
    ratios = {r["env"]: r["control_steps_per_s"] / r["mujoco_rollout"]["control_steps_per_s"] for r in rows}
    names = " / ".join(sorted(ratios))
    return (
        f"Robot tasks, full env step at batch 1024, 1 device: {names}",
        "MuJoCo C `rollout` (physics only), 2 threads",
        " / ".join(f"{number(ratios[k], 2)}x" for k in sorted(ratios)),
        "robot_throughput",
    )


def robot_ports_row() -> tuple[str, str, str, str]:
    """The robot tasks' full env step, the better of 1 and 2 devices, against EnvPool's C++ ports
    of the same tasks (rows measured without EnvPool are left out)."""
    rows = [r for r in load("robot_throughput")["rows"] if r.get("envpool_port")]
    two = lambda r: (r.get("split_2_devices") or {}).get("control_steps_per_s", 0)  # noqa: E731
    best = {r["env"]: max(r["control_steps_per_s"], two(r)) for r in rows}
    ratios = {r["env"]: best[r["env"]] / r["envpool_port"]["control_steps_per_s"] for r in rows}
    return (
        "Robot tasks, full env step, the better of 1 and 2 devices: " + " / ".join(sorted(ratios)),
        "EnvPool's C++ ports of the same tasks, 2 threads",
        " / ".join(f"{number(ratios[k], 2)}x" for k in sorted(ratios)),
        "robot_throughput",
    )


def robot_tasks_block() -> str:
    """The robot tasks' full env step on 1 and 2 devices beside EnvPool's C++ ports and MuJoCo C's
    physics-only rollout, from one run of ``experiments.robot_throughput``."""
    rows = []
    for r in sorted(load("robot_throughput")["rows"], key=lambda r: r["env"]):
        two = (r.get("split_2_devices") or {}).get("control_steps_per_s")
        port = (r.get("envpool_port") or {}).get("control_steps_per_s")
        best = max(r["control_steps_per_s"], two or 0)
        rollout = r["mujoco_rollout"]["control_steps_per_s"]
        rows.append([r["env"], r["control_steps_per_s"], two or "–", port or "–", ratio(best, port),
                     rollout, ratio(best, rollout), f"{r['compile_s']:.0f}"])  # fmt: skip
    header = ["env", "fastrl, 1 device", "fastrl, 2 devices", "EnvPool's C++ port, 2 threads",
              "best / EnvPool", "MuJoCo C rollout (physics only), 2 threads", "best / MuJoCo C",
              "compile s"]  # fmt: skip
    return table(header, rows) + source("robot_throughput")


def _learning_rows() -> list[tuple[str, str, str, str]]:
    """Headline rows on learning: (measure, peer, fastrl's result, record stem)."""
    ttr = {t: time_to_return(t) for t in ("inverted_pendulum", "halfcheetah_sac", "hopper_sac", "ant")}
    scores = load("reference_scores")["rows"]
    ant_ref = next(r for r in scores if r["run"].startswith("ant /"))
    humanoid = sorted((r for r in scores if r["run"].startswith("humanoid / ppo")), key=lambda r: r["run"])
    humanoid_scores = [r["reference"]["mean"] for r in humanoid]
    launch = load("first_minute")["results"]["ant"]
    sb3 = load("sb3_compare")
    times = {env: time_ratio(summary) for env, summary in sb3["summary"].items()}
    return [
        (f"Time to the same return within {sb3['seconds']:g} s, PPO: " + " / ".join(times),
         "SB3 PPO or SAC (PyTorch) on Gymnasium's envs",
         " / ".join("–" if r is None else f"{r:.2f}x" for r in times.values()), "sb3_compare"),
        ("Time to return: PPO inverted_pendulum, SAC halfcheetah / hopper", "Brax's own trainers",
         f"{ttr['inverted_pendulum']['ratio']}, {ttr['halfcheetah_sac']['ratio']} / "
         f"{ttr['hopper_sac']['ratio']}", "time_to_return_inverted_pendulum"),
        ("Time to return 3000: PPO Ant", "Brax PPO, spring Ant",
         f"Brax {ttr['ant']['brax']['median_s']:.0f} s; fastrl {_seconds(ttr['ant']['fastrl'])}",
         "time_to_return_ant"),
        ("Default Ant PPO run, final policy scored in Gymnasium's Ant-v5", "MuJoCo C",
         f"{ant_ref['reference']['mean']:.0f} ± {ant_ref['reference']['std']:.0f}", "reference_scores"),
        (f"Default Humanoid PPO run, final policy scored in Gymnasium's Humanoid-v5: median of "
         f"{len(humanoid)} seeds", "MuJoCo C",
         f"{statistics.median(humanoid_scores):.0f} (seeds: "
         + " / ".join(f"{x:.0f}" for x in humanoid_scores) + ")", "reference_scores"),
        ("Ant PPO launch to first progress line: cold / compile cached", "–",
         f"{launch['cold']['first_line_s']:.0f} s / {launch['cached']['first_line_s']:.0f} s",
         "first_minute"),
    ]  # fmt: skip


def headline_block() -> str:
    rows = []
    for measure, peer, value, stem in _speed_rows() + _learning_rows():
        rows.append([measure, peer, value, link(stem), date(load(stem))])
    header = ["measure", "peer, same machine and run", "fastrl (ratio: fastrl / peer)", "record", "run"]
    return table(header, rows)


BLOCKS: dict[str, Callable[[], str]] = {
    "headline": headline_block,
    "physics": physics_block,
    "contacts": contacts_block,
    "envs": env_block,
    "vector": vector_block,
    "time_to_return": time_to_return_block,
    "first_minute": first_minute_block,
    "sb3": sb3_block,
    "robots": robot_block,
    "robot_tasks": robot_tasks_block,
    "speed_accuracy": speed_accuracy_block,
    "reference_scores": reference_block,
    "scale": scale_block,
}


# --------------------------------------------------------------------------- rendering


def render(text: str, page: Path) -> str:
    """``text`` with every generated block rebuilt; links made relative to ``page``'s folder."""
    prefix = "../" if page.parent != results.ROOT else ""

    def fill(match: re.Match) -> str:
        name = match.group(2)
        if name not in BLOCKS:
            raise KeyError(f"{page}: unknown results block {name!r} (known: {', '.join(BLOCKS)})")
        body = BLOCKS[name]().replace("](experiments/", f"]({prefix}experiments/")
        return f"{match.group(1)}{body}\n{match.group(4)}"

    return BLOCK.sub(fill, text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--check", action="store_true", help="change nothing; exit 1 if a block is stale")
    args = parser.parse_args(argv)
    stale = []
    for page in PAGES:
        text = page.read_text()
        new = render(text, page)
        if new != text:
            stale.append(
                page.relative_to(results.ROOT).as_posix() if page.is_relative_to(results.ROOT) else str(page)
            )
            if not args.check:
                page.write_text(new)
    if args.check and stale:
        print(
            "stale generated blocks (run `python -m experiments.docs`): " + ", ".join(stale), file=sys.stderr
        )
        return 1
    print(("rebuilt: " + ", ".join(stale)) if stale and not args.check else "generated blocks are current")
    return 0


if __name__ == "__main__":
    sys.exit(main())
