"""SIGINT/SIGTERM caught from a command's first step, before any file is created.

asyncio's own handlers (``loop.add_signal_handler``) exist only while its loop runs: before it (the record file is
already open) and after it (the record being finalised) the default handlers would kill the process mid-write and
leave an unreadable file. :class:`StopSignals` notes the signal instead; the command asks :attr:`reason` at its
next step, and :meth:`rearm` puts the handlers back once the loop has removed its own.
"""

from __future__ import annotations

import signal
import threading

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class StopSignals:
    """``with StopSignals() as stop:`` ... ``stop.reason`` (None, "SIGINT" or "SIGTERM": the first one caught)."""

    def __init__(self) -> None:
        self.reason: str | None = None
        self._old: dict[int, object] = {}

    def note(self, name: str) -> None:
        if self.reason is None:
            self.reason = name

    def _on(self, signum, _frame) -> None:
        self.note(signal.Signals(signum).name)

    def rearm(self) -> None:
        if threading.current_thread() is threading.main_thread():
            for sig in SIGNALS:
                signal.signal(sig, self._on)

    def __enter__(self) -> StopSignals:
        if threading.current_thread() is threading.main_thread():
            self._old = {sig: signal.signal(sig, self._on) for sig in SIGNALS}
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._old.items():
            signal.signal(sig, handler)
        self._old = {}
