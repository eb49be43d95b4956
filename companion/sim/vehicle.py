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
  the horizontal error (truth: the flight's trajectory, or the log's own receiver positions); one the autopilot would
  not use is marked ``ignored`` (:mod:`companion.sim.autopilot_gps`: below 3D, or not for the MAVLink instance);
* ``gps_mav_instance=N`` (the companion feeds GPS instance N, as with ``GPS{N+1}_TYPE = 14``): at the flight's arming
  time the vehicle arms only with a 3D GPS_INPUT for N at most 1 s old; until then it repeats its last disarmed
  second (HEARTBEAT, IMU and GNSS at rest), retries each second, sends "PreArm: GPS {N+1}: Bad fix" at once and every
  30 s, and the rest of the flight follows that much later (records "arming_refused", "armed" with the delay). Only
  on the source's first pass, when it is played from before its arming; fault windows stay on the playback clock.

Time: the playback clock is the source's boot time (log receive time for a tlog); the wall clock only
paces it.
"""

from __future__ import annotations

import itertools
import json
import math
import select
import socket
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from companion.nav.frame import LocalFrame
from companion.inject.gps_input import decode_gps_input
from companion.sim.autopilot_gps import ArmingCheck, ignored_by
from companion.sim.mavlink_out import statustext
from companion.sim.playback import _ALWAYS, Item, Playback, _window

MAV_CMD_SET_MESSAGE_INTERVAL = mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL
#: at the end of the flight, wait at most this long (wall s) for the companion to read what was sent and close
END_DRAIN_S = 60.0
#: an arming refused holds the flight this long (playback s) before the next attempt: its last disarmed second repeats
ARM_RETRY_S = 1.0


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
        idle_exit_s: float = 0.0,
        gps_mav_instance: int | None = None,
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
        #: end once the companion has been heard and then nothing came from it for this long (wall s; 0: never)
        self.idle_exit_s = idle_exit_s
        self._last_rx: float | None = None  # monotonic time of the last bytes from the companion
        self.gps_mav_instance = gps_mav_instance
        self.arming = ArmingCheck(gps_mav_instance) if gps_mav_instance is not None else None
        t_arm = playback.arm_s
        # the arming check applies when the played part starts disarmed and reaches the arming time
        self.arm_gate_s = t_arm if (self.arming is not None and t_arm is not None and t_arm >= ARM_RETRY_S
                                    and self.start_s < t_arm <= self.end_s) else None
        self.hold_s = 0.0  # how long arming was refused: everything after the arming time plays this much later

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

    def _finish_link(self) -> None:
        """The flight is over: over TCP, half-close and read until the companion closes (at most END_DRAIN_S, or until
        stopped), so that what was sent still arrives. Closing a socket with unread input sends a reset and the kernel
        drops the unsent rest of the output: a companion behind the stream lost its last seconds."""
        c = self._conn
        if self.scheme == "tcpin" and c is not None and not self._stop:
            try:
                c.shutdown(socket.SHUT_WR)
                deadline = time.monotonic() + END_DRAIN_S
                while not self._stop and time.monotonic() < deadline:
                    r, _, _ = select.select([c], [], [], 0.1)
                    if r and not c.recv(65536):
                        break  # the companion read everything and closed
            except OSError:
                pass
        self._close_link()

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
        if data:
            self._last_rx = time.monotonic()
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
            tr = self.playback.truth(self._flight_s(t))
            rec = {"event": "gps_input", "play_s": play_s, "state_play_s": t, "signed": signed, **d}
            why = ignored_by(d["gps_id"], d["fix_type"], self.gps_mav_instance)
            if why:
                rec["ignored"] = why
            if self.arming is not None:
                self.arming.on_gps_input(play_s, d["gps_id"], d["fix_type"])
            if tr is not None:
                frame = LocalFrame(tr[0], tr[1], tr[2])
                ned = frame.to_ned_m(d["lat_deg"], d["lon_deg"], d["alt_msl_m"])
                rec["truth"] = tr
                rec["err_h_m"] = float(math.hypot(ned[0], ned[1]))
                rec["err_v_m"] = float(abs(ned[2]))
            self._log(rec)

    def _flight_s(self, t: float) -> float:
        """Playback time -> the source's time: back by the arming delay (held at the arming time while it lasted),
        then into the source's window when looping."""
        if self.arm_gate_s is not None and t >= self.arm_gate_s:
            t = max(self.arm_gate_s, t - self.hold_s)
        return self.start_s + (t - self.start_s) % self.period_s if t > self.end_s else t

    def _try_arm(self, now: float, silent: bool) -> bool:
        """An arming attempt at the flight's arming time (or a retry); True once armed."""
        armed, text = self.arming.attempt(now)
        if text is not None and not silent:
            self._send(statustext(mavlink2.MAV_SEVERITY_CRITICAL, text), (1, 1))
        if armed:
            self._log({"event": "armed", "play_s": now, "scripted_s": self.arm_gate_s, "delay_s": self.hold_s,
                       "attempts": self.arming.attempts, "last_fix": self.arming.last_fix})
        elif text is not None:
            self._log({"event": "arming_refused", "play_s": now, "scripted_s": self.arm_gate_s, "text": text,
                       "attempts": self.arming.attempts, "last_fix": self.arming.last_fix})
        return armed

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
        hold_items: list[Item] = []
        if self.arm_gate_s is not None:  # the last second before arming, without its one-off texts: what a refusal repeats
            hold_items = [it for it in _window(self.playback.items, self.arm_gate_s - ARM_RETRY_S, self.arm_gate_s)
                          if it.play_s < self.arm_gate_s and it.msg.get_type() != "STATUSTEXT"]
            if not hold_items:
                self.arm_gate_s = None  # nothing to hold the vehicle with (a log silent before it arms)
        gate = self.arm_gate_s
        if self.arming is not None:
            self._log({"event": "arming_check", "gps_mav_instance": self.gps_mav_instance, "scripted_s": gate})
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
                loop_offset = k * self.period_s + self.hold_s
                now = play_now()
                # link drop: close everything, reopen at the end of the window
                if _in(f.link_drop, now) and not dropped:
                    dropped = True
                    self._close_link()
                    self._log({"event": "link_drop", "play_s": now})
                elif dropped and not _in(f.link_drop, now):
                    dropped = False
                    if self._last_rx is not None:
                        self._last_rx = time.monotonic()  # our own drop: the companion's silence was ours
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
                if (self.idle_exit_s > 0 and not dropped and self._last_rx is not None
                        and time.monotonic() - self._last_rx > self.idle_exit_s):
                    self._log({"event": "idle_exit", "play_s": now, "idle_s": self.idle_exit_s})
                    break  # the companion went away: nobody to fly for
                while pending is not None and pending.play_s + loop_offset <= now:
                    if (gate is not None and k == 0 and pending.play_s >= gate and self.arming.armed_at_s is None
                            and not self._try_arm(now, silent)):
                        self.hold_s += ARM_RETRY_S  # refused: replay the last disarmed second, then try again
                        loop_offset += ARM_RETRY_S
                        src = itertools.chain(hold_items[1:], [pending], src)
                        pending = hold_items[0]
                        continue
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
                       "sent": dict(self.stats.sent), "arm_delay_s": self.hold_s,
                       "armed_at_s": self.arming.armed_at_s if self.arming else None})
            self._finish_link()
            if self._conn is not None:
                self._conn.close()
            if self._record is not None:
                self._record.close()
        return self.stats
