"""The record's clock: MCAP log times in UTC (Unix epoch ns) once the vehicle's UTC is known.

Payloads keep the vehicle's boot-based time ``t_s``; only the MCAP ``log_time``/``publish_time`` move
to UTC, so a record lines up with other recordings of the same flight (a ROS bag, a GCS tlog, video).
The relation ``unix_ns = round(t_s * 1e9) + offset_ns`` is taken once, from the first of

* a GNSS fix with GPS week and time of week (``GnssFix.gps_week``/``gps_tow_s``: dataflash GPS rows),
  converted with the leap seconds in force at that date (:func:`gps_minus_utc_s`), or
* ``SYSTEM_TIME`` (``companion.events.SystemTime``: the autopilot's UTC),

and then kept for the whole record (also across autopilot reboots: ``t_s`` runs on through them), so
the record stays deterministic. A replay looks ahead for that first time (:func:`find_utc_offset`), so
its record is in UTC from the first message on. A live run learns it on the way: :class:`UtcHold` holds what
comes before (link events, a vehicle without GPS time yet) and writes it in UTC once it is known, so one record
never mixes clocks (the host's clock, on a computer without a real-time clock or before NTP, can be years off the
vehicle's). If the vehicle's UTC is not known within :data:`HOLD_S` of vehicle time, the whole record is in vehicle
boot time instead; the ``clock`` metadata record says which.

Leap seconds: :mod:`companion.gpstime` (the tz database's list, kept up to date by the OS).
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from typing import Any

from companion.gpstime import LEAP_SOURCE, gps_minus_utc_s, gps_to_unix_s

_log = logging.getLogger(__name__)
#: a host clock further than this from the vehicle's UTC is worth a warning (its early stamps are off by that much)
HOST_CLOCK_TOLERANCE_S = 2.0

__all__ = ["RecordClock", "find_utc_offset", "gps_minus_utc_s", "gps_to_unix_s", "utc_of", "LEAP_SOURCE"]

def utc_of(item: Any) -> tuple[float, str] | None:
    """(Unix time at ``item.t_s``, how it is known) for an event that tells the vehicle's UTC, else None."""
    week = getattr(item, "gps_week", None)
    tow = getattr(item, "gps_tow_s", None)
    if isinstance(week, int) and week > 0 and tow is not None and math.isfinite(tow) and tow >= 0:
        return gps_to_unix_s(week, tow), "GPS week and time of week"
    unix = getattr(item, "unix_time_s", None)
    if type(item).__name__ == "SystemTime" and unix is not None and math.isfinite(unix) and unix > 0:
        return float(unix), "SYSTEM_TIME"
    return None


def _unix_ns(unix_s: float) -> int:
    """A UTC time in ns at the microsecond its sources give (SYSTEM_TIME: us, GPS time of week: ms): a float of
    ~1.7e9 s holds only ~0.2 us, so ``round(unix_s * 1e9)`` would put 2025-03-15T01:30:00 at 01:29:59.999999936."""
    return round(unix_s * 1e6) * 1000


class RecordClock:
    """Vehicle time -> MCAP log time. ``offset_ns`` None: UTC not known (yet).

    :param offset_ns: known UTC offset (a replay's look-ahead), fixed for the record.
    :param host_fallback: a live run: before the UTC is known, stamp messages with the host's UTC clock
        (``time.time_ns``) instead of boot time; False keeps boot time (deterministic replays).
    """

    def __init__(self, offset_ns: int | None = None, source: str = "", *, host_fallback: bool = False):
        self.offset_ns = offset_ns
        self.source = source if offset_ns is not None else ""
        self.host_fallback = host_fallback
        self.before_utc = 0  # messages stamped before the UTC was known
        self.first_utc_t_s: float | None = None if offset_ns is None else -math.inf
        self.host_minus_vehicle_s: float | None = None  # host clock - vehicle UTC when the latter became known (live)

    def observe(self, item: Any) -> None:
        if self.offset_ns is not None:
            return
        got = utc_of(item)
        if got is not None:
            unix_s, self.source = got
            self.offset_ns = _unix_ns(unix_s) - round(item.t_s * 1e9)
            self.first_utc_t_s = item.t_s
            if self.host_fallback:
                # what the messages stamped before now are off by (arrival latency aside): a host without a synced
                # clock (no RTC, no network) puts them far from the rest of the record
                self.host_minus_vehicle_s = time.time() - unix_s
                if self.before_utc and abs(self.host_minus_vehicle_s) > HOST_CLOCK_TOLERANCE_S:
                    _log.warning("the host clock is %.0f s off the vehicle's UTC (%s): the %d messages recorded before "
                                 "it was known carry the host's time", self.host_minus_vehicle_s, self.source,
                                 self.before_utc)

    def use_boot_time(self, why: str) -> None:
        """Commit the record to vehicle boot time (its UTC is not known soon enough): one clock throughout."""
        if self.offset_ns is None:
            self.offset_ns, self.source, self.boot_time = 0, why, True

    boot_time = False  # committed to vehicle boot time (use_boot_time)

    def log_ns(self, t_ns: int) -> int:
        if self.offset_ns is not None:
            return max(0, t_ns + self.offset_ns)
        self.before_utc += 1
        return time.time_ns() if self.host_fallback else t_ns

    def metadata(self) -> dict[str, str]:
        if self.boot_time:
            meta = {"log_time": f"vehicle boot time ns ({self.source})"}
        elif self.offset_ns is None:
            meta = {"log_time": "vehicle boot time ns (no GPS time or SYSTEM_TIME seen)" if not self.host_fallback
                    else "host UTC clock, Unix epoch ns (the vehicle's UTC was never known)"}
        else:
            meta = {
                "log_time": "UTC, Unix epoch ns",
                "utc_source": self.source,
                "utc_offset_ns": str(self.offset_ns),
                "utc_offset_definition": "log_time = round(t_s * 1e9) + utc_offset_ns",
            }
            if self.before_utc:
                meta["before_utc"] = (f"{self.before_utc} earlier messages stamped "
                                      + ("with the host UTC clock" if self.host_fallback else "with boot time"))
            if self.host_minus_vehicle_s is not None:
                meta["host_clock_minus_vehicle_utc_s"] = f"{self.host_minus_vehicle_s:.3f}"
        meta["payload_time"] = "t_s: vehicle time in s since autopilot boot (running on through reboots)"
        meta["leap_seconds"] = LEAP_SOURCE
        return meta


#: how long (vehicle time) a live record holds its messages waiting for the vehicle's UTC, and how many at most
HOLD_S = 30.0
HOLD_MAX = 200_000


class UtcHold:
    """A live recorder's front (``Recorder`` or ``RotatingRecorder`` with ``clock``): every write is held until the
    vehicle's UTC is known (then all go in UTC, in order), or until :data:`HOLD_S` of vehicle time has passed without
    it (then the record is in vehicle boot time throughout). Anything else is the recorder's own."""

    def __init__(self, recorder: Any, clock: RecordClock, hold_s: float = HOLD_S, max_held: int = HOLD_MAX) -> None:
        self.recorder, self.clock = recorder, clock
        self.hold_s, self.max_held = hold_s, max_held
        self._held: list[tuple[Any, tuple, dict]] | None = []  # None: released
        self._first_t: float | None = None

    def _put(self, fn, t_s: float, args: tuple, kw: dict) -> None:
        if self._held is None:
            fn(*args, **kw)
            return
        self._held.append((fn, args, kw))
        if self._first_t is None and math.isfinite(t_s):
            self._first_t = t_s
        if self.clock.offset_ns is None and (len(self._held) >= self.max_held or (
                self._first_t is not None and math.isfinite(t_s) and t_s - self._first_t > self.hold_s)):
            self.clock.use_boot_time(f"the vehicle's UTC was not known within {self.hold_s:g} s of vehicle time: "
                                     "one clock for the whole record")
            _log.warning("no GPS time or SYSTEM_TIME from the vehicle in %g s: the record is in vehicle boot time",
                         self.hold_s)
        if self.clock.offset_ns is not None:
            self.release()

    def release(self) -> None:
        """Write what is held (in UTC if known, else committing the record to boot time)."""
        if self._held is None:
            return
        if self.clock.offset_ns is None:
            self.clock.use_boot_time("the vehicle's UTC was never known: one clock for the whole record")
        held, self._held = self._held, None
        for fn, args, kw in held:
            fn(*args, **kw)

    def write(self, item: Any, topic: str | None = None) -> None:
        self.clock.observe(item)
        self._put(self.recorder.write, getattr(item, "t_s", math.nan), (item, topic), {})

    def write_dict(self, topic, schema_name, json_schema, payload, t_s: float) -> None:
        self._put(self.recorder.write_dict, t_s, (topic, schema_name, json_schema, payload, t_s), {})

    def write_location(self, topic: str, t_s: float, *args: Any, **kw: Any) -> None:
        self._put(self.recorder.write_location, t_s, (topic, t_s, *args), kw)

    def write_log(self, topic: str, t_s: float, *args: Any, **kw: Any) -> None:
        self._put(self.recorder.write_log, t_s, (topic, t_s, *args), kw)

    def close(self) -> None:
        self.release()
        self.recorder.close()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.recorder, name)


async def _first_utc(source) -> tuple[int, str] | None:
    try:
        async for ev in source:
            got = utc_of(ev)
            if got is not None:
                return _unix_ns(got[0]) - round(ev.t_s * 1e9), got[1]
    finally:
        await source.aclose()
    return None


def find_utc_offset(path: Path) -> tuple[int, str] | None:
    """Look ahead in a log for its first GPS time or SYSTEM_TIME: (offset ns, source) or None.

    Reads the log until the first such message (the whole log if it has none); errors in the log are
    left to the main pass to report.
    """
    import asyncio

    from companion.sources import FileSource

    try:
        return asyncio.run(_first_utc(FileSource(path)))
    except Exception:  # noqa: BLE001 - a damaged log is reported by the replay itself
        return None
