"""What the simulated vehicle plays: a generated flight (companion.sim.flight, optionally with a gravimeter's
NAMED_VALUE_FLOAT readings) or a telemetry log, as time-stamped MAVLink messages on the playback clock (the
source's boot time). A long flight is framed a chunk of playback time at a time (`LazyItems`), so its hundreds of
thousands of message objects never all exist at once."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from companion import units

_EPOCH_US = 1e15
#: streams an ArduPilot sends whatever was requested
_ALWAYS = ("HEARTBEAT", "STATUSTEXT", "NAMED_VALUE_FLOAT")
_STREAMED = ("SYSTEM_TIME", "GPS_RAW_INT", "GPS2_RAW", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "ATTITUDE",
             "GLOBAL_POSITION_INT")


@dataclass
class Item:
    play_s: float
    msg: Any
    src: tuple[int, int]
    boot_s: float | None = None  # the message's own boot time (None: it has none)
    unix_us: int | None = None  # SYSTEM_TIME's UTC

    def __post_init__(self) -> None:
        m = self.msg
        if hasattr(m, "time_boot_ms"):
            self.boot_s = m.time_boot_ms * 1e-3
        elif hasattr(m, "time_usec") and 0 < m.time_usec < _EPOCH_US:
            self.boot_s = m.time_usec * 1e-6
        if hasattr(m, "time_unix_usec"):
            self.unix_us = int(m.time_unix_usec)


class LazyItems:
    """Items built a chunk of playback time at a time: ``build(t0, t1)`` returns the items with t0 <= play_s < t1,
    in order. Iterating holds one chunk; ``end_s`` is the last item's time."""

    def __init__(self, build: Callable[[float, float], list[Item]], end_s: float, chunk_s: float = 5.0) -> None:
        if chunk_s <= 0:
            raise ValueError("chunk_s must be positive")
        self.build, self.end_s, self.chunk_s = build, float(end_s), float(chunk_s)

    def window(self, start_s: float, end_s: float) -> Iterator[Item]:
        """Items with start_s <= play_s <= end_s, in order."""
        k = max(0, int(math.floor(start_s / self.chunk_s)))
        last = min(end_s, self.end_s)
        while k * self.chunk_s <= last:
            t1 = (k + 1) * self.chunk_s
            for it in self.build(k * self.chunk_s, t1 if t1 <= self.end_s else math.inf):
                if it.play_s > end_s:
                    return
                if it.play_s >= start_s:
                    yield it
            k += 1

    def __iter__(self) -> Iterator[Item]:
        return self.window(0.0, math.inf)


def _window(items, start_s: float, end_s: float) -> Iterator[Item]:
    if isinstance(items, LazyItems):
        return items.window(start_s, end_s)
    return (it for it in items if start_s <= it.play_s <= end_s)


@dataclass
class Playback:
    """Messages on the playback clock (a list, or :class:`LazyItems`) and the truth position as a function of it."""

    items: Sequence[Item] | LazyItems
    truth: Callable[[float], tuple[float, float, float] | None]  # play_s -> (lat, lon, alt_msl) or None
    description: str
    arm_s: float | None = None  # when the flight arms (playback s; None: never, or unknown)

    @property
    def duration_s(self) -> float:
        if isinstance(self.items, LazyItems):
            return self.items.end_s
        return self.items[-1].play_s if self.items else 0.0


def _v2(msg):
    """A pymavlink message as the MAVLink 2 ardupilotmega class (extension fields 0 when absent)."""
    cls = mavlink2.mavlink_map[msg.get_msgId()]
    vals = [getattr(msg, f, 0) for f in cls.fieldnames]
    return cls(*[v.encode("latin-1", "replace") if isinstance(v, str) else v for v in vals])


def gravity_readings(profile, lmap, *, hz: float = 1.0, sigma_mgal: float = 1.0, seed: int = 0,
                     offset_s: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Simulated gravimeter readings along a generated flight: (boot times s, anomaly mGal) every 1/hz from
    ``offset_s``, the map value at the true position plus Gaussian noise (seeded); readings off the map are left out.

    The truth lat/lon is mapped onto the map with the map's own frame (an identity Placement): the flight is
    where its profile says it is on the Earth.
    """
    from companion.gravity.placement import Placement
    from companion.sim.gravimeter import SimulatedGravimeter

    if not hz > 0:
        raise ValueError("gravity rate must be positive")
    if lmap.frame is None:
        raise ValueError("the gravity map must be geographic (lat/lon axes) to fly a generated flight over it")
    n = int(math.floor((profile.duration_s - offset_s) * hz + 1e-9)) + 1
    t = offset_s + np.arange(max(n, 0)) / hz
    tr = profile.sample(t)
    ne = lmap.frame.to_ned_m(tr.lat_deg, tr.lon_deg, 0.0)[:, :2]
    grav = SimulatedGravimeter(lmap, Placement(), np.random.default_rng(seed), sigma_mgal=sigma_mgal)
    keep_t, keep_v = [], []
    for tk, p in zip(t, ne):
        r = grav.read(float(tk), p)
        if r is not None:
            keep_t.append(float(tk))
            keep_v.append(r.gravity_mgal)
    return np.asarray(keep_t), np.asarray(keep_v)


def playback_from_flight(flight=None, *, gravity: tuple[np.ndarray, np.ndarray] | None = None,
                         gravity_name: str = "GRAV", lazy: bool | None = None, chunk_s: float = 5.0) -> Playback:
    """A generated flight (default: the project's sample flight); truth from its trajectory.

    ``gravity``: (boot times, mGal) from :func:`gravity_readings`, sent as NAMED_VALUE_FLOAT ``gravity_name``.
    ``lazy`` (default: flights over 10 minutes) frames the messages ``chunk_s`` of playback time at a time.
    """
    from companion.sim.flight import sample_flight
    from companion.sim.mavlink_out import baro_error_m, telemetry_messages

    flight = flight or sample_flight()
    berr = baro_error_m(flight)  # GLOBAL_POSITION_INT (sent only when requested: streams="requested")

    def build(t0: float, t1: float) -> list[Item]:
        msgs = telemetry_messages(flight, gcs=True, gravity=gravity, gravity_name=gravity_name,
                                  t_range=None if (t0, t1) == (-math.inf, math.inf) else (t0, t1),
                                  global_position=True, baro_err_m=berr)
        return [Item(o.boot_us * 1e-6, o.msg, (o.src_system, o.src_component)) for o in msgs]

    if lazy is None:
        lazy = flight.duration_s > 600.0
    if lazy:
        last = build(max(0.0, flight.duration_s - 2.0), math.inf)  # the last message's time (GCS heartbeat, ...)
        items: Sequence[Item] | LazyItems = LazyItems(build, last[-1].play_s if last else 0.0, chunk_s)
    else:
        items = build(-math.inf, math.inf)
    profile = flight.profile

    def truth(t: float):
        if not 0.0 <= t <= profile.duration_s:
            return None
        tr = profile.sample(t)
        return float(tr.lat_deg[0]), float(tr.lon_deg[0]), float(tr.alt_msl_m[0])

    return Playback(items, truth, f"generated flight ({flight.duration_s:.0f} s, seed {flight.seed})", flight.armed_s[0])


def playback_from_tlog(path: str | Path) -> Playback:
    """A telemetry log; truth from the log's own GPS_RAW_INT positions (interpolated, 3D fixes only)."""
    from pymavlink import mavutil

    log = mavutil.mavlogfile(str(path), robust_parsing=True)
    items: list[Item] = []
    autopilot: tuple[int, int] | None = None
    gps_t, gps_pos = [], []
    t0 = arm_s = None
    while True:
        m = log.recv_msg()
        if m is None:
            break
        mtype = m.get_type()
        if mtype == "BAD_DATA" or mtype not in _ALWAYS + _STREAMED:
            continue
        src = (m.get_srcSystem(), m.get_srcComponent())
        if autopilot is None:
            if mtype == "HEARTBEAT" and m.autopilot != mavlink2.MAV_AUTOPILOT_INVALID and m.type != mavlink2.MAV_TYPE_GCS:
                autopilot = src
            else:
                continue
        if src != autopilot:
            continue
        t = float(m._timestamp)
        if t0 is None:
            t0 = t
        play = t - t0
        if mtype == "HEARTBEAT" and arm_s is None and m.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED:
            arm_s = play
        if mtype == "GPS_RAW_INT" and m.fix_type >= 3 and not (m.lat == 0 and m.lon == 0):
            gps_t.append(play)
            gps_pos.append((units.deg_from_degE7(m.lat), units.deg_from_degE7(m.lon), units.m_from_mm(m.alt)))
        items.append(Item(play, _v2(m), src))
    if not items:
        raise ValueError(f"{path}: no autopilot messages")
    gt = np.asarray(gps_t)
    gp = np.asarray(gps_pos)

    def truth(t: float):
        if len(gt) < 2 or not gt[0] <= t <= gt[-1]:
            return None
        i = int(np.searchsorted(gt, t))
        i = min(max(i, 1), len(gt) - 1)
        if gt[i] - gt[i - 1] > 2.0:  # no truth inside the log's own outages
            return None
        w = (t - gt[i - 1]) / (gt[i] - gt[i - 1])
        p = gp[i - 1] + w * (gp[i] - gp[i - 1])
        return float(p[0]), float(p[1]), float(p[2])

    return Playback(items, truth, f"tlog {Path(path).name}", arm_s)
