"""GPS time and UTC: leap seconds by date, GPS week / time of week.

GPS time runs without leap seconds from its epoch 1980-01-06T00:00:00Z; UTC has had 18 since (2017-01-01). The
leap seconds come from the IANA tz database's ``leap-seconds.list`` (Debian package ``tzdata``, kept up to date by
the OS), read at import; a built-in table (to the 2017-01-01 leap second) serves when that file is absent. Python
packages that know leap seconds either read that same file (``leapseconddata``, which falls back to downloading
the list, impossible on a vehicle without a network) or carry their own large tables (astropy with its IERS data):
a 15-line reader of the file the OS maintains is the smaller dependency.
"""

from __future__ import annotations

import bisect
import calendar
from pathlib import Path

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


def gps_week_from_unix(unix_s: float) -> tuple[int, int]:
    """(GPS week, milliseconds of week) of a UTC Unix time, with the leap seconds in force then."""
    return split_gps_s(unix_s - GPS_EPOCH_UNIX_S + gps_minus_utc_s(unix_s))


def split_gps_s(gps_s: float) -> tuple[int, int]:
    """(GPS week, milliseconds of week) of seconds since the GPS epoch."""
    week = int(gps_s // WEEK_S)
    ms = int(round((gps_s - week * WEEK_S) * 1000.0))
    if ms >= WEEK_S * 1000:
        week, ms = week + 1, ms - WEEK_S * 1000
    return week, ms
