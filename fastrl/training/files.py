"""The files a run writes into its folder, written so that a run folder cannot reach outside itself.

A run folder may come from someone else (a shared disk, an archive, a colleague's results), so
its contents are untrusted input. fastrl never writes through a symbolic link inside it: a run
refuses to start in a folder that holds one (``refuse_links``), and each file it writes is
created without following links (``O_NOFOLLOW``; a new file also ``O_EXCL``), so a link planted
while the run goes is refused too. The run folder itself may be a link (a run placed on another
disk); links inside it may not. Whole files are written to a fresh temporary beside them and
renamed over the old one, so a crash or a full disk mid-write never leaves half a file in place
of a good one.
"""

from __future__ import annotations

import contextlib
import errno
import os
from pathlib import Path
from typing import IO

__all__ = [
    "RunDirError",
    "WriteError",
    "append_text",
    "open_lock",
    "refuse_links",
    "write_bytes",
    "write_text",
]

_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_CLOEXEC = getattr(os, "O_CLOEXEC", 0)


class RunDirError(RuntimeError):
    """The run folder cannot be used (in use by another run, or it holds a symbolic link); the
    message says why."""


class WriteError(RuntimeError):
    """A run's output could not be written (a full disk, a read-only folder); the message names
    the file, the cause and the last good checkpoint."""


def _link_error(path: Path) -> RunDirError:
    try:
        target = os.readlink(path)
    except OSError:
        target = "?"
    return RunDirError(
        f"{path} is a symbolic link (-> {target}); fastrl does not write through links inside a run "
        "folder, so that a folder from elsewhere cannot make it overwrite other files. Replace the link "
        "with the file or folder itself (the run folder as a whole may be a link)"
    )


def refuse_links(run_dir: Path) -> None:
    """Raises ``RunDirError`` naming the first symbolic link inside ``run_dir`` (not entered)."""
    for root, dirs, names in os.walk(run_dir):  # followlinks=False: a linked folder is not walked
        for name in sorted(dirs + names):
            path = Path(root, name)
            if path.is_symlink():
                raise _link_error(path)


def _refuse_link(path: Path) -> None:
    if path.is_symlink():
        raise _link_error(path)


def _open(path: Path, flags: int, mode: int = 0o644) -> int:
    try:
        return os.open(path, flags | _NOFOLLOW | _CLOEXEC, mode)
    except OSError as e:
        if e.errno == errno.ELOOP or path.is_symlink():
            raise _link_error(path) from None
        raise


def write_bytes(path: str | Path, data: bytes) -> None:
    """Replaces ``path`` with ``data`` whole: a new temporary (created exclusively, links not
    followed) is written, flushed to disk and renamed over ``path``. On any error the old file
    is left as it was and the temporary removed."""
    path = Path(path)
    _refuse_link(path)
    tmp = path.with_name(path.name + ".tmp")
    if tmp.is_symlink():
        raise _link_error(tmp)
    with contextlib.suppress(FileNotFoundError):
        tmp.unlink()  # a crashed write's leftover (a plain file: links are refused above)
    fd = _open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)  # rename replaces a link at ``path`` itself, never its target
    except BaseException as e:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(e, OSError) and e.filename is None:  # os.write names no file
            raise OSError(e.errno, e.strerror, str(path)) from None
        raise


def write_text(path: str | Path, text: str) -> None:
    """``write_bytes`` of ``text`` in UTF-8."""
    write_bytes(path, text.encode("utf-8"))


def append_text(path: str | Path, text: str) -> None:
    """Appends ``text`` to ``path`` (created if absent), never through a link, whole or not at
    all: when the write fails part way (a full disk) the file is cut back to its old length."""
    path = Path(path)
    _refuse_link(path)
    fd = _open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
    try:
        size = os.fstat(fd).st_size
        data = memoryview(text.encode("utf-8"))
        try:
            while data:
                data = data[os.write(fd, data) :]
        except OSError as e:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, size)  # shrinking a file needs no space
            raise OSError(e.errno, e.strerror, str(path)) from None
    finally:
        os.close(fd)


def open_lock(path: str | Path) -> IO[str]:
    """``path`` opened to read and write (created if absent, not truncated), never through a link:
    the run folder's lock file."""
    path = Path(path)
    fd = _open(path, os.O_RDWR | os.O_CREAT)
    return os.fdopen(fd, "r+")
