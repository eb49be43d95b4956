"""Logging for the command line and the service: the standard :mod:`logging` module, one line per event.

On a terminal a line reads ``20:41:07 WARNING companion.runtime: link lost: ...``. Under systemd
(``JOURNAL_STREAM`` set: stderr goes to the journal) there is no timestamp, which journald adds, and
each line starts with the sd-daemon priority prefix (``<4>`` for a warning, see sd-daemon(3)), so
``journalctl -p warning`` filters by level; the level name stays in the text for ``journalctl -o cat``.
``-v`` shows DEBUG, ``-q`` only warnings, ``-qq`` only errors.
"""

from __future__ import annotations

import logging
import os
import sys

#: syslog priorities of the logging levels (sd-daemon(3) prefixes)
_SYSLOG = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3, logging.CRITICAL: 2}


class _JournalFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        prio = _SYSLOG.get(record.levelno, 6)
        # one event, one line: a multi-line message or traceback would be split into several entries
        text = super().format(record).replace("\n", " | ")
        return f"<{prio}>{text}"


def under_journal() -> bool:
    return bool(os.environ.get("JOURNAL_STREAM"))


def level_for(verbose: int = 0, quiet: int = 0) -> int:
    return {2: logging.DEBUG, 1: logging.DEBUG, 0: logging.INFO, -1: logging.WARNING}.get(
        max(-2, min(2, verbose - quiet)), logging.ERROR)


def configure(verbose: int = 0, quiet: int = 0, stream=None) -> None:
    """Set up the ``companion`` logger once per process (idempotent: replaces our earlier handler)."""
    root = logging.getLogger("companion")
    for h in list(root.handlers):
        if getattr(h, "_companion", False):
            root.removeHandler(h)
    handler = logging.StreamHandler(stream if stream is not None else sys.stderr)
    handler._companion = True  # type: ignore[attr-defined]
    if under_journal():
        handler.setFormatter(_JournalFormatter("%(levelname)s %(name)s: %(message)s"))
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s", "%H:%M:%S"))
    root.addHandler(handler)
    root.setLevel(level_for(verbose, quiet))
    root.propagate = False


def stderr_line(text: str, priority: int = 3) -> None:
    """One line on stderr outside the logger (the CLI's ``companion: error: ...``): under systemd with its syslog
    priority prefix (3: error, 4: warning), so ``journalctl -p err`` shows it too."""
    print(f"<{priority}>{text}" if under_journal() else text, file=sys.stderr, flush=True)
