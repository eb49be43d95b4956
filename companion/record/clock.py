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

Leap seconds come from the IANA tz database's ``leap-seconds.list`` (Debian package ``tzdata``, kept
up to date by the OS), read at import; a built-in table (to the 2017-01-01 leap second) serves when
that file is absent. astropy (with its IERS tables) would also know them but is a large dependency
that wants to download its tables at run time; the tz database is already on every Debian machine.
"""

from __future__ import annotations

import bisect
import calendar
import math
import time
from pathlib import Path
from typing import Any

from companion.constants import GPS_EPOCH_UNIX_S, WEEK_S

LEAP_SECONDS_FILE = Path("/usr/share/zoneinfo/leap-seconds.list")
_NTP_TO_UNIX_S = 2208988800  # 1900-01-01 -> 1970-01-01
_TAI_MINUS_GPS_S = 19

#: (UTC date, GPS - UTC in s from then on): the leap seconds since the GPS epoch.
_BUILTIN = [
    ((1981, 7, 1), 1), ((1982, 7, 1), 2), ((1983, 7, 1), 3), ((1985, 7, 1), 4), ((1988, 1, 1), 5),
    ((1990, 1, 1), 6), ((1991, 1, 1), 7), ((1992, 7, 1), 8), ((1993, 7, 1), 9), ((1994, 7, 1), 10),
    ((1996, 1, 1), 11), ((1997, 7, 1), 12), ((1999, 1, 1), 13), ((2006, 1, 1), 14), ((2009, 1, 1), 15),
    ((2012, 7, 1), 16), ((2015, 7, 1), 17), ((2017, 1, 1), 18),
]


def _load_table(path: Path = LEAP_SECONDS_FILE) -> tuple[list[int], list[int], str]:
    """(Unix times of the steps, GPS - UTC from each step, where the table came from)."""
    try:
        rows = []
        for line in path.read_text(encoding="ascii").splitlines():
            parts = line.split("#", 1)[0].split()
            if len(parts) >= 2:
                rows.append((int(parts[0]) - _NTP_TO_UNIX_S, int(parts[1]) - _TAI_MINUS_GPS_S))
        rows = [(t, n) for t, n in rows if n > 0]
        if rows:
            return [t for t, _ in rows], [n for _, n in rows], str(path)
    except (OSError, ValueError):
        pass
    steps = [calendar.timegm((y, m, d, 0, 0, 0)) for (y, m, d), _ in _BUILTIN]
    return steps, [n for _, n in _BUILTIN], "built-in table (to 2017-01-01)"


_STEPS, _LEAPS, LEAP_SOURCE = _load_table()


def gps_minus_utc_s(unix_s: float) -> int:
    """Leap seconds between GPS time and UTC at a UTC instant (0 before 1981-07-01)."""
    i = bisect.bisect_right(_STEPS, unix_s)
    return _LEAPS[i - 1] if i else 0


def gps_to_unix_s(week: int, tow_s: float) -> float:
    """UTC Unix time of a GPS week and time of week."""
    gps_as_unix = GPS_EPOCH_UNIX_S + week * WEEK_S + tow_s
    return gps_as_unix - gps_minus_utc_s(gps_as_unix - gps_minus_utc_s(gps_as_unix))


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

    def observe(self, item: Any) -> None:
        if self.offset_ns is not None:
            return
        got = utc_of(item)
        if got is not None:
            unix_s, self.source = got
            self.offset_ns = round(unix_s * 1e9) - round(item.t_s * 1e9)
            self.first_utc_t_s = item.t_s

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
        meta["payload_time"] = "t_s: vehicle time in s since autopilot boot (running on through reboots)"
        meta["leap_seconds"] = LEAP_SOURCE
        return meta


async def _first_utc(source) -> tuple[int, str] | None:
    try:
        async for ev in source:
            got = utc_of(ev)
            if got is not None:
                return round(got[0] * 1e9) - round(ev.t_s * 1e9), got[1]
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
