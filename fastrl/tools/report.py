"""Learning curves and summaries of run folders.

    python -m fastrl.report DIR      # a run, a multirun folder, or any folder of runs

Finds every run folder under DIR (a folder with ``config.json`` and ``metrics.csv``), groups the
runs by configuration (everything but the seed and the output settings), and prints a table of
final and best evaluation returns as mean +- std over seeds; writes ``DIR/report.md`` and
``DIR/report.png`` (mean curve per configuration with the seeds' spread shaded).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import NoReturn

import numpy as np

from fastrl.tools.curve import read_metrics, save_png

_IGNORED = ("seed", "logger", "checkpoint")


def _flatten(d: dict, prefix: str = "") -> dict[str, object]:
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


def find_runs(root: str | Path) -> list[Path]:
    """Run folders under ``root`` (itself included)."""
    root = Path(root)
    return sorted(p.parent for p in root.rglob("config.json") if (p.parent / "metrics.csv").exists())


def summarize(root: str | Path) -> list[dict]:
    """One row per configuration: its label, seeds, and final/best eval return mean and std."""
    groups: dict[str, list[tuple[int, dict]]] = {}
    configs = {}
    for run in find_runs(root):
        cfg = json.loads((run / "config.json").read_text())
        flat = {k: v for k, v in _flatten(cfg).items() if k.split(".")[0] not in _IGNORED}
        key = json.dumps(flat, sort_keys=True, default=str)
        configs[key] = flat
        groups.setdefault(key, []).append((int(cfg.get("seed", 0)), read_metrics(run / "metrics.csv")))
    # Label each group by the settings that differ between groups.
    keys = list(groups)
    varying = sorted(
        {k for a in keys for k, v in configs[a].items() if any(configs[b].get(k) != v for b in keys)}
    )
    rows = []
    for key in keys:
        cfg = configs[key]
        label = (
            ", ".join(f"{k}={cfg.get(k)}" for k in varying) or f"{cfg.get('env.name')}/{cfg.get('algo.name')}"
        )
        finals, bests = [], []
        for _, m in groups[key]:
            ret = m.get("eval/episode_return")
            if ret is not None and np.isfinite(ret).any():
                finals.append(ret[np.isfinite(ret)][-1])
                bests.append(np.nanmax(ret))
        stat = lambda f, xs: float(f(xs)) if xs else float("nan")  # noqa: E731
        rows.append({
            "label": label, "seeds": sorted(s for s, _ in groups[key]), "runs": groups[key],
            "final_mean": stat(np.mean, finals), "final_std": stat(np.std, finals),
            "best_mean": stat(np.mean, bests), "best_std": stat(np.std, bests),
        })  # fmt: skip
    return rows


def plot_groups(rows: list[dict], png_path: str | Path) -> None:
    """Mean eval return vs env steps per configuration, seeds' min-max shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2), constrained_layout=True)
    for row in rows:
        curves = [
            (m["env_steps"], m["eval/episode_return"]) for _, m in row["runs"] if "eval/episode_return" in m
        ]
        if not curves:
            continue
        n = min(len(x) for x, _ in curves)
        x = curves[0][0][:n]
        y = np.stack([c[1][:n] for c in curves])
        (line,) = ax.plot(x, np.nanmean(y, 0), label=f"{row['label']} ({len(curves)} seeds)")
        ax.fill_between(x, np.nanmin(y, 0), np.nanmax(y, 0), color=line.get_color(), alpha=0.2)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("eval episode return")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    save_png(fig, png_path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> NoReturn:
    """The command (``python -m fastrl.report DIR``): exits with ``run``'s status."""
    sys.exit(run(argv))


def run(argv: list[str] | None = None) -> int:
    """Summarises the runs under a folder as the command line asks; returns the exit status (2: no
    run folders)."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("dir", help="a run folder, a multirun folder, or any folder of runs")
    args = parser.parse_args(argv)
    rows = summarize(args.dir)
    if not rows:
        print(f"[fastrl] no run folders (config.json + metrics.csv) under {args.dir}", file=sys.stderr)
        return 2
    lines = ["| configuration | seeds | final return | best return |", "| --- | --- | ---: | ---: |"]
    for r in rows:
        lines.append(f"| {r['label']} | {','.join(map(str, r['seeds']))} | {r['final_mean']:.1f} +- "
                     f"{r['final_std']:.1f} | {r['best_mean']:.1f} +- {r['best_std']:.1f} |")  # fmt: skip
    text = "\n".join(lines)
    print(text)
    Path(args.dir, "report.md").write_text(text + "\n")
    plot_groups(rows, Path(args.dir, "report.png"))
    return 0
