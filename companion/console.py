"""Terminal output of the commands: progress bars, summary lines wrapped to the terminal, warnings under ``-q``."""

from __future__ import annotations

import logging
import sys


def short_label(text: str, width: int) -> str:
    """``text`` cut in the middle to at most ``width`` characters (a long log name keeps its ends)."""
    if len(text) <= width:
        return text
    keep = max(1, width - 1)
    return text[: (keep + 1) // 2] + "…" + text[len(text) - keep // 2:]


def bar_label(desc: str, columns: int) -> str:
    """The progress bar's label at a terminal ``columns`` wide: the counts, ETA and rate need ~45 columns and the bar
    itself at least 13, so the label gets the rest (at least 8), cut in the middle."""
    return short_label(desc, max(8, columns - 58))


def progress_bar(total: int | None, desc: str, quiet: bool):
    import shutil

    from tqdm import tqdm

    desc = bar_label(desc, shutil.get_terminal_size((80, 24)).columns)

    # disable=None: shown on a terminal, silent when stderr is a file or a pipe (CI logs stay clean)
    return tqdm(
        total=total, desc=desc, unit="B", unit_scale=True, file=sys.stderr, disable=True if quiet else None, leave=False
    )


def summary_line(label: str, text: str) -> str:
    """``label`` in a 12-column field, then ``text`` wrapped to the terminal (at least 60 columns), continuation lines
    under the text."""
    import shutil
    import textwrap

    width = max(60, shutil.get_terminal_size((80, 24)).columns)
    return textwrap.fill(text, width=width, initial_indent=f"{label:<12} ", subsequent_indent=" " * 13,
                         break_on_hyphens=False, break_long_words=False)


def warn_quietly(warnings: list[str], logger: str = "companion.replay") -> None:
    """A source's warnings at WARNING (what ``-q`` still shows), other systems' traffic left out as in the summary."""
    log = logging.getLogger(logger)
    for w in warnings:
        if not ("other system" in w and w.startswith("dropped")):
            log.warning("%s", w)
