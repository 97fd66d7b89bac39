"""Signals to a run: the first stops it cleanly after the chunk in flight, a second at once."""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from typing import Any

from fastrl.runtime import devices


class StopFlag:
    """Stops the run cleanly on Ctrl-C (SIGINT), SIGTERM (Slurm, ``docker stop``, ``kill``, a CI
    cancel) and SIGHUP (a closed terminal): the first sets the flag, and the run stops after the
    chunk in flight and saves a checkpoint. A second signal stops at once without saving, except
    while a checkpoint is being written: that save is completed first (an interrupted save
    would leave nothing but a partial folder). A first signal during a periodic save stops the
    run after the next chunk."""

    SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")

    def __init__(self):
        self.signum: int | None = None
        self._saving = False
        self._previous: dict[int, Any] = {}

    @property
    def set(self) -> bool:
        return self.signum is not None

    @property
    def name(self) -> str | None:
        """How the stop was asked for, as the user would say it."""
        if self.signum is None:
            return None
        return "Ctrl-C" if self.signum == signal.SIGINT else signal.Signals(self.signum).name

    def __enter__(self):
        if threading.current_thread() is not threading.main_thread():
            return self
        for name in self.SIGNALS:
            num = getattr(signal, name, None)  # Windows has no SIGHUP
            if num is not None and signal.getsignal(num) is not None:
                self._previous[num] = signal.signal(num, self._handle)
        return self

    def _handle(self, signum, frame):
        if self.set and self._saving:
            print("\n[fastrl] a checkpoint is being saved: the run ends once it is complete",
                  file=sys.stderr, flush=True)  # fmt: skip
            return
        if self.set:
            raise KeyboardInterrupt
        self.signum = signum
        print(f"\n[fastrl] {self.name}: stopping after this chunk and saving a checkpoint (again to abort)",
              file=sys.stderr, flush=True)  # fmt: skip

    def agree(self) -> None:
        """A stop asked of any process of a multi-host run stops them all (as SIGINT where this
        process received none)."""
        if devices.any_process(self.set) and not self.set:
            self.signum = signal.SIGINT

    @contextlib.contextmanager
    def saving(self):
        """Holds a second signal back while a checkpoint is written."""
        self._saving = True
        try:
            yield
        finally:
            self._saving = False

    def __exit__(self, *exc):
        for num, previous in self._previous.items():
            signal.signal(num, previous)
        self._previous = {}
