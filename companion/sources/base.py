"""One interface for every source of events: an async iterator.

A source yields :mod:`companion.events` in the order the vehicle produced them (log order for files,
arrival order for live links). Blocking I/O (file parsing, sockets, serial) runs in worker threads so
the asyncio loop stays responsive. Problems with the input surface as :class:`SourceError` with a
message meant for the user; no traceback reaches the CLI.
"""

from __future__ import annotations

import abc
from collections.abc import AsyncIterator
from dataclasses import dataclass, field

from companion.events import Event


class SourceError(Exception):
    """The input cannot be used; ``str(err)`` says why in words for the user."""


@dataclass
class SourceInfo:
    """What a source is, for the MCAP metadata and the summary."""

    kind: str  # "dataflash", "tlog", "live"
    location: str  # path or connection URL
    details: dict[str, str] = field(default_factory=dict)  # firmware, vehicle, notes found on the way
    warnings: list[str] = field(default_factory=list)  # non-fatal problems (e.g. truncated tail)


class Source(abc.ABC):
    """Async iterator of events. Use ``async for ev in source`` once; then ``await source.aclose()``."""

    info: SourceInfo

    @abc.abstractmethod
    def __aiter__(self) -> AsyncIterator[Event]: ...

    def progress(self) -> tuple[int, int] | None:
        """(done, total) in bytes for files, None when unknown (live links)."""
        return None

    async def aclose(self) -> None:  # noqa: B027 - optional hook
        """Release the underlying file or link."""
