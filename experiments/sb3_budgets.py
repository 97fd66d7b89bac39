"""The best policy by the time you come back: fastrl's learners against Stable-Baselines3's at
5, 15 and 30 minutes of wall time, over seeds, all scored in Gymnasium.

    python -m experiments.sb3_budgets                      # 5 envs x 5 learners x 3 seeds x 31 min
    python -m experiments.sb3_budgets --envs hopper --learners fastrl_sac sb3_ppo --seeds 0
    python -m experiments.sb3_budgets --quick --out DIR    # hopper, a 40 s budget, for CI
    python -m experiments.sb3_budgets --from-json experiments/results/sb3_budgets.json

A user with a CPU asks which tool gives the best policy within the time they can wait. Each
learner trains one run per env and seed, from launching its process (imports and compiles
inside the clock), for the largest budget plus one snapshot interval, and saves a snapshot every
``--every`` seconds:

* fastrl's learners (``fastrl_ppo``, ``fastrl_sac``, ``fastrl_fasttd3``): ``python -m
  fastrl.train`` with the shipped ``experiment/<env>_<algo>`` settings (where one exists; the
  learner's defaults otherwise), its checkpoints the snapshots;
* SB3's PPO and SAC with the RL Baselines3 Zoo's settings (``experiments/sb3_compare.py`` runs
  both sides the same way; see there).

Every snapshot is scored in Gymnasium's own ``<Env>-v5`` (MuJoCo C), ``--episodes`` episodes of
the deterministic policy. A learner's return at a budget is its last snapshot saved at or before
that many seconds from launch; per learner the median over seeds. At each budget the best
fastrl learner meets the best SB3 learner. The target is the best SB3 learner's median return
at the largest budget; each fastrl learner's time to it is, per seed, the first snapshot from
which every later one scores at least the target (the median over seeds; not reached when half
the seeds miss it), and the speed-up is the largest budget over the best of those times.

The record grows by cells (env, learner, seed), saved as each finishes: a command stopped
part-way continues where it stopped, skipping the cells its record holds (``--again`` re-runs
them). The machine's 2 cores serve one learner at a time.

Writes ``experiments/results/sb3_budgets.{json,md,png}`` (another stem with ``--name``; ``_quick``
with ``--quick``).
"""

from __future__ import annotations

import argparse
import pathlib
import tempfile

import numpy as np

from experiments import results, sb3_compare

ENVS = ("halfcheetah", "hopper", "walker2d", "ant", "humanoid")
FASTRL = ("fastrl_ppo", "fastrl_sac", "fastrl_fasttd3")
SB3 = ("sb3_ppo", "sb3_sac")
LEARNERS = FASTRL + SB3
LABELS = {"fastrl_ppo": "fastrl PPO", "fastrl_sac": "fastrl SAC", "fastrl_fasttd3": "fastrl FastTD3",
          "sb3_ppo": "SB3 PPO", "sb3_sac": "SB3 SAC"}  # fmt: skip
COLORS = {"fastrl_ppo": "tab:blue", "fastrl_sac": "tab:purple", "fastrl_fasttd3": "tab:red",
          "sb3_ppo": "tab:orange", "sb3_sac": "tab:green"}  # fmt: skip


# A snapshot due at a budget is saved just after it (SB3 saves at the first step past it): one
# saved within this many seconds after a budget counts for it, on either side.
SLACK = 2.0


def return_at(snaps: list[dict], seconds: float) -> float | None:
    """The mean return of the last snapshot saved by ``seconds`` (None: none was)."""
    before = [s for s in snaps if s["seconds"] <= seconds + SLACK]
    return float(np.mean(before[-1]["returns"])) if before else None


def time_to(snaps: list[dict], target: float, horizon: float) -> float | None:
    """Seconds to the first snapshot (within ``horizon``) from which every later one within it
    scores at least ``target``: a lucky snapshot the learner falls back from does not count."""
    kept = [s for s in snaps if s["seconds"] <= horizon + SLACK]
    means = [float(np.mean(s["returns"])) for s in kept]
    stays = [i for i in range(len(means)) if all(m >= target for m in means[i:])]
    return kept[stays[0]]["seconds"] if stays else None


def median(values: list[float | None], missing: float) -> float | None:
    """The median with ``missing`` standing in for None; None where the median is missing."""
    filled = [missing if v is None else v for v in values]
    m = float(np.median(filled)) if filled else missing
    return None if m == missing or not np.isfinite(m) else m


def _best(medians: dict[str, float | None], names: tuple[str, ...]) -> tuple[str | None, float | None]:
    scored = [(v, k) for k, v in medians.items() if k in names and v is not None]
    return (max(scored)[1], max(scored)[0]) if scored else (None, None)


def summarize(env_runs: dict[str, dict[str, list[dict]]], budgets: list[float]) -> dict:
    """Per budget: each learner's median return over seeds, and the best of each side; then the
    target (SB3's best at the largest budget) and each fastrl learner's median time to it."""
    out: dict = {"budgets": {}}
    for budget in budgets:
        medians = {
            learner: median([return_at(s, budget) for s in seeds.values()], -np.inf)
            for learner, seeds in env_runs.items()
        }
        fastrl, sb3 = _best(medians, FASTRL), _best(medians, SB3)
        out["budgets"][f"{budget:g}"] = {"medians": medians, "fastrl_best": fastrl, "sb3_best": sb3,
                                         "seeds": {k: len(v) for k, v in env_runs.items()}}  # fmt: skip
    last = max(budgets)
    target = out["budgets"][f"{last:g}"]["sb3_best"][1]
    times = {}
    for learner, seeds in env_runs.items():
        if learner in FASTRL and target is not None:
            times[learner] = median([time_to(s, target, last) for s in seeds.values()], np.inf)
    reached = [t for t in times.values() if t is not None]
    out.update(target=target, times=times, speedup=last / min(reached) if reached else None)
    return out


def _cell(value: float | None) -> str:
    return "–" if value is None else f"{value:.0f}"


def render(result: dict) -> str:
    """The markdown page of ``result``."""
    budgets = result["budgets"]
    minutes = ", ".join(f"{b / 60:g}" for b in budgets)
    lines = [f"# fastrl's learners against Stable-Baselines3's at {minutes} minutes", "",
             f"Machine: {result['machine']}. Command: `{result['command']}`. fastrl {result['fastrl']}, "
             f"{result['sb3_versions']}.", "",
             "Each learner trains from launching its process (start-up and compiles included), one at a "
             f"time, with a snapshot every {result['every']:g} s; every snapshot is scored in "
             f"Gymnasium's own v5 env (MuJoCo C), {result['episodes']} episodes of the deterministic "
             f"policy. A return at a budget is the last snapshot saved by then ({SLACK:g} s of slack for "
             "the save itself), the median over seeds. "
             "The cells' own runs are listed at the end.",
             "", "## Best learner of each side", "",
             "| env | budget | fastrl's best | SB3's best | fastrl − SB3 |",
             "| --- | ---: | --- | --- | ---: |"]  # fmt: skip
    for env, summary in result["summary"].items():
        for budget, row in summary["budgets"].items():
            (fl, fv), (sl, sv) = row["fastrl_best"], row["sb3_best"]
            gap = "–" if fv is None or sv is None else f"{fv - sv:+.0f}"
            lines.append(f"| {env} | {float(budget) / 60:g} min | {_cell(fv)} ({LABELS.get(fl, '–')}) | "
                         f"{_cell(sv)} ({LABELS.get(sl, '–')}) | {gap} |")  # fmt: skip
    lines += ["", f"## Time to SB3's best {budgets[-1] / 60:g}-minute return", "",
              "| env | target | " + " | ".join(LABELS[k] for k in FASTRL) + " | speed-up |",
              "| --- | ---: | " + " | ".join("---:" for _ in FASTRL) + " | ---: |"]  # fmt: skip
    for env, summary in result["summary"].items():
        times = [summary["times"].get(k) for k in FASTRL]
        shown = ["–" if k not in summary["times"] else "not reached" if t is None else f"{t:.0f} s"
                 for k, t in zip(FASTRL, times, strict=True)]  # fmt: skip
        speed = "–" if summary["speedup"] is None else f"{summary['speedup']:.1f}x"
        lines.append(f"| {env} | {_cell(summary['target'])} | " + " | ".join(shown) + f" | {speed} |")
    lines += ["", "## Every learner", "", "| env | learner | seeds | "
              + " | ".join(f"{b / 60:g} min" for b in budgets) + " |",
              "| --- | --- | ---: | " + " | ".join("---:" for _ in budgets) + " |"]  # fmt: skip
    for env, summary in result["summary"].items():
        for learner in (k for k in LEARNERS if k in result["runs"][env]):
            seeds = len(result["runs"][env][learner])
            cells = [_cell(summary["budgets"][f"{b:g}"]["medians"][learner]) for b in budgets]
            lines.append(f"| {env} | {LABELS[learner]} | {seeds} | " + " | ".join(cells) + " |")
    lines += ["", "## Runs", "", *(f"- {line}" for line in result["log"])]
    return "\n".join(lines)


def plot(result: dict):
    """Gymnasium return against wall-clock seconds, one panel per env, one line per seed."""
    envs = list(result["runs"])
    fig, axes = sb3_compare.env_panels(envs)
    for ax, env in zip(axes, envs, strict=True):
        for learner, seeds in result["runs"][env].items():
            for i, snaps in enumerate(seeds.values()):
                label = LABELS[learner] if i == 0 else None
                minutes, means = [s["seconds"] / 60 for s in snaps], [np.mean(s["returns"]) for s in snaps]
                ax.plot(minutes, means, color=COLORS[learner], alpha=0.8, lw=1, label=label)
        for budget in result["budgets"]:
            ax.axvline(budget / 60, color="0.8", lw=0.8, zorder=0)
        ax.set_title(env, fontsize=10)
        ax.set_xlabel("wall-clock minutes from launch")
    axes[0].legend(fontsize=7)
    return fig


def run_cell(env: str, learner: str, seed: int, args, work: pathlib.Path) -> list[dict]:
    """One learner's run on one env and seed, its snapshots scored."""
    seconds = max(args.budgets) + args.every
    snapshots = int(round(seconds / args.every))
    if learner in FASTRL:
        algo = learner.removeprefix("fastrl_")
        snaps = sb3_compare.run_fastrl(env, seed, seconds, snapshots, args.quick, work, algo=algo)
        sb3_compare.score_fastrl(snaps, args.episodes, seed)
        for s in snaps:
            s.pop("where")
        return snaps
    algo = learner.removeprefix("sb3_")
    return sb3_compare.run_sb3(algo, env, seed, seconds, snapshots, args.episodes, work)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--envs", nargs="*", choices=ENVS, default=list(ENVS))
    parser.add_argument("--learners", nargs="*", choices=LEARNERS, default=list(LEARNERS))
    parser.add_argument("--seeds", nargs="*", type=int, default=[0, 1, 2])
    parser.add_argument("--budgets", nargs="*", type=float, default=[300.0, 900.0, 1800.0])
    parser.add_argument("--every", type=float, default=60.0, help="seconds between snapshots")
    parser.add_argument("--episodes", type=int, default=10, help="Gymnasium episodes per snapshot")
    parser.add_argument("--quick", action="store_true", help="hopper, seed 0, a 40 s budget, 2 episodes")
    parser.add_argument("--again", action="store_true", help="re-run cells the record already holds")
    parser.add_argument("--out", default=str(results.RESULTS))
    parser.add_argument("--name", default="sb3_budgets", help="the record's file stem")
    parser.add_argument("--from-json", help="re-summarise a saved record instead of training")
    args = parser.parse_args(argv)
    if args.quick:
        args.envs, args.seeds, args.budgets, args.every, args.episodes = ["hopper"], [0], [40.0], 10.0, 2
        args.learners = [k for k in args.learners if k in ("fastrl_fasttd3", "sb3_ppo")]
    args.budgets = sorted(args.budgets)
    stem = args.name + ("_quick" if args.quick else "")
    if args.from_json:
        result = results.load(pathlib.Path(args.from_json))
        stem = pathlib.Path(args.from_json).stem
        _save(args.out, stem, result)
        return
    path = pathlib.Path(args.out) / f"{stem}.json"
    result = _start(path, args, argv)
    with tempfile.TemporaryDirectory() as tmp:
        for env in args.envs:
            for learner in args.learners:
                for seed in args.seeds:
                    cells = result["runs"].setdefault(env, {}).setdefault(learner, {})
                    if str(seed) in cells and not args.again:
                        continue
                    print(f"sb3_budgets: {env} {LABELS[learner]} seed {seed}", flush=True)
                    cells[str(seed)] = run_cell(env, learner, seed, args, pathlib.Path(tmp))
                    how = f"{results.today()}, fastrl {results.fastrl_version()}, `{results.command(argv)}`"
                    result["log"].append(f"{env} {learner} seed {seed}: {how}")
                    _save(args.out, stem, result)
    print(render(result))


def _start(path: pathlib.Path, args, argv) -> dict:
    """The record to add cells to: the saved one where its budgets and scoring match, else new."""
    fresh = {"machine": results.machine(), "command": results.command(argv),
             "fastrl": results.fastrl_version(), "sb3_versions": sb3_compare.sb3_versions(),
             "budgets": args.budgets, "every": args.every, "episodes": args.episodes,
             "runs": {}, "log": []}  # fmt: skip
    if not path.exists():
        return fresh
    old = results.load(path)
    for key in ("budgets", "every", "episodes"):
        if old[key] != fresh[key]:
            raise SystemExit(f"{path} has {key}={old[key]}, this command {fresh[key]}: they must match "
                             "(or pass another --out)")  # fmt: skip
    return old


def _save(out, stem: str, result: dict) -> None:
    result["summary"] = {env: summarize(r, result["budgets"]) for env, r in result["runs"].items() if r}
    results.save(out, stem, result, render(result), plot(result))


if __name__ == "__main__":
    main()
