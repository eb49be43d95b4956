"""A recorder that starts a new MCAP file every ``segment_s`` of message time, within a disk budget.

An MCAP writer keeps one index entry per closed chunk until it writes the summary, so a single file
written for hours grows the process's memory (about 1 MB per 15 min at one chunk a second). A service
that runs for hours rotates instead: ``live.mcap`` becomes ``live-000.mcap``, ``live-001.mcap``, ...; each
segment is a complete, finalised MCAP with the same metadata records (source, configuration, version)
and the messages of its time span. Metadata added after the start goes to every later segment.

Disk budget (``max_total_bytes``): a segment is also cut once it reaches a quarter of the budget, and before a
new one starts the oldest segments are deleted until the finished ones left take at most half of it, so the
record (finished segments, the one being written and its summary section) stays under the budget. Only
segments this recorder wrote itself are ever deleted, never another file.

A write error stops the recording as in :class:`~companion.record.recorder.Recorder` (one line, nothing raised):
no new segment is opened after it.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

from companion.record.recorder import Recorder

_logger = logging.getLogger(__name__)


class RotatingRecorder:
    def __init__(self, path: str | os.PathLike, *, segment_s: float = 0.0, max_total_bytes: int = 0,
                 **recorder_kw: Any) -> None:
        if not segment_s >= 0 or not max_total_bytes >= 0 or not (segment_s > 0 or max_total_bytes > 0):
            raise ValueError("segment_s and max_total_bytes must be >= 0, one of them > 0")
        base = Path(path)
        self._stem, self._suffix, self._dir = base.stem, base.suffix or ".mcap", base.parent
        self.segment_s = segment_s
        self.max_total_bytes = int(max_total_bytes)
        self._segment_max_bytes = self.max_total_bytes // 4
        self._kw = recorder_kw
        self._metadata: list[tuple[str, dict]] = []
        self._segment_t0: float | None = None
        self.paths: list[Path] = []  # segments on disk, oldest first (the last one is being written)
        self.deleted: list[Path] = []  # segments deleted to stay within the budget
        self._n = 0
        self._sizes: dict[Path, int] = {}  # finished segments -> bytes
        self._counts: dict[str, int] = {}
        self._stopped: Recorder | None = None  # the segment whose write error stopped the recording
        self.dropped_after_error = 0
        self._rec = self._open()

    def _open(self) -> Recorder:
        path = self._dir / f"{self._stem}-{self._n:03d}{self._suffix}"
        self._n += 1
        rec = Recorder(path, **self._kw)
        for name, data in self._metadata:
            rec.add_metadata(name, data)
        self.paths.append(path)
        return rec

    def _rotate_for(self, t_s: float) -> bool:
        """Start the next segment when this one is due; False once the recording has stopped."""
        if self._rec.write_error is not None:
            self.dropped_after_error += 1
            return False
        if self._segment_t0 is None:
            self._segment_t0 = t_s
        elif ((self.segment_s > 0 and t_s - self._segment_t0 >= self.segment_s)
              or (self._segment_max_bytes > 0 and self._rec.size_bytes >= self._segment_max_bytes)):
            self._fold_counts()
            self._rec.close()
            if self._rec.write_error is not None:
                self.dropped_after_error += 1
                return False
            self._sizes[self._rec.path] = _size(self._rec.path)
            self._keep_budget()
            self._rec = self._open()
            self._segment_t0 = t_s
        return True

    def _keep_budget(self) -> None:
        """Delete the oldest finished segments until those left take at most half the budget."""
        if not self.max_total_bytes:
            return
        while self.paths and sum(self._sizes.get(p, 0) for p in self.paths) > self.max_total_bytes // 2:
            old = self.paths.pop(0)
            try:
                old.unlink()
            except FileNotFoundError:
                pass
            except OSError as err:  # cannot delete: leave it, the budget is then exceeded (said once per file)
                _logger.warning("record budget: cannot delete %s: %s", old, err.strerror or err)
            else:
                _logger.info("record budget: deleted the oldest segment %s (%d bytes)", old, self._sizes[old])
            self._sizes.pop(old, None)
            self.deleted.append(old)

    def _fold_counts(self) -> None:
        for topic, n in self._rec.counts.items():
            self._counts[topic] = self._counts.get(topic, 0) + n

    @property
    def write_error(self) -> OSError | None:
        return self._rec.write_error

    @property
    def path(self) -> Path:
        return self._rec.path

    @property
    def counts(self) -> dict[str, int]:
        total = dict(self._counts)
        if not self._rec.closed:  # a closed segment's counts are already folded in
            for topic, n in self._rec.counts.items():
                total[topic] = total.get(topic, 0) + n
        return total

    @property
    def closed(self) -> bool:
        return self._rec.closed

    def write(self, item: Any, topic: str | None = None) -> None:
        if self._rotate_for(item.t_s):
            self._rec.write(item, topic)

    def write_dict(self, topic, schema_name, json_schema, payload, t_s: float) -> None:
        if self._rotate_for(t_s):
            self._rec.write_dict(topic, schema_name, json_schema, payload, t_s)

    def write_location(self, topic: str, t_s: float, *args: Any, **kw: Any) -> None:
        if self._rotate_for(t_s):
            self._rec.write_location(topic, t_s, *args, **kw)

    def add_metadata(self, name: str, data) -> None:
        data = dict(data)
        self._metadata.append((name, data))
        self._rec.add_metadata(name, data)

    def flush(self) -> None:
        self._rec.flush()

    def close(self) -> None:
        if not self._rec.closed:
            self._fold_counts()
        self._rec.close()

    def __enter__(self) -> RotatingRecorder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0
