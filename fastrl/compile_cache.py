"""JAX's persistent compilation cache, as the command line uses it.

A second launch of the same run (same program, same XLA flags, same JAX) reads its compiled
chunk from disk instead of compiling it again. The command-line entry points (``fastrl.train``,
``fastrl.evaluate``) turn it on; importing fastrl as a library changes nothing, and a library
user opts in with ``fastrl.compile_cache.enable()``.

Where: ``$FASTRL_COMPILE_CACHE`` if set (an empty value turns the cache off), else
``$XDG_CACHE_HOME/fastrl/jax`` (``~/.cache/fastrl/jax``). The cache is bounded
(``MAX_BYTES``, least recently used entries evicted) and its reads and writes hold a file lock,
so runs started together share it safely.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

import jax

ENV_VAR = "FASTRL_COMPILE_CACHE"
MAX_BYTES = 4 * 1024**3
# Programs that compile faster than this are not worth a disk entry (evaluation helpers, resets).
MIN_COMPILE_SECS = 1.0


def default_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "fastrl" / "jax"


def enable(path: str | os.PathLike | None = None) -> Path | None:
    """Turns the persistent cache on at ``path`` (default: ``$FASTRL_COMPILE_CACHE``, else
    ``default_dir()``); returns the folder, or None when ``FASTRL_COMPILE_CACHE`` is empty."""
    if path is None:
        value = os.environ.get(ENV_VAR)
        if value is not None and not value.strip():
            return None
        path = value or default_dir()
    path = Path(path).expanduser().absolute()
    path.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECS)
    jax.config.update("jax_compilation_cache_max_size", MAX_BYTES)
    return path


class _Counts:
    """Persistent-cache hits and misses, counted from JAX's monitoring events."""

    def __init__(self):
        self.hits = self.misses = 0
        self._lock = threading.Lock()

    def __call__(self, event: str, **kwargs) -> None:
        if event == "/jax/compilation_cache/cache_hits":
            with self._lock:
                self.hits += 1
        elif event == "/jax/compilation_cache/cache_misses":
            with self._lock:
                self.misses += 1


_COUNTS: _Counts | None = None


def counts() -> tuple[int, int]:
    """(hits, misses) of the persistent cache in this process since the first call."""
    global _COUNTS
    if _COUNTS is None:
        _COUNTS = _Counts()
        jax.monitoring.register_event_listener(_COUNTS)
    return _COUNTS.hits, _COUNTS.misses


def describe(before: tuple[int, int], enabled: bool) -> str:
    """How a compile that started at ``before = counts()`` went, for the run's first line."""
    if not enabled:
        return "compilation cache off"
    hits, misses = (now - then for now, then in zip(counts(), before, strict=True))
    if hits and not misses:
        return "compilation cache hit"
    return "compilation cache miss" if misses else "not cached"


def is_enabled() -> bool:
    return bool(jax.config.jax_compilation_cache_dir)
