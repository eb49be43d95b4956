"""The base of every pipeline stage: `process` (required), and optional hooks with defaults.

A stage turns each item it is given (an input event, or an earlier stage's output) into zero or more outputs::

    process(item) -> list[outputs]   every item, in stream order
    finish() -> list[outputs]        once, at the end of the stream (default: nothing)
    passes(item) -> bool             whether the stages after this one see the item (default: all of them);
                                     only asked of stages with ``filters = True`` (a filter, e.g. a GNSS denial)
    metadata() -> dict[str, str]     what the stage says about itself in the record (default: nothing)
    summary_lines() -> list[str]     lines for the end-of-run summary (default: none)

Outputs are frozen dataclasses with ``t_s`` and a ``topic`` (companion.events.Event). An output whose type has
``feedback = True`` (companion.events.PositionFix) goes back to the first stage as an input: see
companion.pipeline.core.
"""

from __future__ import annotations

from typing import Any, ClassVar


class Stage:
    """Base of every pipeline stage (see the module docstring)."""

    #: True for a stage whose `passes` decides what the stages after it see
    filters: ClassVar[bool] = False

    def process(self, item: Any) -> list[Any]:
        raise NotImplementedError

    def finish(self) -> list[Any]:
        return []

    def passes(self, item: Any) -> bool:
        return True

    def metadata(self) -> dict[str, str]:
        return {}

    def summary_lines(self) -> list[str]:
        return []
