"""The record's clock: MCAP log times in UTC (Unix epoch ns) once the vehicle's UTC is known.

Payloads keep the vehicle's boot-based time ``t_s``; only the MCAP ``log_time``/``publish_time`` move
to UTC, so a record lines up with other recordings of the same flight (a ROS bag, a GCS tlog, video).
The relation ``unix_ns = round(t_s * 1e9) + offset_ns`` is taken once, from the first of

* a GNSS fix with GPS week and time of week (``GnssFix.gps_week``/``gps_tow_s``: dataflash GPS rows),
  converted with the leap seconds in force at that date (:func:`gps_minus_utc_s`), or
* ``SYSTEM_TIME`` (``companion.events.SystemTime``: the autopilot's UTC),

and then kept for the whole record (also across autopilot reboots: ``t_s`` runs on through them), so
the record stays deterministic. A replay looks ahead for that first time (:func:`find_utc_offset`), so
its record is in UTC from the first message on. A live run learns it on the way; messages before
that (link events before the first vehicle message, or a vehicle without GPS time yet) get the host's
UTC clock, marked in the ``clock`` metadata record, instead of all being stamped 0.

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

    def log_ns(self, t_ns: int) -> int:
        if self.offset_ns is not None:
            return max(0, t_ns + self.offset_ns)
        self.before_utc += 1
        return time.time_ns() if self.host_fallback else t_ns

    def metadata(self) -> dict[str, str]:
        if self.offset_ns is None:
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
