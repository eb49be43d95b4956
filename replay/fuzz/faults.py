"""The live-link fuzzer's faults: what the hostile autopilot (replay.fuzz.link.Peer) does on its play clock.

Each :class:`Fault` starts ``at_s`` after the first fresh GPS_INPUT and lasts ``duration_s``: garbage bytes, frames
with a bad CRC, MAVLink 1 frames among MAVLink 2, edited fields (extreme, NaN, a time far ahead or behind), a burst
of thousands of RAW_IMU a second, a silent link whose backlog then arrives at once, an autopilot reboot, a SIGTERM.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from replay.fuzz.frames import FastFrames


class FaultPeer(Protocol):
    """What a fault may do with the autopilot peer that plays it (replay.fuzz.link.Peer)."""

    rng: np.random.Generator

    def write(self, data: bytes) -> None: ...

    def pack(self, msg, src=(1, 1), force_mavlink1: bool = False) -> bytes: ...

    def packer(self, src=(1, 1)) -> Any: ...

    def newest(self, mtype: str) -> Any: ...

    def sigterm(self) -> None: ...

    def reboot(self) -> None: ...


@dataclass
class Fault:
    """Something the peer does on the play clock, ``at_s`` after the first fresh GPS_INPUT, for ``duration_s``."""

    at_s: float
    duration_s: float = 0.0
    started: bool = field(default=False, init=False)
    done: bool = field(default=False, init=False)
    t0: float = field(default=0.0, init=False)  # play time it started

    @property
    def name(self) -> str:
        return type(self).__name__

    def begin(self, peer: FaultPeer, now: float) -> None:  # once, when at_s is reached
        pass

    def step(self, peer: FaultPeer, now: float) -> None:  # every loop iteration while active
        pass

    def transform(self, peer: FaultPeer, frame: bytes, msg) -> bytes:  # a stream frame while active
        return frame

    def end(self, peer: FaultPeer, now: float) -> None:  # once, when its duration is over
        pass


class Garbage(Fault):
    """Random bytes between frames, ``bytes_per_s`` of them."""

    def __init__(self, at_s, duration_s=5.0, bytes_per_s=20_000):
        super().__init__(at_s, duration_s)
        self.rate = bytes_per_s
        self._sent = 0

    def step(self, peer, now):
        due = int(self.rate * (now - self.t0)) - self._sent
        if due >= 64:
            peer.write(peer.rng.bytes(due))
            self._sent += due


class BadCrc(Fault):
    """Every ``every``-th stream frame with its CRC broken (dropped as a bad frame, never decoded)."""

    def __init__(self, at_s, duration_s=5.0, every=3):
        super().__init__(at_s, duration_s)
        self.every, self._n = every, 0

    def transform(self, peer, frame, msg):
        self._n += 1
        if self._n % self.every:
            return frame
        b = bytearray(frame)
        b[-1] ^= 0x5A
        return bytes(b)


class Mavlink1(Fault):
    """Every other stream frame sent as MAVLink 1 (pymavlink's own v1 encoding)."""

    def __init__(self, at_s, duration_s=5.0):
        super().__init__(at_s, duration_s)
        self._n = 0

    def transform(self, peer, frame, msg):
        self._n += 1
        if self._n % 2 or msg.get_msgId() > 255:
            return frame
        return peer.pack(msg, force_mavlink1=True)


class Inject(Fault):
    """Extra messages built from the newest stream message of a type: ``edits`` {type: [(field, value), ...]}
    -- each (field, value) one message -- sent ``repeat_hz`` times a second for ``duration_s`` (0: once).
    A value "+30s"/"-10s" moves the message's own boot time."""

    def __init__(self, at_s, edits: dict[str, list[tuple[str, object]]], duration_s=0.0, repeat_hz=5.0):
        super().__init__(at_s, duration_s)
        self.edits, self.repeat_hz, self._next = edits, repeat_hz, 0.0
        self.sent = 0

    def begin(self, peer, now):
        self._next = now

    def step(self, peer, now):
        if now < self._next:
            return
        for mtype, changes in self.edits.items():
            for fname, value in changes:
                msg = peer.newest(mtype)
                if msg is None:
                    continue
                msg = copy.copy(msg)
                if isinstance(value, str) and value.endswith("s"):
                    shift = float(value[:-1])
                    tf = "time_boot_ms" if hasattr(msg, "time_boot_ms") else "time_usec"
                    scale = 1e3 if tf == "time_boot_ms" else 1e6
                    setattr(msg, tf, max(0, int(getattr(msg, tf) + shift * scale)))
                else:
                    setattr(msg, fname, value)
                peer.write(peer.pack(msg))
                self.sent += 1
        self._next = now + 1.0 / self.repeat_hz if self.duration_s > 0 else math.inf


class Burst(Fault):
    """RAW_IMU at ``rate`` messages a second on top of the stream, boot time advancing with the play clock.

    At most :data:`BURST_STEP_S` of the schedule is packed per play-loop step, so the stream goes on between chunks
    however slow the peer is (a peer busy packing seconds of burst at once would starve its own stream and the test
    would judge the peer); what the peer could not send is not made up later (``sent`` counts what went)."""

    def __init__(self, at_s, duration_s=3.0, rate=14_000, chunk=40):
        super().__init__(at_s, duration_s)
        self.rate, self.chunk, self.sent = rate, chunk, 0
        self._scheduled = 0  # frames the schedule has reached (sent or given up)
        self._frames: FastFrames | None = None

    def step(self, peer, now):
        due = int(self.rate * (now - self.t0)) - self._scheduled
        if due < self.chunk:
            return
        tmpl = peer.newest("RAW_IMU")
        if tmpl is None:
            return
        if self._frames is None:
            self._frames = FastFrames(tmpl, peer.packer((1, 1)))
        n = min(due, max(self.chunk, int(self.rate * BURST_STEP_S)))
        peer.write(self._frames.frames([int((now - (n - k) / self.rate) * 1e6) for k in range(n)]))
        self._scheduled += due  # the schedule moves on: a peer that fell behind does not pile up a backlog of its own
        self.sent += n


#: the longest stretch of a burst's schedule packed in one play-loop step
BURST_STEP_S = 0.01


class Sigterm(Fault):
    """SIGTERM to the companion."""

    def begin(self, peer, now):
        peer.sigterm()


class Silence(Fault):
    """The link goes silent for ``duration_s`` (a radio fade: the companion declares it lost and reconnects), then
    everything held back arrives at once, oldest first, before the live stream goes on: a burst of seconds-old
    messages whose bytes are new."""

    def __init__(self, at_s, duration_s=4.0):
        super().__init__(at_s, duration_s)
        self._held: list[bytes] = []
        self.held = 0
        self.burst_mono: float | None = None  # when the backlog went out (time.monotonic)

    def transform(self, peer, frame, msg):
        self._held.append(frame)
        self.held += 1
        return b""

    def end(self, peer, now):
        peer.write(b"".join(self._held))
        self._held.clear()
        self.burst_mono = time.monotonic()


class Reboot(Fault):
    """The autopilot reboots: silent for ``duration_s`` (its start-up), then its boot clock starts again near 0
    (every later message's boot time moves back by what it had reached) while the vehicle goes on."""

    def transform(self, peer, frame, msg):
        return b""  # what it would have sent while restarting is never sent

    def end(self, peer, now):
        peer.reboot()
