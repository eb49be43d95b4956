"""Many MAVLink 2 frames of one message a second from Python: what the live-link fuzzer's bursts are made of."""

from __future__ import annotations

import copy

import numpy as np


class FastFrames:
    """MAVLink 2 frames of one message whose leading uint64 time stamp (and sequence number) change, built without
    pymavlink's per-byte CRC loop (30 us a frame): the CRC is affine in the frame's bytes over GF(2), so the
    contribution of each value of each changing byte is tabled once."""

    def __init__(self, msg, mav) -> None:
        from pymavlink.generator.mavcrc import x25crc

        m = copy.copy(msg)
        m.time_usec = 0
        seq = mav.seq
        mav.seq = 0
        frame = bytearray(m.pack(mav))
        mav.seq = seq
        self.mav = mav
        if frame[0] != 0xFD:
            raise ValueError("FastFrames builds MAVLink 2 frames")
        self.frame0 = frame
        self.crc0 = frame[-2] | frame[-1] << 8
        body = len(frame) - 3  # frame[1:-2], the bytes the CRC covers (then the message's CRC_EXTRA)

        def crc(pos: int, v: int) -> int:
            b = bytearray(body + 1)  # + the CRC_EXTRA byte, zero in the difference
            if pos >= 0:
                b[pos] = v
            return x25crc(bytes(b)).crc

        zero = crc(-1, 0)
        self._seq_tab = np.array([crc(3, v) ^ zero for v in range(256)], dtype=np.uint16)  # frame[4]
        self._time_tabs = np.array([[crc(9 + i, v) ^ zero for v in range(256)] for i in range(8)],
                                   dtype=np.uint16)  # frame[10:18]

    def frames(self, times_us: list[int]) -> bytes:
        n = len(times_us)
        seq = (self.mav.seq + np.arange(n)) % 256
        self.mav.seq = int((self.mav.seq + n) % 256)
        tb = np.asarray(times_us, dtype=np.uint64).astype("<u8").view(np.uint8).reshape(n, 8)
        crc = np.full(n, self.crc0, dtype=np.uint16) ^ self._seq_tab[seq]
        for i in range(8):
            crc ^= self._time_tabs[i][tb[:, i]]
        f = np.tile(np.frombuffer(bytes(self.frame0), dtype=np.uint8), (n, 1))
        f[:, 4] = seq
        f[:, 10:18] = tb
        f[:, -2] = crc & 0xFF
        f[:, -1] = crc >> 8
        return f.tobytes()
