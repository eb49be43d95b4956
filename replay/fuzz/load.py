"""A loaded machine, emulated: a process group run only a fraction of the time (SIGSTOP / SIGCONT at a duty cycle).

Everything in the group slows down by the same factor while wall-clock time runs on, which is what a machine at
load 6-10 on 2 cores does to a test that waits a fixed time instead of for a condition -- without loading the
machine for everyone else.
"""

from __future__ import annotations

import os
import signal
import threading


class Throttle:
    """Run process group ``pgid`` ``run_fraction`` of every ``period_s`` (a context manager; resumes it at exit)."""

    def __init__(self, pgid: int, run_fraction: float = 0.25, period_s: float = 0.04) -> None:
        if not 0 < run_fraction <= 1:
            raise ValueError("run_fraction must be in (0, 1]")
        self.pgid, self.run_s, self.stop_s = pgid, run_fraction * period_s, (1 - run_fraction) * period_s
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="throttle", daemon=True)

    def _signal(self, sig) -> bool:
        try:
            os.killpg(self.pgid, sig)
            return True
        except ProcessLookupError:
            return False

    def _loop(self) -> None:
        while not self._done.is_set():
            if not self._signal(signal.SIGCONT):
                return
            self._done.wait(self.run_s)
            if self._done.is_set() or self.stop_s <= 0:
                continue
            self._signal(signal.SIGSTOP)
            self._done.wait(self.stop_s)
        self._signal(signal.SIGCONT)

    def __enter__(self) -> Throttle:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._done.set()
        self._thread.join(5)
        self._signal(signal.SIGCONT)
