"""What every experiment writes, written one way: markdown tables, the JSON record, the figure.

An experiment computes rows, then calls :func:`save` with a stem: ``<stem>.json`` (the record,
with :func:`machine`'s description of where it ran and the command that made it),
``<stem>.md`` (its page) and, given a figure, ``<stem>.png``. :func:`load` reads a record back
(``--merge`` and ``--from-json`` modes, and ``python -m experiments.docs``).
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import shlex
import subprocess
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import fastrl

ROOT = Path(__file__).resolve().parents[1]
RESULTS = Path(__file__).resolve().parent / "results"


def machine() -> str:
    """Where this process runs: CPU, cores, memory, the library versions and (once JAX is imported)
    its devices, e.g. ``x86_64, 2 cores, 24 GiB, jax 0.10.2, mujoco 4.0.0, 1 cpu device``."""
    cpu = platform.processor() or platform.machine()
    try:
        pages, page_size = os.sysconf("SC_PHYS_PAGES"), os.sysconf("SC_PAGE_SIZE")
        memory = f", {pages * page_size / 2**30:.0f} GiB"
    except (ValueError, OSError, AttributeError):
        memory = ""
    parts = [f"{cpu}, {os.cpu_count()} cores{memory}"]
    for name in ("jax", "mujoco"):
        module = sys.modules.get(name)
        if module is not None:
            parts.append(f"{name} {module.__version__}")
    jax = sys.modules.get("jax")
    if jax is not None:
        count = jax.device_count()
        parts.append(f"{count} {jax.default_backend()} device{'s' if count > 1 else ''}")
    return ", ".join(parts)


def command(argv: Sequence[str] | None = None) -> str:
    """The command line that ran this experiment, as ``python -m experiments.<name> ...``."""
    argv = list(sys.argv if argv is None else argv)
    script = Path(argv[0])
    head = f"python -m experiments.{script.stem}" if script.suffix == ".py" else shlex.quote(argv[0])
    return " ".join([head, *map(shlex.quote, argv[1:])])


def today() -> str:
    return datetime.date.today().isoformat()


def number(value: Any, digits: int = 3) -> str:
    """A table cell: integers with thousands separators, floats to ``digits`` significant
    figures (scientific below 1e-3), None and NaN as an en dash, anything else as ``str``."""
    if value is None or (isinstance(value, float) and value != value):
        return "–"
    if isinstance(value, bool) or not isinstance(value, int | float):
        return str(value)
    if isinstance(value, int) or (abs(value) >= 1000 and float(value).is_integer()):
        return f"{int(value):,}"
    if value != 0 and abs(value) < 1e-3:
        return f"{value:.{max(digits - 1, 0)}e}"
    if abs(value) >= 10**digits:
        return f"{value:,.0f}"
    return f"{value:.{digits}g}"


def table(header: Sequence[str], rows: Iterable[Sequence[Any]], align: str | None = None) -> str:
    """A markdown table. ``align`` has one letter per column, ``l`` or ``r`` (default: text
    columns left, columns whose first cell is a number right); cells go through :func:`number`."""
    rows = [list(r) for r in rows]
    if align is None:
        first = rows[0] if rows else [""] * len(header)
        align = "".join("r" if isinstance(c, int | float) and not isinstance(c, bool) else "l" for c in first)
    if len(align) != len(header) or any(len(r) != len(header) for r in rows):
        raise ValueError(f"table: {len(header)} columns in the header, rows or align differ")
    rule = ["---:" if a == "r" else "---" for a in align]
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join(rule) + " |"]
    lines += ["| " + " | ".join(number(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def pyplot():
    """matplotlib's pyplot on the file-only Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(
    out: Path | str, stem: str, record: Any, markdown: str | None = None, figure=None, *, dpi: int = 110
) -> list[Path]:
    """Writes ``out/<stem>.json`` (``record``), ``out/<stem>.md`` and ``out/<stem>.png`` (a
    matplotlib figure at ``dpi``, then closed), those given (``record=None``: no JSON, for a page
    re-rendered from a record kept elsewhere); returns the paths written. A record that is a
    dict and names no ``date`` (nor ``meta.date``) gets today's, which the docs show beside it."""
    out = Path(out)
    if isinstance(record, dict) and not (record.get("date") or (record.get("meta") or {}).get("date")):
        record = {**record, "date": today()}
    out.mkdir(parents=True, exist_ok=True)
    written = []
    if record is not None:
        written.append(out / f"{stem}.json")
        written[-1].write_text(json.dumps(record, indent=1) + "\n")
    if markdown is not None:
        written.append(out / f"{stem}.md")
        written[-1].write_text(markdown.rstrip("\n") + "\n")
    if figure is not None:
        written.append(out / f"{stem}.png")
        figure.savefig(written[-1], dpi=dpi)
        pyplot().close(figure)
    return written


def load(stem_or_path: Path | str, out: Path | str = RESULTS) -> Any:
    """A saved record: ``load("robot_coverage")`` reads ``experiments/results/robot_coverage.json``;
    a path ending in ``.json`` is read as it is."""
    path = Path(stem_or_path)
    if path.suffix != ".json":
        path = Path(out) / f"{stem_or_path}.json"
    return json.loads(path.read_text())


def fastrl_version() -> str:
    """The git commit of the imported fastrl, marked dirty if its files differ from it."""
    where = Path(fastrl.__file__).resolve().parent
    git = ["git", "-C", str(where)]
    try:
        head = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
        dirty = subprocess.run([*git, "status", "--porcelain", "--", "."], capture_output=True, text=True)
    except OSError:
        return str(where)
    if head.returncode:
        return f"from {where} (not a git checkout)"
    return head.stdout.strip() + (" with uncommitted changes in fastrl/" if dirty.stdout.strip() else "")
