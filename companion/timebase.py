"""One monotonic vehicle clock per source, from whatever time base the autopilot used.

ArduPilot stamps data with its boot time: ``TimeMS`` (AC 3.1-3.3 dataflash), ``TimeUS`` (AC 4.x), ``T``
(boot ms in AC 3.x GPS rows, whose ``TimeMS`` is GPS time of week), ``time_boot_ms`` / ``time_usec``
(MAVLink). Boot time restarts at zero when the autopilot reboots. :class:`VehicleClock` turns boot time
into ``t_s``: boot time plus an offset that grows at every reboot by the boot time reached before it, so
``t_s`` keeps increasing through reboots (the downtime itself is unknown and not counted).

Messages of different types can arrive slightly out of time order (each is stamped when its sensor was
sampled, not when it was written); only a backward jump larger than ``reboot_jump_s`` counts as a reboot.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field

from companion.events import Event, Reboot


@dataclass
class VehicleClock:
    """Boot time -> vehicle time. A reboot is declared only once ``confirm_messages`` messages in a row
    sit more than ``reboot_jump_s`` behind the clock; until then they are held back (``t_s`` None), so one
    very late sample is dropped as late instead of shifting the whole clock.

    ``derived=True`` marks a boot time extrapolated from another message's (a MAVLink message without
    its own time stamp): it neither confirms nor cancels a pending reboot.
    """

    reboot_jump_s: float = 2.0
    confirm_messages: int = 3
    offset_s: float = 0.0
    max_boot_s: float | None = None
    reboots: int = 0
    held_back: int = 0  # messages dropped while a backward jump was unconfirmed
    _candidate: list[float] = field(default_factory=list)
    _candidate_recv_s: float | None = None  # receive time of the first message of the new epoch
    _last_recv_s: float | None = None  # receive time of the newest message on the current epoch

    def to_vehicle(
        self, boot_s: float, derived: bool = False, recv_s: float | None = None
    ) -> tuple[float | None, Reboot | None]:
        """Vehicle time for a boot time (None: held back), and a Reboot event when one is confirmed.

        ``recv_s`` (a receive clock: tlog record time, live link monotonic time) lets a reboot keep the
        downtime: the new epoch starts that much after the last message before it, so a vehicle that
        kept moving while its autopilot restarted does not appear to jump in zero time.
        """
        if self.max_boot_s is None:
            self.max_boot_s = boot_s
            self._last_recv_s = recv_s
            return self.offset_s + boot_s, None
        if derived:
            return self.offset_s + max(boot_s, 0.0), None
        if boot_s < self.max_boot_s - self.reboot_jump_s:
            if self._candidate and boot_s < self._candidate[-1] - self.reboot_jump_s:
                self._candidate.clear()  # not one new epoch either: start over
            if not self._candidate:
                self._candidate_recv_s = recv_s
            self._candidate.append(boot_s)
            if len(self._candidate) < self.confirm_messages:
                self.held_back += 1
                return None, None
            prev, first = self.max_boot_s, self._candidate[0]
            downtime_s = 0.0
            if self._candidate_recv_s is not None and self._last_recv_s is not None:
                downtime_s = max(0.0, self._candidate_recv_s - self._last_recv_s - first)
            self.offset_s += prev + downtime_s
            self.max_boot_s = max(self._candidate)
            self._candidate.clear()
            self.reboots += 1
            return self.offset_s + boot_s, Reboot(t_s=self.offset_s + first, previous_boot_s=prev, new_boot_s=first)
        self._candidate.clear()  # back on the current epoch: what jumped back was only late
        if boot_s >= self.max_boot_s:
            self.max_boot_s = boot_s
            if recv_s is not None:
                self._last_recv_s = recv_s
        return self.offset_s + boot_s, None


@dataclass(order=True)
class _Item:
    t_s: float
    seq: int
    event: Event = field(compare=False)


class ReorderBuffer:
    """Releases events in time order once they are older than ``horizon_s`` behind the newest.

    Stable for equal times (arrival order kept). ``horizon_s = 0`` passes events straight through.
    Events that arrive later than the horizon allows are released at once, still in arrival order, and
    counted in ``late``.
    """

    def __init__(self, horizon_s: float) -> None:
        self.horizon_s = horizon_s
        self._heap: list[_Item] = []
        self._seq = 0
        self._newest = float("-inf")
        self._released = float("-inf")
        self.late = 0

    def push(self, ev: Event) -> list[Event]:
        if self.horizon_s <= 0:
            return [ev]
        if ev.t_s < self._released:
            self.late += 1
        self._seq += 1
        heapq.heappush(self._heap, _Item(ev.t_s, self._seq, ev))
        if ev.t_s > self._newest:
            self._newest = ev.t_s
        out = []
        limit = self._newest - self.horizon_s
        while self._heap and self._heap[0].t_s <= limit:
            item = heapq.heappop(self._heap)
            self._released = max(self._released, item.t_s)
            out.append(item.event)
        return out

    def flush(self) -> list[Event]:
        out = [heapq.heappop(self._heap).event for _ in range(len(self._heap))]
        if out:
            self._released = max(self._released, out[-1].t_s)
        return out
