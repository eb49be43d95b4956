"""Which of the link's batches the live loop may leave for later: those that cannot make a GPS_INPUT leave.

A GPS_INPUT follows a navigator output (FusedState), which comes at a 10 Hz tick once an event later than the tick
leaves the navigator's reorder buffer, i.e. once the newest event is ``reorder_window_s`` past the first event after
the tick (companion.nav.reorder). An event that cannot bring that about, of the streams the navigator takes (IMU
samples, attitude, receiver fixes, the autopilot's position), only changes the navigator's state: it may wait, in
order, until the next event that can. Woken twice per output instead of once per message (once :data:`LEAD_S`
ahead, to run what waited, so that the event that makes the output finds little before it), the loop runs the same
events in the same order with its caches warm. Everything else (a reboot, a heartbeat, a gravimeter reading,
SYSTEM_TIME, ...) is taken at once.

The loop publishes the navigator's next tick (:attr:`OutputWait.next_output_s`) after each batch; the link's reader
thread asks :meth:`OutputWait.may_wait` about each read, with the times of every event it has seen (the navigator's
are among them). A tick read before the loop published the next is earlier than the real one, so the answer errs
towards waking.
"""

from __future__ import annotations

import math
from collections import deque

from companion.events import (AirData, Attitude, AutopilotAltitude, AutopilotPosition, Event, GnssFix, ImuSample,
                              MagField, WaterSpeed)

#: the event types that may wait for the next output: the streams the navigator takes, in its event order, and the
#: air data, water speed and compass field the air-data gravity stage takes (it acts on the navigator's outputs only)
MAY_WAIT = (ImuSample, Attitude, GnssFix, AutopilotPosition, AutopilotAltitude, AirData, WaterSpeed, MagField)


#: event times kept to find the first after a tick: this far (s) behind the newest, past the reorder window
KEEP_S = 2.0
#: the loop is woken once this long (event time, s) before the output is due, to run what waited: the event that
#: makes the output then finds little before it (a 20 Hz stream or faster has an event in this lead). Measured:
#: docs/decisions/0014-live-wake-ups-and-compiled-core.md
LEAD_S = 0.05


#: event times kept at most (memory stays bounded whatever the times)
MAX_KEPT = 20_000


class OutputWait:
    """``may_wait(events)``: True when none of the events can release a navigator output (see the module doc).

    An event stamped more than ``outlier_s`` ahead of the newest is not counted until ``confirm_n`` consecutive ones
    confirm the jump, as the navigator's reorder buffer does (companion.nav.reorder): one bad time stamp would
    otherwise keep the loop awake for every message until the stream caught up with it."""

    def __init__(self, reorder_window_s: float, outlier_s: float = math.inf, confirm_n: int = 1) -> None:
        self.horizon_s = reorder_window_s
        self.outlier_s = outlier_s
        self.confirm_n = confirm_n
        self._ahead: list[float] = []  # times far ahead of the newest, waiting for confirmation
        #: the navigator's next tick, published by the loop; nothing waits until it is finite (a fix scheduled it)
        self.next_output_s = -math.inf
        self._tick = -math.inf  # the tick _first was found for
        self._first = -math.inf  # the earliest event time seen after it
        self._newest_s = -math.inf  # the newest event time seen
        self._recent: deque[float] = deque()  # event times seen, in arrival order, back to newest - horizon - KEEP_S
        self._forgot_s = -math.inf  # the latest time dropped from _recent
        self._led = math.nan  # the first event after the tick whose output the loop was last woken ahead of

    def may_wait(self, events: list[Event]) -> bool:
        h = self.horizon_s
        tick = self.next_output_s
        if tick != self._tick:
            self._tick = tick
            self._first = (-math.inf if self._forgot_s > tick else
                           min((t for t in self._recent if t > tick), default=math.inf))
        first, newest, recent = self._first, self._newest_s, self._recent
        ok = True
        ahead = self._ahead
        for ev in events:
            t = ev.t_s
            if newest != -math.inf and t > newest + self.outlier_s:
                ok = False  # the navigator holds it (and the loop looks at it at once)
                if ahead and abs(t - ahead[0]) > self.outlier_s:
                    del ahead[:]
                ahead.append(t)
                if len(ahead) < self.confirm_n:
                    continue
                times = list(ahead)  # the stream really jumped
                del ahead[:]
            else:
                if ahead:
                    del ahead[:]  # back on the stream clock: they were outliers (the navigator drops them)
                times = (t,)
            for t in times:
                recent.append(t)
                if t > newest:
                    newest = t
                if tick < t < first:
                    first = t
            # the navigator releases every event up to newest - h: the tick goes once the first after it is among them
            if type(ev) not in MAY_WAIT or not first > newest - h:
                ok = False
        if not math.isfinite(tick):
            ok = False  # before the first output is scheduled (by a fix the navigator has not yet released): take all
        if ok and newest > first + h - LEAD_S and first != self._led:
            self._led = first  # once per output: run what waited now, not when the output is due
            ok = False
        self._first, self._newest_s = first, newest
        while recent and (not recent[0] >= newest - h - KEEP_S or len(recent) > MAX_KEPT):
            self._forgot_s = max(self._forgot_s, recent.popleft())
        return ok
