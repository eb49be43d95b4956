"""Load shedding before the MAVLink parser: IMU frames thinned at the byte level while the reader is behind.

pymavlink's parser costs about 35 us a frame in pure Python (its CRC loops over every byte): a burst of tens of
thousands of frames a second is more than one core can parse, the socket's queue grows and everything behind it
arrives seconds late. :class:`ImuShedder` walks the raw bytes (header, length and message id only, no CRC) and
removes the IMU frames (RAW_IMU, SCALED_IMU, SCALED_IMU2/3, HIGHRES_IMU) that come less than ``min_interval_s`` (their own
time stamp) after the last one kept from the same sender; everything else, including what it cannot frame
(garbage, a frame cut by the end of the buffer), passes through untouched for the parser to judge.

Pure: bytes in, bytes out, no I/O, no clock.
"""

from __future__ import annotations

import re

#: message id -> (time stamp bytes at the start of the payload, seconds per unit)
IMU_TIME = {27: (8, 1e-6), 26: (4, 1e-3), 116: (4, 1e-3), 129: (4, 1e-3), 105: (8, 1e-6)}
_MAGIC = re.compile(b"[\xfd\xfe]")
_V2, _V1 = 0xFD, 0xFE


class ImuShedder:
    """``filter(data)`` -> ``data`` without the IMU frames that come too soon; counts in ``shed`` / ``kept``."""

    def __init__(self, min_interval_s: float) -> None:
        self.min_interval_s = min_interval_s
        self.shed = 0
        self.kept = 0
        self._last_s: dict[tuple[int, int, int], float] = {}  # (system, component, message id) -> time kept

    def reset(self) -> None:
        """Forget the last kept times (a new episode starts from whatever arrives first)."""
        self._last_s.clear()

    def filter(self, data: bytes) -> bytes:
        n = len(data)
        parts: list[bytes] = []
        start = 0  # first byte not yet copied to parts
        search, imu_time, last_s, min_s = _MAGIC.search, IMU_TIME, self._last_s, self.min_interval_s
        j = 0
        while j < n:
            magic = data[j]
            if magic != _V2 and magic != _V1:
                m = search(data, j + 1)
                if m is None:
                    break
                j = m.start()
                continue
            if magic == _V2:
                if j + 10 > n:
                    break
                plen, flags = data[j + 1], data[j + 2]
                end = j + 12 + plen + (13 if flags & 1 else 0)
                msgid = data[j + 7] | data[j + 8] << 8 | data[j + 9] << 16 if flags <= 1 else -1
                head, src = j + 10, j + 5
            else:
                if j + 6 > n:
                    break
                plen = data[j + 1]
                end = j + 8 + plen
                msgid = data[j + 5]
                head, src = j + 6, j + 3
            if end > n:
                break  # cut by the end of the read: the parser keeps it for the next one
            if end < n and data[end] != _V2 and data[end] != _V1:
                j += 1  # not a frame boundary (garbage, or a magic byte inside a payload): look further
                continue
            spec = imu_time.get(msgid)
            if spec is not None:
                size, unit_s = spec
                stamp = int.from_bytes(data[head:head + min(size, plen)], "little") * unit_s  # zeros trimmed: 0
                key = (data[src], data[src + 1], msgid)
                last = last_s.get(key)
                if last is not None and 0.0 <= stamp - last < min_s:
                    parts.append(data[start:j])
                    start = end
                    self.shed += 1
                else:
                    last_s[key] = stamp
                    self.kept += 1
            j = end
        if not parts:
            return data
        parts.append(data[start:])
        return b"".join(parts)
