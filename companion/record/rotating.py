"""A recorder that starts a new MCAP file every ``segment_s`` of message time, within a disk budget.

An MCAP writer keeps one index entry per closed chunk until it writes the summary, so a single file
written for hours grows the process's memory (about 1 MB per 15 min at one chunk a second). A service
that runs for hours rotates instead: ``live.mcap`` becomes ``live-000.mcap``, ``live-001.mcap``, ...; each
segment is a complete, finalised MCAP with the same metadata records (source, configuration, version)
and the messages of its time span. Metadata added after the start goes to every later segment.

Disk budget (``max_total_bytes``): a segment is also cut once it reaches a quarter of the budget, and before a
new one starts the oldest segments are deleted until the finished ones left take at most half of it, so the
record (finished segments, the one being written and its summary section) stays under the budget. Only
segments this recorder wrote itself are ever deleted, and the ``earlier`` records it is given (a service's
earlier runs in its record directory): those count in the budget and go first, oldest first, also at the start,
so a service restarted day after day keeps its directory under the budget too.

A write error stops the segment as in :class:`~companion.record.recorder.Recorder` (one line naming it, nothing
raised); a new segment is tried after :data:`RETRY_MIN_S` of message time, the wait doubling up to
:data:`RETRY_MAX_S` while the disk stays unwritable (quietly; with a budget the oldest segment is deleted first
to make room). The new segment is on probation until its first chunk of messages is on disk: only then does one
line say the recording resumed; if it fails before (a disk with room for a header, not for a chunk), it is deleted
-- it holds nothing readable -- and the wait doubles. A stopped segment that never got a chunk to disk is deleted
as well: no unreadable segment is left behind.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

from companion.record.recorder import Recorder

_logger = logging.getLogger(__name__)
RETRY_MIN_S = 10.0  # message time from a write error to the first new segment tried
RETRY_MAX_S = 600.0


class RotatingRecorder:
    def __init__(self, path: str | os.PathLike, *, segment_s: float = 0.0, max_total_bytes: int = 0,
                 earlier: list[Path] | tuple[Path, ...] = (), **recorder_kw: Any) -> None:
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
        self._dropped = 0
        self._retry_s = RETRY_MIN_S
        self._retry_at: float | None = None  # message time of the next new segment tried after a write error
        self.write_errors: list[OSError] = []  # every write error that stopped a segment
        self._probation = False  # the segment opened after a write error has not got a chunk to disk yet
        #: earlier records in the budget, oldest first (deleted before any segment of this run)
        self._earlier = [Path(q) for q in earlier] if self.max_total_bytes else []
        for q in self._earlier:
            self._sizes[q] = _size(q)
        self._keep_budget()
        self._rec = self._open()

    def _open(self, announce_errors: bool = True) -> Recorder:
        path = self._dir / f"{self._stem}-{self._n:03d}{self._suffix}"
        self._n += 1
        rec = Recorder(path, announce_errors=announce_errors, **self._kw)
        for name, data in self._metadata:
            rec.add_metadata(name, data)
        self.paths.append(path)
        return rec

    def _rotate_for(self, t_s: float) -> bool:
        """Start the next segment when this one is due; False while the recording is stopped by a write error."""
        if self._probation:
            if self._rec.write_error is not None:
                return self._failed_attempt(t_s)
            if self._rec.chunks_written:
                self._probation = False
                self._rec.announce_errors = True  # (a later write error is news again)
                _logger.warning("recording resumed in %s after a write error (%d messages not recorded)",
                                self._rec.path, self.dropped_after_error)
        if self._rec.write_error is not None:
            return self._retry(t_s)
        if self._segment_t0 is None:
            self._segment_t0 = t_s
        elif ((self.segment_s > 0 and t_s - self._segment_t0 >= self.segment_s)
              or (self._segment_max_bytes > 0 and self._rec.size_bytes >= self._segment_max_bytes)):
            self._fold_counts()
            self._rec.close()
            if self._rec.write_error is not None:  # its summary could not be written: try the next one now
                self._retry_at = t_s
                return self._retry(t_s)
            self._sizes[self._rec.path] = _size(self._rec.path)
            self._keep_budget()
            self._rec = self._open()
            self._segment_t0 = t_s
            self._retry_s = RETRY_MIN_S  # a segment finished whole: the disk is fine again
        return True

    def _retry(self, t_s: float) -> bool:
        """The segment stopped on a write error: messages are dropped until the next try, then a new segment is
        tried; the stopped one stays open meanwhile (unwritten) so the live view it feeds goes on."""
        if self._retry_at is None:
            self.write_errors.append(self._rec.write_error)
            self._retry_at = t_s + self._retry_s
        if t_s < self._retry_at:
            return False
        if self.max_total_bytes and len(self.paths) > 1:  # make room: the oldest segment goes
            self._delete(self.paths[0])
        rec = self._open(announce_errors=False)
        if rec.write_error is not None:  # still unwritable: wait longer (the attempt's own file goes)
            rec.close()
            self._delete(rec.path, budget=False)
            self._retry_s = min(2.0 * self._retry_s, RETRY_MAX_S)
            self._retry_at = t_s + self._retry_s
            return False
        old = self._rec
        if not old.closed:
            self._fold_counts()
            old.close()
        if old.path in self.paths:  # the stopped segment keeps what it has: it counts in the budget
            if old.chunks_written:
                self._sizes[old.path] = _size(old.path)
            else:  # nothing of it reached the disk whole: not a segment anyone could read
                self._delete(old.path, budget=False)
        self._dropped += old.dropped_after_error
        self._rec, self._segment_t0, self._retry_at = rec, t_s, None
        self._probation = True  # resumed once its first chunk is on disk
        return True

    def _failed_attempt(self, t_s: float) -> bool:
        """The segment on probation failed before its first chunk reached the disk: it goes (nothing in it is
        readable), what it held counts as not recorded, and the wait doubles."""
        rec = self._rec
        self._probation = False
        self._dropped += sum(rec.counts.values())
        rec.close()
        self._delete(rec.path, budget=False)
        self._retry_s = min(2.0 * self._retry_s, RETRY_MAX_S)
        self._retry_at = t_s + self._retry_s
        return False

    def _delete(self, old: Path, budget: bool = True) -> None:
        if old in self.paths:
            self.paths.remove(old)
        try:
            old.unlink()
        except FileNotFoundError:
            pass
        except OSError as err:  # cannot delete: leave it, the budget is then exceeded (said once per file)
            _logger.warning("record budget: cannot delete %s: %s", old, err.strerror or err)
        else:
            if budget:
                _logger.info("record budget: deleted the oldest segment %s (%d bytes)", old, self._sizes.get(old, 0))
        if budget:
            self.deleted.append(old)
        self._sizes.pop(old, None)

    def _keep_budget(self) -> None:
        """Delete the oldest finished segments (earlier records first) until those left take at most half the budget."""
        if not self.max_total_bytes:
            return
        while self._earlier or self.paths:
            if sum(self._sizes.get(p, 0) for p in self._earlier + self.paths) <= self.max_total_bytes // 2:
                return
            if self._earlier:
                self._delete_earlier(self._earlier.pop(0))
            else:
                self._delete(self.paths[0])

    def _delete_earlier(self, old: Path) -> None:
        try:
            old.unlink()
        except FileNotFoundError:
            pass
        except OSError as err:
            _logger.warning("record budget: cannot delete %s: %s", old, err.strerror or err)
        else:
            _logger.info("record budget: deleted the earlier record %s (%d bytes)", old, self._sizes.get(old, 0))
            self.deleted.append(old)
        self._sizes.pop(old, None)

    def _fold_counts(self) -> None:
        for topic, n in self._rec.counts.items():
            self._counts[topic] = self._counts.get(topic, 0) + n

    @property
    def write_error(self) -> OSError | None:
        """The write error the recording is stopped on now (None once it has resumed; all: ``write_errors``)."""
        return self._rec.write_error

    @property
    def dropped_after_error(self) -> int:
        return self._dropped + self._rec.dropped_after_error

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

    # while stopped, a message still goes to the stopped segment (dropped and counted there, shown in the live view)
    def write(self, item: Any, topic: str | None = None) -> None:
        if self._rotate_for(item.t_s) or not self._rec.closed:
            self._rec.write(item, topic)
        else:
            self._dropped += 1

    def write_dict(self, topic, schema_name, json_schema, payload, t_s: float) -> None:
        if self._rotate_for(t_s) or not self._rec.closed:
            self._rec.write_dict(topic, schema_name, json_schema, payload, t_s)
        else:
            self._dropped += 1

    def write_location(self, topic: str, t_s: float, *args: Any, **kw: Any) -> None:
        if self._rotate_for(t_s) or not self._rec.closed:
            self._rec.write_location(topic, t_s, *args, **kw)
        else:
            self._dropped += 1

    def write_log(self, topic: str, t_s: float, *args: Any, **kw: Any) -> None:
        if self._rotate_for(t_s) or not self._rec.closed:
            self._rec.write_log(topic, t_s, *args, **kw)
        else:
            self._dropped += 1

    def add_metadata(self, name: str, data) -> None:
        data = dict(data)
        self._metadata.append((name, data))
        self._rec.add_metadata(name, data)

    def flush(self) -> None:
        self._rec.flush()

    def close(self) -> None:
        rec = self._rec
        if not rec.closed:
            self._fold_counts()
        rec.close()
        if rec.write_error is not None and not rec.chunks_written and rec.path in self.paths:
            self._delete(rec.path, budget=False)  # stopped before anything reached the disk whole: unreadable

    def __enter__(self) -> RotatingRecorder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0
