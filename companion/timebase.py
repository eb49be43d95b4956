"""One monotonic vehicle clock per source, from whatever time base the autopilot used.

ArduPilot stamps data with its boot time: ``TimeMS`` (AC 3.1-3.3 dataflash), ``TimeUS`` (AC 4.x), ``T``
(boot ms in AC 3.x GPS rows, whose ``TimeMS`` is GPS time of week), ``time_boot_ms`` / ``time_usec``
(MAVLink). Boot time restarts at zero when the autopilot reboots. :class:`VehicleClock` turns boot time
into ``t_s``: boot time plus an offset that grows at every reboot by the boot time reached before it, so
``t_s`` keeps increasing through reboots (the downtime itself is unknown and not counted).

Messages of different types can arrive slightly out of time order (each is stamped when its sensor was
sampled, not when it was written); only a backward jump larger than ``reboot_jump_s`` counts as a reboot. Time
order itself is restored by companion.nav.reorder.ReorderBuffer.

A forward jump is judged the same way: one message stamped far ahead (a bit flip, a corrupt field) is dropped
and counted (``held_ahead``), not a gap in the data; only ``confirm_messages`` messages in a row that agree with
each other move the clock forward (or, with a receive clock, a jump the receive time shows as well: the link was
silent that long).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from companion.events import Reboot

#: a boot time beyond this (about 3 years) is a corrupt field, not an autopilot's uptime; it also keeps every
#: vehicle time well inside what a recorder's uint64 nanosecond stamps hold
MAX_BOOT_S = 1e8

#: what the decoders count a held-back message as, per VehicleClock.last_hold
HOLD_REASONS = {
    "back": "time jumped back (late, or a reboot not yet confirmed)",
    "ahead": "time jumped ahead (one outlier, or a gap not yet confirmed)",
    "invalid": "time out of range",
}


@dataclass
class VehicleClock:
    """Boot time -> vehicle time. A reboot is declared only once ``confirm_messages`` messages in a row
    sit more than ``reboot_jump_s`` behind the clock; until then they are held back (``t_s`` None), so one
    very late sample is dropped as late instead of shifting the whole clock.

    The same holds forward: a message more than ``ahead_jump_s`` ahead of the clock (beyond what the receive
    clock has advanced, when there is one) is held back until ``confirm_messages`` messages in a row sit there.

    ``derived=True`` marks a boot time extrapolated from another message's (a MAVLink message without
    its own time stamp): it neither confirms nor cancels a pending reboot.
    """

    reboot_jump_s: float = 2.0
    confirm_messages: int = 3
    offset_s: float = 0.0
    max_boot_s: float | None = None
    reboots: int = 0
    held_back: int = 0  # messages dropped while a backward jump was unconfirmed
    ahead_jump_s: float = 2.0
    held_ahead: int = 0  # messages dropped while a forward jump was unconfirmed (outliers, mostly)
    gaps: int = 0  # forward jumps confirmed by consistent messages
    invalid: int = 0  # boot times no autopilot reaches (negative, non-finite, beyond MAX_BOOT_S): dropped
    #: why the last message was held back: "back", "ahead" or "invalid"
    last_hold: str = ""
    _ahead: list[float] = field(default_factory=list)
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
        if not (math.isfinite(boot_s) and 0.0 <= boot_s <= MAX_BOOT_S):
            self.invalid += 1
            self.last_hold = "invalid"
            return None, None
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
                self.last_hold = "back"
                return None, None
            prev, first = self.max_boot_s, self._candidate[0]
            downtime_s = 0.0
            if self._candidate_recv_s is not None and self._last_recv_s is not None:
                downtime_s = max(0.0, self._candidate_recv_s - self._last_recv_s - first)
            self.offset_s += prev + downtime_s
            self.max_boot_s = max(self._candidate)
            self._candidate.clear()
            self._ahead.clear()
            self.reboots += 1
            return self.offset_s + boot_s, Reboot(t_s=self.offset_s + first, previous_boot_s=prev, new_boot_s=first)
        if boot_s > self.max_boot_s + self.ahead_jump_s and not self._explained_by_receive(boot_s, recv_s):
            if self._ahead and not abs(boot_s - self._ahead[-1]) <= self.ahead_jump_s:
                self._ahead.clear()  # not one new stretch of time either: start over
            self._ahead.append(boot_s)
            if len(self._ahead) < self.confirm_messages:
                self.held_ahead += 1
                self.last_hold = "ahead"
                return None, None
            self._ahead.clear()
            self.gaps += 1
        else:
            self._ahead.clear()  # back on the current time: what jumped ahead was one outlier
        self._candidate.clear()  # back on the current epoch: what jumped back was only late
        if boot_s >= self.max_boot_s:
            self.max_boot_s = boot_s
            if recv_s is not None:
                self._last_recv_s = recv_s
        return self.offset_s + boot_s, None

    def _explained_by_receive(self, boot_s: float, recv_s: float | None) -> bool:
        """A forward jump the receive clock shows too (the link or the log was silent that long) is real."""
        if recv_s is None or self._last_recv_s is None or self.max_boot_s is None:
            return False
        gap = recv_s - self._last_recv_s
        return gap >= 0.0 and boot_s - self.max_boot_s <= gap + self.ahead_jump_s
