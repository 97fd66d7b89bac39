"""A run's learning curve: ``metrics.csv`` read back, and ``curve.png`` drawn from it.

The curve callback draws each run's curve at its end; ``fastrl.report`` reads the same files for its
summaries. Figures are written whole or not at all, never through a link in the run folder.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from fastrl.training.files import write_bytes

__all__ = ["plot_run", "read_metrics", "save_png"]


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


def save_png(fig, path: str | Path) -> None:
    """Writes the figure whole or not at all (a full disk leaves the previous PNG, not 0 bytes),
    never through a link in the folder."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    write_bytes(path, buf.getvalue())


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
    save_png(fig, png_path)
    plt.close(fig)
