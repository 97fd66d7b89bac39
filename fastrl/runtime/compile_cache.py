"""JAX's persistent compilation cache, as the command line uses it.

A second launch of the same run (same program, same XLA flags, same JAX) reads its compiled
chunk from disk instead of compiling it again. The command-line entry points (``fastrl.train``,
``fastrl.evaluate``) turn it on; importing fastrl as a library changes nothing, and a library
user opts in with ``fastrl.runtime.compile_cache.enable()``.

Where: ``$FASTRL_COMPILE_CACHE`` if set (an empty value turns the cache off), else
``$XDG_CACHE_HOME/fastrl/jax`` (``~/.cache/fastrl/jax``). The cache is bounded
(``MAX_BYTES``, least recently used entries evicted) and its reads and writes hold a file lock,
so runs started together share it safely.

JAX's cache still traces the program to find its entry (seconds for a chunk of physics and
learning). ``exported`` goes one step further for the training chunk: the traced program itself
(``jax.export``'s serialised StableHLO) is kept beside JAX's entries (``*.exported``, the newest
``MAX_PROGRAMS``), under a key that covers everything the program is made of (the run's
configuration, the model's arrays, the state's shapes and layout, fastrl's source files, the
versions of JAX and the libraries that build the program, the devices and XLA flags), so an
identical launch reads it instead of tracing, and JAX's cache then holds its compiled form. A
changed source file or configuration is a different key; an entry that cannot be read (another
JAX) is traced again. (XLA:CPU's own serialised executables could skip the compile too, but
one of fastrl's chunks, reloaded, failed to find its kernels: "Function iota_convert_fusion not
found".)
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import os
import re
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np

ENV_VAR = "FASTRL_COMPILE_CACHE"
MAX_BYTES = 4 * 1024**3
# Programs that compile faster than this are not worth a disk entry (evaluation helpers, resets).
MIN_COMPILE_SECS = 1.0
MAX_PROGRAMS = 32
_SUFFIX = ".exported"
# what else shapes a traced program, besides the arguments of ``program_key``
_LIBRARIES = ("jax", "jaxlib", "flax", "optax", "numpy", "mujoco")
# memory addresses in reprs (a static field holding a function): the same program every launch
_ADDRESS = re.compile(r" at 0x[0-9a-f]+")


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
    """Persistent-cache hits and misses per thread, counted from JAX's monitoring events (JAX
    reports them on the thread that compiles, so a compile on a worker thread is told apart
    from those the main thread runs meanwhile)."""

    def __init__(self):
        self.by_thread: dict[int, list[int]] = {}
        self._lock = threading.Lock()

    _INDEX = {"/jax/compilation_cache/cache_hits": 0, "/jax/compilation_cache/cache_misses": 1}

    def __call__(self, event: str, **kwargs) -> None:
        which = self._INDEX.get(event)
        if which is not None:
            with self._lock:
                self.by_thread.setdefault(threading.get_ident(), [0, 0])[which] += 1

    def of_this_thread(self) -> tuple[int, int]:
        with self._lock:
            hits, misses = self.by_thread.get(threading.get_ident(), (0, 0))
        return hits, misses


_COUNTS: _Counts | None = None


def counts() -> tuple[int, int]:
    """(hits, misses) of the persistent cache on the calling thread since the first call."""
    global _COUNTS
    if _COUNTS is None:
        _COUNTS = _Counts()
        jax.monitoring.register_event_listener(_COUNTS)
    return _COUNTS.of_this_thread()


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


@functools.cache
def _code_digest() -> str:
    """A digest of every file of the fastrl package (source and assets)."""
    root, h = Path(__file__).resolve().parents[1], hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _version(name: str) -> str:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return "-"


def program_key(values, shaped) -> str:
    """The key of a kept traced program built from ``values`` (pytrees of arrays and plain
    values, by content: the configuration, the model) taking arguments like ``shaped`` (by
    structure, shape, dtype and layout: the state), with fastrl's source, the library versions,
    the devices, XLA's flags and JAX's numeric settings."""
    h = hashlib.sha256()
    for tree, by_content in ((values, True), (shaped, False)):
        leaves, treedef = jax.tree.flatten(tree)
        h.update(_ADDRESS.sub("", str(treedef)).encode())
        for x in leaves:
            if not isinstance(x, jax.Array | np.ndarray | np.generic):
                h.update(_ADDRESS.sub("", repr(x)).encode())
                continue
            h.update(f"{x.shape}{x.dtype}{getattr(x, 'sharding', '')}".encode())
            if by_content:
                h.update(np.ascontiguousarray(np.asarray(x)).tobytes())
    h.update(_code_digest().encode())
    h.update(repr([(n, _version(n)) for n in _LIBRARIES]).encode())
    h.update(repr([(d.platform, d.device_kind, d.id) for d in jax.devices()]).encode())
    h.update(os.environ.get("XLA_FLAGS", "").encode())
    h.update(repr((jax.config.jax_enable_x64, jax.config.jax_default_matmul_precision)).encode())
    return h.hexdigest()[:32]


def exported(key: str, export: Callable[[], jax.export.Exported]) -> tuple[jax.export.Exported, bool]:
    """The program under ``key`` as a ``jax.export.Exported`` (its StableHLO): read from the cache
    folder if it holds it (no tracing), else ``export()`` (which traces), then kept. Returns it
    and whether it was read. Compiling it (``jax.jit(exported.call)``) then goes through JAX's
    persistent cache."""
    path = Path(jax.config.jax_compilation_cache_dir) / f"{key}{_SUFFIX}"
    try:
        program = jax.export.deserialize(bytearray(path.read_bytes()))
        os.utime(path)  # recently used
        return program, True
    except FileNotFoundError:
        pass
    except Exception:  # noqa: BLE001  (written by another JAX, or cut short): exported anew
        path.unlink(missing_ok=True)
    program = export()
    with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".tmp", delete=False) as f:
        f.write(program.serialize())
    os.replace(f.name, path)  # whole or not at all
    entries = sorted(path.parent.glob(f"*{_SUFFIX}"), key=_mtime, reverse=True)
    for old in entries[MAX_PROGRAMS:]:
        old.unlink(missing_ok=True)
    return program, False


def _mtime(path: Path) -> float:
    try:
        return path.stat().st_mtime
    except FileNotFoundError:  # another run evicted it meanwhile
        return 0.0
