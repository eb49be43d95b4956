"""The autopilot's clock as the link shows it: what vehicle time it is *now*, from when messages arrived.

Each message the link delivers gives one relation ``arrival - t_s`` (host clock minus vehicle time). The freshest
messages give the smallest: the transport's own delay. A message held up on the way (a radio fade whose backlog
then arrives at once, a loaded host) gives a larger one, by exactly how late it is. So the vehicle's time now is
``host now - min(arrival - t_s)``, and a state's age is that minus its epoch, whatever the bytes' own arrival time
says (a burst's bytes are new, its contents seconds old).

The minimum is allowed to rise slowly (:data:`RELAX_S_PER_S`: the host clock is slewed by NTP, the autopilot's
crystal drifts, both well under 1e-3) so that a relation from hours ago does not make every message look late; it
is forgotten at an autopilot reboot (its clock restarts; the vehicle time spanning it is an estimate).
"""

from __future__ import annotations

import math

#: how fast the smallest relation may rise (s per s of host time): drift and slewing, not a burst's seconds
RELAX_S_PER_S = 2e-3


class LinkClock:
    """``observe(t_s, arrival_s)`` for each timed input; ``vehicle_now(host_now_s)``: the vehicle's time now."""

    def __init__(self, relax_s_per_s: float = RELAX_S_PER_S) -> None:
        self.relax = relax_s_per_s
        self._offset_s: float | None = None  # min(arrival - t_s), relaxed
        self._at_s = 0.0  # host time of the last update

    def reset(self) -> None:
        self._offset_s = None

    def observe(self, t_s: float, arrival_s: float) -> None:
        off = arrival_s - t_s
        if not math.isfinite(off):
            return
        if self._offset_s is None:
            self._offset_s, self._at_s = off, arrival_s
            return
        relaxed = self._offset_s + self.relax * max(0.0, arrival_s - self._at_s)
        self._offset_s = min(off, relaxed)
        self._at_s = max(self._at_s, arrival_s)

    def vehicle_now(self, host_now_s: float) -> float | None:
        """The vehicle's time at host time ``host_now_s`` (None before any message)."""
        if self._offset_s is None:
            return None
        return host_now_s - self._offset_s
