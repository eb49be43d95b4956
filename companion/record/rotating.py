"""A recorder that starts a new MCAP file every ``segment_s`` of message time.

An MCAP writer keeps one index entry per closed chunk until it writes the summary, so a single file
written for hours grows the process's memory (about 1 MB per 15 min at one chunk a second). A service
that runs for hours rotates instead: ``live.mcap`` becomes ``live-000.mcap``, ``live-001.mcap``, ...; each
segment is a complete, finalised MCAP with the same metadata records (source, configuration, version)
and the messages of its time span. Metadata added after the start goes to every later segment.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from companion.record.recorder import Recorder


class RotatingRecorder:
    def __init__(self, path: str | os.PathLike, *, segment_s: float, **recorder_kw: Any) -> None:
        if not segment_s > 0:
            raise ValueError("segment_s must be > 0")
        base = Path(path)
        self._stem, self._suffix, self._dir = base.stem, base.suffix or ".mcap", base.parent
        self.segment_s = segment_s
        self._kw = recorder_kw
        self._metadata: list[tuple[str, dict]] = []
        self._segment_t0: float | None = None
        self.paths: list[Path] = []
        self._counts: dict[str, int] = {}
        self._rec = self._open()

    def _open(self) -> Recorder:
        path = self._dir / f"{self._stem}-{len(self.paths):03d}{self._suffix}"
        rec = Recorder(path, **self._kw)
        for name, data in self._metadata:
            rec.add_metadata(name, data)
        self.paths.append(path)
        return rec

    def _rotate_for(self, t_s: float) -> None:
        if self._segment_t0 is None:
            self._segment_t0 = t_s
        elif t_s - self._segment_t0 >= self.segment_s:
            self._fold_counts()
            self._rec.close()
            self._rec = self._open()
            self._segment_t0 = t_s

    def _fold_counts(self) -> None:
        for topic, n in self._rec.counts.items():
            self._counts[topic] = self._counts.get(topic, 0) + n

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
        self._rotate_for(item.t_s)
        self._rec.write(item, topic)

    def write_dict(self, topic, schema_name, json_schema, payload, t_s: float) -> None:
        self._rotate_for(t_s)
        self._rec.write_dict(topic, schema_name, json_schema, payload, t_s)

    def write_location(self, topic: str, t_s: float, *args: Any, **kw: Any) -> None:
        self._rotate_for(t_s)
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
