"""One reorder buffer for every stream that must be handled in time order: releases events in time order once they
are ``horizon_s`` older than the newest seen (file sources, the navigator's input)."""

from __future__ import annotations

import heapq
from collections.abc import Mapping

from companion.events import Event


#: events a buffer holds at most (a 0.5 s horizon holds about 1,500 at 1 kHz IMU x 3): beyond, memory would grow
MAX_HELD = 20_000


class ReorderBuffer:
    """Releases events in time order once they are older than ``horizon_s`` behind the newest.

    Equal times go by ``priority`` (event type -> rank, lower first; others ``default_priority``), then arrival
    order. ``horizon_s = 0`` passes events straight through. Events that arrive later than the horizon allows are
    released at once, still in arrival order, and counted in ``late``. With ``outlier_s``, an event stamped more than that
ahead of the newest is held until ``confirm_n`` consecutive such events confirm the jump (a stream gap); an event
back on the stream clock first means they were outliers: dropped and counted in ``dropped_future`` (so one
future-stamped event cannot drag the horizon and flush everything).

    Memory stays bounded whatever the times: an event equal to the previous one of its type (the same record
    repeated: same time, same values) is dropped and counted in ``duplicates``, and at most ``max_held`` events wait
    (beyond, the oldest go out early, counted in ``forced``: distinct events that all share a time never age).
    """

    def __init__(self, horizon_s: float, priority: Mapping[type, int] | None = None, default_priority: int = 0,
                 outlier_s: float = float("inf"), confirm_n: int = 1, max_held: int = MAX_HELD) -> None:
        self.horizon_s = horizon_s
        self.max_held = max_held
        self.duplicates = 0
        self.forced = 0
        self._last: dict[type, Event] = {}
        self.outlier_s = outlier_s
        self.confirm_n = confirm_n
        self._held: list[Event] = []  # events far ahead of the stream, waiting for confirmation
        self.dropped_future = 0
        self._priority = dict(priority or {})
        self._default = default_priority
        self._heap: list[tuple[float, int, int, Event]] = []
        self._seq = 0
        self.newest_s = float("-inf")
        self._released = float("-inf")
        self.late = 0

    def push(self, ev: Event) -> list[Event]:
        last = self._last.get(type(ev))
        if last is not None and last.t_s == ev.t_s and last == ev:
            self.duplicates += 1
            return []
        self._last[type(ev)] = ev
        if self.newest_s > float("-inf") and ev.t_s > self.newest_s + self.outlier_s:
            if self._held and abs(ev.t_s - self._held[0].t_s) > self.outlier_s:
                self.dropped_future += len(self._held)  # inconsistent outliers: start again from this one
                self._held = []
            self._held.append(ev)
            if len(self._held) < self.confirm_n:
                return []
            held, self._held = self._held, []  # the stream really jumped
            return [out for h in held for out in self._push(h)]
        if self._held:  # back on the stream clock: the held events were outliers
            self.dropped_future += len(self._held)
            self._held = []
        return self._push(ev)

    def _push(self, ev: Event) -> list[Event]:
        if ev.t_s > self.newest_s:
            self.newest_s = ev.t_s
        if self.horizon_s <= 0:
            return [ev]
        if ev.t_s < self._released:
            self.late += 1
        self._seq += 1
        heapq.heappush(self._heap, (ev.t_s, self._priority.get(type(ev), self._default), self._seq, ev))
        out = []
        limit = self.newest_s - self.horizon_s
        while self._heap and (self._heap[0][0] <= limit or len(self._heap) > self.max_held):
            if self._heap[0][0] > limit:
                self.forced += 1
            item = heapq.heappop(self._heap)
            self._released = max(self._released, item[0])
            out.append(item[3])
        return out

    def flush(self) -> list[Event]:
        self.dropped_future += len(self._held)  # never confirmed
        self._held = []
        out = [heapq.heappop(self._heap)[3] for _ in range(len(self._heap))]
        if out:
            self._released = max(self._released, out[-1].t_s)
        return out
