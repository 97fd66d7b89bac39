"""Learning curves from run folders (``metrics.csv``)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np


def read_metrics(path: str | Path) -> dict[str, np.ndarray]:
    """Columns of a ``metrics.csv`` as float arrays (missing cells are NaN)."""
    with Path(path).open() as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return {}
    cols = {}
    for key in rows[0]:
        cols[key] = np.array([float(r[key]) if r.get(key) not in ("", None) else np.nan for r in rows])
    return cols


def plot_run(csv_path: str | Path, png_path: str | Path, title: str = "") -> None:
    """Return vs env steps and vs wall-clock seconds (train and eval), side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m = read_metrics(csv_path)
    if not m:
        return
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), constrained_layout=True)
    for ax, xkey, xlabel in ((axes[0], "env_steps", "environment steps"), (axes[1], "wall_s", "seconds")):
        for key, label in (("train/episode_return", "train"), ("eval/episode_return", "eval")):
            if key in m:
                ok = np.isfinite(m[key])
                ax.plot(m[xkey][ok], m[key][ok], marker=".", label=label)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("episode return")
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle(title)
    fig.savefig(png_path, dpi=110)
    plt.close(fig)
