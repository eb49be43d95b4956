"""A simulated ArduPilot vehicle on a MAVLink link, for hardware-in-the-loop tests of ``companion run``.

It plays a telemetry log (``.tlog``) or a generated flight (:mod:`companion.sim.flight`) in real time
(or ``speed`` times faster) as the autopilot would stream it -- HEARTBEAT, SYSTEM_TIME, GPS_RAW_INT,
RAW_IMU / SCALED_IMU2, ATTITUDE, STATUSTEXT -- and behaves like one towards the companion:

* streams other than HEARTBEAT/STATUSTEXT flow only once requested with MAV_CMD_SET_MESSAGE_INTERVAL
  (``streams="requested"``, ArduPilot with SRn_ = 0) or as the source has them (``"all"``); a request is
  answered with COMMAND_ACK and honoured by decimating the source stream (interval -1 stops it);
* faults on the playback clock: GNSS cut (GPS_RAW_INT with fix_type 1 and lat = lon = 0, as ArduPilot
  sends it), IMU stop, link drop (silence both ways; a TCP server closes the connection and stops
  listening), reboot (silence, then boot time restarts at 0 and the requested intervals are forgotten),
  and ``noise``: garbage bytes, frames with a bad CRC, another system's GPS, NaN attitude, fix_type 0 at
  0,0, a 3D fix at latitude 95 deg, duplicated and out-of-order IMU samples;
* as TCP server (``tcpin``, like SITL) it starts its clock when the first client connects;
* a gravimeter (``gravity=`` of :func:`playback_from_flight`): NAMED_VALUE_FLOAT "GRAV" from (1, 1) with the
  map's anomaly at the true position plus seeded noise, always sent (like HEARTBEAT), silent with the link;
* a long generated flight (hours of cruise, :mod:`companion.sim.cruise`) is framed a chunk of playback time
  at a time (:class:`LazyItems`), so its hundreds of thousands of message objects never all exist at once;
* every GPS_INPUT received is written to a JSON-lines record with the truth at the message's time and
  the horizontal error (truth: the flight's trajectory, or the log's own receiver positions).

Time: the playback clock is the source's boot time (log receive time for a tlog); the wall clock only
paces it.
"""

from __future__ import annotations

import json
import math
import select
import signal
import socket
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from companion import units
from companion.nav.frame import LocalFrame
from companion.inject.gps_input import decode_gps_input

_EPOCH_US = 1e15
MAV_CMD_SET_MESSAGE_INTERVAL = mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL
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

    return Playback(items, truth, f"generated flight ({flight.duration_s:.0f} s, seed {flight.seed})")


def playback_from_tlog(path: str | Path) -> Playback:
    """A telemetry log; truth from the log's own GPS_RAW_INT positions (interpolated, 3D fixes only)."""
    from pymavlink import mavutil

    log = mavutil.mavlogfile(str(path), robust_parsing=True)
    items: list[Item] = []
    autopilot: tuple[int, int] | None = None
    gps_t, gps_pos = [], []
    t0 = None
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

    return Playback(items, truth, f"tlog {Path(path).name}")


@dataclass
class Faults:
    """Fault windows on the playback clock (seconds)."""

    gnss_off: tuple[float, float] | None = None
    imu_off: tuple[float, float] | None = None
    link_drop: tuple[float, float] | None = None
    reboot_at: float | None = None
    reboot_downtime_s: float = 2.0
    forget_streams_at: float | None = None  # drop every requested interval (an autopilot losing its stream setup)
    noise: bool = False


def _in(w, t) -> bool:
    return w is not None and w[0] <= t < w[1]


@dataclass
class SimStats:
    sent: Counter = field(default_factory=Counter)
    received: Counter = field(default_factory=Counter)
    gps_input: int = 0
    gps_input_signed: int = 0
    requests: list = field(default_factory=list)
    connections: int = 0
    reboots: int = 0
    #: pacing: the most any message was sent behind its playback time (playback s; wall s = this / speed),
    #: and how many were sent more than 10 ms (wall) late
    max_lag_s: float = 0.0
    late_messages: int = 0


class VehicleSim:
    """Serve a playback on ``listen`` (``tcpin:HOST:PORT`` like SITL, or ``udpout:HOST:PORT``)."""

    def __init__(
        self,
        playback: Playback,
        listen: str,
        *,
        faults: Faults | None = None,
        speed: float = 1.0,
        start_s: float = 0.0,
        end_s: float | None = None,
        streams: str = "requested",
        loops: int = 1,
        record: str | Path | None = None,
        key: bytes | None = None,
        seed: int = 0,
    ) -> None:
        if streams not in ("requested", "all"):
            raise ValueError("streams must be 'requested' or 'all'")
        self.playback = playback
        self.scheme, host, port = listen.split(":")
        if self.scheme not in ("tcpin", "udpout"):
            raise ValueError(f"{listen}: the simulator serves tcpin:HOST:PORT or udpout:HOST:PORT")
        self.addr = (host, int(port))
        self.faults = faults or Faults()
        self.speed = speed
        self.start_s = start_s
        self.end_s = end_s if end_s is not None else playback.duration_s
        self.streams = streams
        self.loops = loops  # play the source this many times (0: until stopped); boot time keeps counting
        self.period_s = self.end_s - self.start_s + 0.02
        self.key = key
        self.rng = np.random.default_rng(seed)
        self.stats = SimStats()
        self.intervals_us: dict[int, float] = {}
        self.last_sent: dict[str, float] = {}
        self.boot_shift_s = 0.0
        self.boot_play = (0.0, 0.0)  # (boot_s, play_s) of the last message with a boot time
        self._senders: dict[tuple[int, int], Any] = {}
        self._rx = self._mav(None)
        self._record = open(record, "w") if record else None  # noqa: SIM115
        self._stop = False
        self._listen_sock = None
        self._conn = None  # TCP client socket / UDP socket
        self._recent_imu: list[Any] = []

    # -- I/O ----------------------------------------------------------------------------------
    def _mav(self, src):
        mav = mavlink2.MAVLink(None, srcSystem=src[0] if src else 1, srcComponent=src[1] if src else 1)
        mav.robust_parsing = True
        if self.key is not None:
            mav.signing.secret_key = self.key
            mav.signing.link_id = 1
            mav.signing.timestamp = int(max(time.time() - 1420070400, 0) * 1e5)
            mav.signing.sign_outgoing = src is not None
        return mav

    def _open(self) -> None:
        if self.scheme == "tcpin":
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind(self.addr)
            s.listen(1)
            self._listen_sock = s
        else:
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind(("127.0.0.1", 0))
            self._conn = s

    def _close_link(self) -> None:
        if self.scheme == "tcpin":
            for s in (self._conn, self._listen_sock):
                if s is not None:
                    s.close()
            self._conn = self._listen_sock = None
        self._rx = self._mav(None)

    def _write(self, data: bytes) -> None:
        try:
            if self.scheme == "tcpin":
                if self._conn is not None:
                    self._conn.sendall(data)
            else:
                self._conn.sendto(data, self.addr)
        except OSError:
            if self.scheme == "tcpin" and self._conn is not None:
                self._conn.close()
                self._conn = None

    def _send(self, msg, src: tuple[int, int]) -> None:
        mav = self._senders.get(src)
        if mav is None:
            mav = self._senders[src] = self._mav(src)
        self._write(bytes(msg.pack(mav)))
        self.stats.sent[msg.get_type()] += 1

    def _poll(self, timeout_s: float, play_s: float, silent: bool) -> None:
        socks = []
        if self.scheme == "tcpin":
            if self._conn is not None:
                socks.append(self._conn)
            elif self._listen_sock is not None:
                socks.append(self._listen_sock)
        elif self._conn is not None:
            socks.append(self._conn)
        if not socks:
            time.sleep(timeout_s)
            return
        r, _, _ = select.select(socks, [], [], max(0.0, timeout_s))
        if not r:
            return
        s = r[0]
        if s is self._listen_sock:
            c, _ = s.accept()
            c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._conn = c
            self._rx = self._mav(None)
            self.stats.connections += 1
            self._log({"event": "connected", "play_s": play_s})
            return
        try:
            data = s.recv(65536)
        except OSError:
            data = b""
        if not data and self.scheme == "tcpin":
            s.close()
            self._conn = None
            return
        if silent:
            return
        for m in self._rx.parse_buffer(data) or []:
            self._handle(m, play_s)

    def _handle(self, m, play_s: float) -> None:
        mtype = m.get_type()
        self.stats.received[mtype] += 1
        if mtype == "COMMAND_LONG" and m.command == MAV_CMD_SET_MESSAGE_INTERVAL and m.target_system in (0, 1):
            msg_id, interval = int(m.param1), float(m.param2)
            self.intervals_us[msg_id] = interval
            self.stats.requests.append((play_s, msg_id, interval))
            self._send(mavlink2.MAVLink_command_ack_message(m.command, 0, 0, 0, m.get_srcSystem(), m.get_srcComponent()), (1, 1))
        elif mtype == "GPS_INPUT":
            self.stats.gps_input += 1
            signed = bool(getattr(m, "_signed", False))
            self.stats.gps_input_signed += signed
            d = decode_gps_input(m)
            boot_s = d["time_boot_us"] * 1e-6
            t = boot_s + (self.boot_play[1] - self.boot_play[0])  # boot time -> playback time
            tr = self.playback.truth(self.start_s + (t - self.start_s) % self.period_s if t > self.end_s else t)
            rec = {"event": "gps_input", "play_s": play_s, "state_play_s": t, "signed": signed, **d}
            if tr is not None:
                frame = LocalFrame(tr[0], tr[1], tr[2])
                ned = frame.to_ned_m(d["lat_deg"], d["lon_deg"], d["alt_msl_m"])
                rec["truth"] = tr
                rec["err_h_m"] = float(math.hypot(ned[0], ned[1]))
                rec["err_v_m"] = float(abs(ned[2]))
            self._log(rec)

    def _log(self, rec: dict) -> None:
        if self._record is not None:
            self._record.write(json.dumps(rec) + "\n")
            self._record.flush()

    # -- playback -----------------------------------------------------------------------------
    def _wanted(self, mtype: str, play_s: float) -> bool:
        if mtype in _ALWAYS:
            return True
        if self.streams == "all" and not self.intervals_us:
            return True
        interval = self.intervals_us.get(getattr(mavlink2, f"MAVLINK_MSG_ID_{mtype}"), None)
        if interval is None or interval < 0:
            return self.streams == "all" and interval is None
        if interval == 0:
            return True  # 0: the autopilot's default rate = as the source has it
        last = self.last_sent.get(mtype)
        return last is None or (play_s - last) * 1e6 >= 0.9 * interval

    def _retime(self, it: Item, msg, loop_offset_s: float) -> float | None:
        """Set the boot-time fields for the loop and reboot offsets; returns the boot time sent."""
        if it.unix_us is not None:
            msg.time_unix_usec = it.unix_us + int(round(loop_offset_s * 1e6))
        if it.boot_s is None:
            return None
        boot = it.boot_s + loop_offset_s - self.boot_shift_s
        if hasattr(msg, "time_boot_ms"):
            msg.time_boot_ms = max(0, int(round(boot * 1e3)))
        else:
            msg.time_usec = max(0, int(round(boot * 1e6)))
        return boot

    def _noise(self, play_s: float) -> None:
        """One round of bad input (about once a second)."""
        rng = self.rng
        self._write(rng.bytes(int(rng.integers(5, 60))))  # garbage
        hb = bytearray(mavlink2.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(self._senders.get((1, 1)) or self._mav((1, 1))))
        hb[-3] ^= 0x5A  # bad CRC (unsigned frame: CRC is the last two bytes)
        self._write(bytes(hb))
        boot = self.boot_play[0] + (play_s - self.boot_play[1])
        other = mavlink2.MAVLink_gps_raw_int_message(int(boot * 1e6), 3, 100000000, 200000000, 10000, 100, 100, 0, 0, 12)
        self._send(other, (2, 1))  # another vehicle's receiver: must be ignored
        self._send(mavlink2.MAVLink_attitude_message(max(0, int(boot * 1e3)), math.nan, 0.0, 0.0, 0, 0, 0), (1, 1))
        self._send(mavlink2.MAVLink_gps_raw_int_message(int(boot * 1e6), 0, 0, 0, 0, 65535, 65535, 0, 65535, 0), (1, 1))
        # a 3D fix with latitude 95 deg: out of range, must be refused
        self._send(mavlink2.MAVLink_gps_raw_int_message(int(boot * 1e6), 3, 950000000, 1491652000, 600000, 80, 120, 0, 0, 12), (1, 1))
        if len(self._recent_imu) >= 2 and self.boot_play[0] - self._recent_imu[0].time_usec * 1e-6 < 0.5:
            # a duplicate and a sample ~0.1 s out of order (only while the IMU streams: a sample seconds
            # old looks like an autopilot reboot to companion.timebase, which needs a 2 s jump back)
            self._send(self._recent_imu[-1], (1, 1))
            self._send(self._recent_imu[0], (1, 1))
        self.stats.sent["noise"] += 1

    def stop(self, *_args) -> None:
        self._stop = True

    def run(self) -> SimStats:
        f = self.faults
        self._open()
        self._log({"event": "start", "description": self.playback.description, "start_s": self.start_s, "speed": self.speed})
        def window() -> Iterator[Item]:
            return _window(self.playback.items, self.start_s, self.end_s)

        src = window()
        pending = next(src, None)
        if self.scheme == "tcpin":
            # like ArduPilot SITL on 5760: the vehicle's clock starts once something connects
            while self._conn is None and not self._stop:
                self._poll(0.05, self.start_s, False)
        wall0 = time.monotonic()

        def play_now() -> float:
            return self.start_s + (time.monotonic() - wall0) * self.speed

        next_noise = self.start_s + 1.0
        last_fix_us: int | None = None  # time_usec of the last GPS_RAW_INT with a fix
        dropped = rebooting = gnss_logged = forgot = False
        k = 0
        try:
            while not self._stop:
                if pending is None:
                    if self.loops and k + 1 >= self.loops:
                        break
                    k += 1
                    src = window()
                    pending = next(src, None)
                    if pending is None:
                        break  # nothing to play
                    self._log({"event": "loop", "play_s": play_now(), "loop": k})
                loop_offset = k * self.period_s
                now = play_now()
                # link drop: close everything, reopen at the end of the window
                if _in(f.link_drop, now) and not dropped:
                    dropped = True
                    self._close_link()
                    self._log({"event": "link_drop", "play_s": now})
                elif dropped and not _in(f.link_drop, now):
                    dropped = False
                    if self.scheme == "tcpin":
                        self._open()
                    self._log({"event": "link_back", "play_s": now})
                if f.reboot_at is not None and not rebooting and f.reboot_at <= now < f.reboot_at + f.reboot_downtime_s and self.stats.reboots == 0:
                    rebooting = True
                    self._log({"event": "reboot", "play_s": now})
                elif rebooting and now >= f.reboot_at + f.reboot_downtime_s:
                    rebooting = False
                    self.stats.reboots += 1
                    self.boot_shift_s = f.reboot_at + f.reboot_downtime_s
                    self.intervals_us.clear()
                    self.last_sent.clear()
                    self._log({"event": "booted", "play_s": now})
                if f.forget_streams_at is not None and now >= f.forget_streams_at and not forgot:
                    forgot = True
                    self.intervals_us.clear()
                    self._log({"event": "forgot_streams", "play_s": now})
                if _in(f.gnss_off, now) and not gnss_logged:
                    gnss_logged = True
                    self._log({"event": "gnss_off", "play_s": now})
                silent = dropped or rebooting
                while pending is not None and pending.play_s + loop_offset <= now:
                    it = pending
                    t = it.play_s + loop_offset
                    pending = next(src, None)
                    lag = play_now() - t
                    if lag > self.stats.max_lag_s:
                        self.stats.max_lag_s = lag
                    if lag > 0.01 * self.speed:
                        self.stats.late_messages += 1
                    if silent:
                        continue
                    mtype = it.msg.get_type()
                    if mtype in ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2") and _in(f.imu_off, t):
                        continue
                    if not self._wanted(mtype, t):
                        continue
                    msg = it.msg
                    outage = mtype == "GPS_RAW_INT" and _in(f.gnss_off, t)
                    if outage:
                        msg = mavlink2.MAVLink_gps_raw_int_message(msg.time_usec, 1, 0, 0, 0, 65535, 65535, 0, 65535, 0)
                    boot = self._retime(it, msg, loop_offset)
                    if mtype == "GPS_RAW_INT":
                        # as ArduPilot reports an outage: no fix, 0,0, stamped with the time of the last fix (frozen)
                        if outage and last_fix_us is not None:
                            msg.time_usec = last_fix_us
                        elif not outage:
                            last_fix_us = msg.time_usec
                    if boot is not None:
                        self.boot_play = (boot, t)
                    self._send(msg, it.src)
                    self.last_sent[mtype] = t
                    if mtype == "RAW_IMU":
                        self._recent_imu = (self._recent_imu + [msg])[-5:]
                if f.noise and not silent and now >= next_noise and self.boot_play != (0.0, 0.0):
                    self._noise(now)
                    next_noise = now + 1.0
                nxt = pending.play_s + loop_offset if pending is not None else now
                self._poll(min(0.005, max(0.0, (nxt - play_now()) / self.speed)), now, silent)
        finally:
            self._log({"event": "end", "play_s": play_now(), "gps_input": self.stats.gps_input,
                       "gps_input_signed": self.stats.gps_input_signed, "requests": len(self.stats.requests),
                       "connections": self.stats.connections, "received": dict(self.stats.received),
                       "max_lag_s": self.stats.max_lag_s, "late_messages": self.stats.late_messages,
                       "sent": dict(self.stats.sent)})
            self._close_link()
            if self._conn is not None:
                self._conn.close()
            if self._record is not None:
                self._record.close()
        return self.stats


def circuit_profile(circuits: int = 2):
    """Take off, fly ``circuits`` 200 m squares at 8 m/s, land where it started and yaw back to north:
    it ends as it began (on the ground at the origin, nose north), so it can be looped for soak runs."""
    from companion.sim.flight import CANBERRA_FIELD
    from companion.sim.trajectory import Climb, FlightProfile, Hold, Land, Speed, Yaw, legs_through_waypoints

    wps = [(200.0, 0.0), (200.0, 200.0), (0.0, 200.0), (0.0, 0.0)] * circuits
    legs = [
        Hold(6.0, mode="STABILIZE"),
        Hold(4.0, mode="AUTO"),
        Climb(20.0, rate_mps=2.5),
        Hold(2.0),
        *legs_through_waypoints(wps, start_ne_m=(0.0, 0.0), start_heading_deg=0.0, speed_mps=8.0, turn_radius_m=20.0),
        Speed(0.0),
        Hold(2.0),
        Land(rate_mps=1.5, final_rate_mps=0.5, flare_m=3.0, mode="LAND"),
        Yaw(90.0),
        Hold(4.0, mode="STABILIZE"),
    ]
    return FlightProfile(legs, CANBERRA_FIELD, start_heading_deg=0.0)


_NOTES: list[str] = []  # details printed after the listening line


def _lat_lon(text: str, what: str) -> tuple[float, float]:
    try:
        lat, lon = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"{what} {text!r}: expected LAT,LON in degrees") from None
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 360.0):
        raise ValueError(f"{what} {text!r}: latitude must be within +-90 deg and longitude within -180..360 deg")
    return lat, lon


def _cruise_from_args(args):
    """``--profile cruise``: a lawn-mower survey (aircraft defaults at >= 30 m/s, ship defaults below)."""
    from companion.sim.cruise import AIRCRAFT, SHIP, cruise_profile

    speed = args.cruise_speed
    preset = AIRCRAFT if speed >= 30.0 else SHIP
    lat, lon = _lat_lon(args.origin, "--origin") if args.origin else (-40.5, 155.6)
    return cruise_profile(
        LocalFrame(lat, lon, 0.0), hours=args.hours, speed_mps=speed,
        line_km=args.line_km if args.line_km is not None else preset["line_km"],
        spacing_km=args.spacing_km if args.spacing_km is not None else preset["spacing_km"],
        heading_deg=args.cruise_heading,
        altitude_m=args.cruise_alt if args.cruise_alt is not None else preset["altitude_m"],
        max_lines=args.max_lines,
    )


def _gravity_from_args(args, profile) -> tuple[np.ndarray, np.ndarray]:
    """``--gravity-map``: readings along the flight; one-line errors for a bad file or a flight off the map."""
    from companion.gravity.maps import LocalGravityMap, MapFormatError, load_grid

    if not 1 <= len(args.gravity_name.encode("ascii", "replace")) <= 10:
        raise ValueError(f"--gravity-name {args.gravity_name!r}: NAMED_VALUE_FLOAT names are 1-10 characters")
    try:
        lmap = LocalGravityMap.around(load_grid(args.gravity_map))
    except (MapFormatError, OSError, ValueError, KeyError) as err:
        first = (str(err).splitlines() or [type(err).__name__])[0]  # xarray's hints run over several lines
        raise ValueError(f"gravity map {args.gravity_map}: {first}") from None
    if lmap.frame is None:
        raise ValueError(f"gravity map {args.gravity_map}: needs lat/lon axes to fly a generated flight over it")
    f = profile.frame
    n0, e0 = lmap.frame.to_ned_m(f.ref_lat_deg, f.ref_lon_deg, 0.0)[:2]
    if not math.isfinite(float(lmap.interp_ne(n0, e0))):
        raise ValueError(f"the flight starts at {f.ref_lat_deg:.4f},{f.ref_lon_deg:.4f}, off the gravity map "
                         f"{args.gravity_map} (lon {lmap.gmap.x[0]:g}..{lmap.gmap.x[-1]:g}, lat {lmap.gmap.y[0]:g}..{lmap.gmap.y[-1]:g})")
    hz = args.gravity_hz
    seed = args.seed if args.seed is not None else 0
    t, v = gravity_readings(profile, lmap, hz=hz, sigma_mgal=args.gravity_sigma_mgal, seed=seed)
    expected = int(math.floor((profile.duration_s - 0.05) * hz + 1e-9)) + 1
    off = expected - len(t)
    _NOTES.append(f"sim: gravimeter {len(t)} readings at {hz:g} Hz as NAMED_VALUE_FLOAT {args.gravity_name!r} "
          f"(sigma {args.gravity_sigma_mgal:g} mGal, map {Path(args.gravity_map).name})"
          + (f"; {off} positions off the map send nothing" if off else ""))
    return t, v


def run_sim(args) -> int:
    """``companion sim`` entry point (argparse namespace from companion.cli)."""
    from companion.config import load_signing_key

    _NOTES.clear()
    if args.log:
        if getattr(args, "gravity_map", None):
            raise ValueError("--gravity-map works with a generated flight (--profile), not with --log")
        playback = playback_from_tlog(args.log)
    else:
        from companion.sim.flight import SAMPLE_SEED, SENSOR_SETS, SimConfig, sample_profile, simulate_flight

        cruise = args.profile == "cruise"
        if cruise:
            profile = _cruise_from_args(args)
        else:
            profile = circuit_profile() if args.profile == "circuit" else sample_profile()
        gravity = _gravity_from_args(args, profile) if getattr(args, "gravity_map", None) else None
        imu_hz = args.imu_hz or (25.0 if cruise else 50.0)
        gnss_hz = args.gnss_hz or (5.0 if cruise else 10.0)
        t0 = time.perf_counter()
        flight = simulate_flight(
            profile, args.seed if args.seed is not None else SAMPLE_SEED,
            SimConfig(gnss_rate_hz=gnss_hz, imu_rate_hz=imu_hz, attitude_rate_hz=getattr(args, "attitude_hz", 10.0),
                      **SENSOR_SETS[getattr(args, "sensors", "drone")]),
        )
        playback = playback_from_flight(flight, gravity=gravity, gravity_name=getattr(args, "gravity_name", "GRAV"))
        _NOTES.append(f"sim: built {profile.duration_s / 3600:.2f} h flight in {time.perf_counter() - t0:.1f} s "
                      f"(IMU {imu_hz:g} Hz, GNSS {gnss_hz:g} Hz, attitude {getattr(args, 'attitude_hz', 10.0):g} Hz, "
                      f"{getattr(args, 'sensors', 'drone')} sensors)")
    faults = Faults(
        gnss_off=tuple(args.gnss_off) if args.gnss_off else None,
        imu_off=tuple(args.imu_off) if args.imu_off else None,
        link_drop=tuple(args.link_drop) if args.link_drop else None,
        reboot_at=args.reboot_at,
        reboot_downtime_s=args.reboot_downtime,
        noise=args.noise,
    )
    key = load_signing_key(args.signing_key_file) if args.signing_key_file else None
    sim = VehicleSim(
        playback, args.listen, faults=faults, speed=args.speed, start_s=args.start, end_s=args.end,
        streams=args.streams, loops=args.loops, record=args.record, key=key, seed=args.seed or 0,
    )
    signal.signal(signal.SIGTERM, sim.stop)
    signal.signal(signal.SIGINT, sim.stop)
    print(f"sim: {playback.description} on {args.listen} from {args.start:g} s at x{args.speed:g}", flush=True)
    for note in _NOTES:  # after the first line, which says the simulator is about to listen
        print(note, flush=True)
    _NOTES.clear()
    st = sim.run()
    print(f"sim: sent {sum(st.sent.values())} messages, received {st.gps_input} GPS_INPUT "
          f"({st.gps_input_signed} signed), {len(st.requests)} interval requests, {st.connections} connections; "
          f"pacing: max lag {st.max_lag_s:.3f} s playback ({st.max_lag_s / sim.speed * 1e3:.1f} ms wall), "
          f"{st.late_messages} messages > 10 ms late", flush=True)
    return 0
