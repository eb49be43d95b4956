"""The live-link fuzzer: a hostile autopilot on loopback against a real ``companion run`` process.

:class:`Peer` plays the project's generated sample flight (``companion.sim.vehicle.playback_from_flight``: the
messages ``companion sim`` sends, encoded by ``companion.sim.mavlink_out`` with pymavlink's ardupilotmega
dialect) in real time as the autopilot (system 1, component 1), over TCP (it listens, the companion connects
with ``tcp:``, like SITL) or UDP (the companion binds ``udpin:``, the peer sends to it). On the play clock it
applies faults (:mod:`replay.fuzz.faults`): garbage bytes, frames with a bad CRC, MAVLink 1 frames among MAVLink 2, extreme and
NaN fields, a message stamped far ahead or behind, a burst of thousands of messages a second, a SIGTERM.

It reads back what the companion sends: HEARTBEATs (the link is alive) and, in inject mode, every GPS_INPUT,
with its arrival time, the horizontal error against the flight's truth and its *lag*: arrival minus the send
time of the stream message it was built on (GPS_INPUT is stamped ``autopilot_lag_s`` before the newest input
the companion had: the first message with boot time >= its time + that lag). The properties (:func:`judge_live`): the process stays up until the SIGTERM and keeps
consuming (fresh GPS_INPUT in the quiet seconds after the last fault), exits within 2 s of SIGTERM with exit 0,
no traceback, no GPS_INPUT more than ``max_lag_s`` late, no 3D fix whose error exceeds 4 x its stated
accuracy, a readable MCAP.

Waits are for conditions (the TCP accept, the companion's UDP port bound in /proc/net/udp, the first fresh
GPS_INPUT), each with a generous limit; never a fixed sleep.
"""

from __future__ import annotations

import bisect
import copy
import math
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from replay.fuzz.faults import (  # noqa: F401 (re-exported)
    BadCrc, Burst, Fault, Garbage, Inject, Mavlink1, Reboot, Sigterm, Silence,
)
from replay.fuzz.properties import TRACEBACK_MARKS, check_mcap

CLI = [sys.executable, "-m", "companion.cli"]
#: what an autopilot sends the companion by default (companion.config.DEFAULT_STREAMS_HZ) and always
STREAMS = ("HEARTBEAT", "STATUSTEXT", "SYSTEM_TIME", "GPS_RAW_INT", "RAW_IMU", "ATTITUDE")
MAX_LAG_S = 0.5  # companion.inject.gps_input.InjectConfig.max_lag_s (the default the companion runs with)
SIGTERM_EXIT_S = 2.0
ACCURACY_FACTOR = 4.0  # a 3D fix's horizontal error may reach this many times its stated accuracy (as tests/test_hil)


def free_port(kind=socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def udp_port_bound(port: int) -> bool:
    """Something has bound UDP ``port`` on this host (read from /proc/net/udp; nothing is disturbed)."""
    hexport = f"{port:04X}"
    try:
        with open("/proc/net/udp") as f:
            next(f)
            return any(line.split()[1].split(":")[1] == hexport for line in f)
    except (OSError, StopIteration, IndexError):
        return False


def _autopilot_lag_s() -> float:
    """Each GPS_INPUT describes the vehicle this long before the newest input the companion had when it built it."""
    from companion.inject.gps_input import InjectConfig

    return float(InjectConfig().autopilot_lag_s)


def sample_playback():
    """The sample flight's messages and truth (built once per process: about 2 s)."""
    global _PLAYBACK
    if _PLAYBACK is None:
        from companion.sim.playback import playback_from_flight

        _PLAYBACK = playback_from_flight()
    return _PLAYBACK


_PLAYBACK = None


# ----------------------------------------------------------------------------------------------- peer
@dataclass
class GpsInputSeen:
    recv_mono: float
    boot_s: float
    fix_type: int
    h_acc_m: float
    err_h_m: float | None
    lag_s: float | None
    time_week: int = 0
    ahead: bool = False  # stamped later than anything the autopilot sent on its current boot (an older boot's time)


class Peer:
    """The fake autopilot. ``transport`` "tcp" (we listen) or "udp" (the companion binds)."""

    def __init__(self, transport: str = "tcp", *, start_s: float = 20.0, seed: int = 0, playback=None) -> None:
        if transport not in ("tcp", "udp"):
            raise ValueError(transport)
        self.transport = transport
        self.playback = playback or sample_playback()
        self.items = [it for it in self.playback.items if it.msg.get_type() in STREAMS and it.play_s >= start_s]
        self.start_s = start_s
        self.rng = np.random.default_rng(seed)
        self.epoch_lag_s = _autopilot_lag_s()
        self._listen = None
        self.sock: socket.socket | None = None
        if transport == "tcp":
            self._listen = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self._listen.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._listen.bind(("127.0.0.1", 0))
            self._listen.listen(1)
            self.port = self._listen.getsockname()[1]
            self.url = f"tcp:127.0.0.1:{self.port}"
        else:
            self.port = free_port(socket.SOCK_DGRAM)
            self.url = f"udpin:127.0.0.1:{self.port}"
        self._rx = mavlink2.MAVLink(None)
        self._rx.robust_parsing = True
        self._packers: dict[tuple[int, int], mavlink2.MAVLink] = {}
        self._newest: dict[str, object] = {}
        self._sent_boot: list[float] = []  # boot times of the stream messages sent on the current boot, in order ...
        self._sent_mono: list[float] = []  # ... and when
        self.boot_shift_s = 0.0  # the flight's boot time minus the autopilot's (grows at each reboot)
        self.reboot_mono: list[float] = []  # when the autopilot came back from each reboot
        self.gps_inputs: list[GpsInputSeen] = []
        self.heartbeats: list[float] = []
        self.received: dict[str, int] = {}
        self.bytes_out = 0
        self.companion: Companion | None = None
        self.wall0: float | None = None
        self.sigterm_mono: float | None = None
        self._k = 0
        # what the companion sends is read (and timed) by a thread of its own: the play loop can be busy packing
        # a burst for a long time on a loaded machine, and a GPS_INPUT must not look late for the peer's delay
        self._lock = threading.Lock()
        self._reader: threading.Thread | None = None
        self._closing = threading.Event()

    # -- I/O ----------------------------------------------------------------------------------
    def packer(self, src=(1, 1)):
        mav = self._packers.get(src)
        if mav is None:
            mav = self._packers[src] = mavlink2.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
        return mav

    def pack(self, msg, src=(1, 1), force_mavlink1=False) -> bytes:
        mav = self.packer(src)
        frame = bytes(msg.pack(mav, force_mavlink1=force_mavlink1))
        mav.seq = (mav.seq + 1) % 256
        return frame

    def write(self, data: bytes) -> None:
        if self.sock is None:
            return
        try:
            if self.transport == "tcp":
                self.sock.sendall(data)
            else:
                for i in range(0, len(data), 8192):
                    self.sock.sendto(data[i:i + 8192], ("127.0.0.1", self.port))
            self.bytes_out += len(data)
        except OSError:
            pass  # the companion is gone or not reading: the properties say what that means

    def newest(self, mtype: str):
        return self._newest.get(mtype)

    def reboot(self) -> None:
        """The boot clock starts again: later messages are stamped from 1 s on (the flight itself goes on)."""
        nxt = next((it.boot_s for it in self.items[self._k:] if it.boot_s is not None), None)
        with self._lock:
            self.boot_shift_s = (nxt - 1.0) if nxt is not None else self.boot_shift_s
            self._sent_boot, self._sent_mono = [], []
            self.reboot_mono.append(time.monotonic())

    def _on_boot(self, msg):
        """``msg`` stamped on the autopilot's current boot (a copy when it has rebooted)."""
        if not self.boot_shift_s:
            return msg
        msg = copy.copy(msg)
        if hasattr(msg, "time_boot_ms"):
            msg.time_boot_ms = max(0, int(round(msg.time_boot_ms - self.boot_shift_s * 1e3)))
        elif getattr(msg, "time_usec", 0) and msg.time_usec < 1e15:
            msg.time_usec = max(0, int(round(msg.time_usec - self.boot_shift_s * 1e6)))
        return msg

    def _accept_again(self) -> None:
        """TCP: the companion closed the connection (it declared the link lost) and connects again."""
        if self.transport != "tcp" or self.sock is not None or self._listen is None:
            return
        r, _, _ = select.select([self._listen], [], [], 0)
        if r:
            sock, _ = self._listen.accept()
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            if self._reader is not None:
                self._reader.join(5)
            self.sock = sock
            self._start_reader()

    def sigterm(self) -> None:
        if self.companion is not None and self.sigterm_mono is None:
            self.sigterm_mono = time.monotonic()
            self.companion.proc.send_signal(signal.SIGTERM)

    def play_now(self) -> float:
        return self.start_s + (time.monotonic() - self.wall0)

    def connect(self, timeout_s: float = 60.0) -> None:
        """Wait until the companion's end of the link is up: the TCP accept, or its UDP port bound."""
        end = time.monotonic() + timeout_s
        if self.transport == "tcp":
            while self.sock is None:
                if time.monotonic() > end or (self.companion and self.companion.proc.poll() is not None):
                    raise TimeoutError("the companion did not connect")
                r, _, _ = select.select([self._listen], [], [], 0.2)
                if r:
                    self.sock, _ = self._listen.accept()
                    self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    self._start_reader()
        else:
            while not udp_port_bound(self.port):
                if time.monotonic() > end or (self.companion and self.companion.proc.poll() is not None):
                    raise TimeoutError("the companion did not bind its UDP port")
                time.sleep(0.05)
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.sock.bind(("127.0.0.1", 0))
            self._start_reader()
        self.wall0 = time.monotonic()

    def _start_reader(self) -> None:
        def run():
            while not self._closing.is_set() and self.sock is not None:
                self._read(0.05)

        self._reader = threading.Thread(target=run, name="peer-reader", daemon=True)
        self._reader.start()

    def close(self) -> None:
        self._closing.set()
        if self._reader is not None:
            self._reader.join(5)
            self._reader = None
        for s in (self.sock, self._listen):
            if s is not None:
                s.close()
        self.sock = self._listen = None

    # -- receiving ----------------------------------------------------------------------------
    def _read(self, timeout_s: float) -> None:
        sock = self.sock
        if sock is None:
            return
        try:
            r, _, _ = select.select([sock], [], [], max(0.0, timeout_s))
            if not r:
                return
            data = sock.recv(65536) if self.transport == "tcp" else sock.recvfrom(65536)[0]
        except (OSError, ValueError):  # closed under us
            return
        now = time.monotonic()
        if not data:
            sock.close()
            self.sock = None
            return
        for m in self._rx.parse_buffer(data) or []:
            t = m.get_type()
            self.received[t] = self.received.get(t, 0) + 1
            if t == "HEARTBEAT":
                self.heartbeats.append(now)
            elif t == "GPS_INPUT":
                self._on_gps_input(m, now)

    def _on_gps_input(self, m, now: float) -> None:
        from companion.nav.frame import LocalFrame
        from companion.inject.gps_input import decode_gps_input

        d = decode_gps_input(m)
        boot = d["time_boot_us"] * 1e-6
        with self._lock:
            shift = self.boot_shift_s
        tr = self.playback.truth(boot + shift)
        err = None
        if tr is not None:
            ned = LocalFrame(tr[0], tr[1], tr[2]).to_ned_m(d["lat_deg"], d["lon_deg"], d["alt_msl_m"])
            err = float(math.hypot(ned[0], ned[1]))
        lag = None
        # the input it was built on: the first sent at or after the state's epoch + the autopilot's lag (on the
        # autopilot's current boot: a time later than anything it sent is another boot's, or made up)
        with self._lock:
            i = bisect.bisect_left(self._sent_boot, boot + self.epoch_lag_s - 1e-6)
            if i < len(self._sent_boot):
                lag = now - self._sent_mono[i]
            ahead = bool(self._sent_boot) and i == len(self._sent_boot) and boot > self._sent_boot[-1] + 0.05
        self.gps_inputs.append(GpsInputSeen(now, boot, d["fix_type"], d["h_acc_m"], err, lag, d["time_week"], ahead))

    # -- playing ------------------------------------------------------------------------------
    def play(self, until: Callable[[float], bool], faults: list[Fault] = (), t_faults0: float | None = None) -> None:
        """Send the stream (and the faults, timed from ``t_faults0`` on the play clock) until ``until(play_now)``."""
        faults = list(faults)
        while True:
            now = self.play_now()
            if until(now) or self._k >= len(self.items):
                return
            self._accept_again()
            active = []
            for f in faults:
                if f.done or t_faults0 is None:
                    continue
                t = t_faults0 + f.at_s
                if now >= t:
                    first = not f.started
                    if first:
                        f.started, f.t0 = True, now
                        f.begin(self, now)
                    if first or now <= t + f.duration_s:
                        active.append(f)
                        f.step(self, now)
                    else:
                        f.done = True
                        f.end(self, now)
            out = []
            while self._k < len(self.items) and self.items[self._k].play_s <= now:
                it = self.items[self._k]
                self._k += 1
                msg = self._on_boot(it.msg)
                frame = self.pack(msg, it.src)
                for f in active:
                    frame = f.transform(self, frame, msg)
                    if not frame:
                        break
                if frame:
                    out.append(frame)
                self._newest[msg.get_type()] = msg
                if it.boot_s is not None:  # (when the autopilot stamped it: held back or not, it is that old)
                    with self._lock:
                        self._sent_boot.append(it.boot_s - self.boot_shift_s)
                        self._sent_mono.append(time.monotonic())
            if out:
                self.write(b"".join(out))
            nxt = self.items[self._k].play_s if self._k < len(self.items) else now + 0.01
            busy = any(isinstance(f, (Burst, Garbage)) for f in active)
            time.sleep(0.0005 if busy else min(0.005, max(0.0, nxt - self.play_now())))

    def fresh_since(self, t_mono: float) -> list[GpsInputSeen]:
        return [g for g in self.gps_inputs if g.recv_mono >= t_mono and g.lag_s is not None and g.lag_s <= MAX_LAG_S]


# ----------------------------------------------------------------------------------------------- companion
class Companion:
    """``companion run --connect URL --inject MODE --out OUT`` with stdout/stderr on files."""

    def __init__(self, url: str, out: Path, *args: str, inject: str = "inject", workdir: Path | None = None) -> None:
        self.out = Path(out)
        self.dir = Path(workdir or self.out.parent)
        self.dir.mkdir(parents=True, exist_ok=True)
        self._fo = open(self.dir / "companion.stdout", "wb")  # noqa: SIM115
        self._fe = open(self.dir / "companion.stderr", "wb")  # noqa: SIM115
        self.proc = subprocess.Popen([*CLI, "run", "--connect", url, "--inject", inject, "--out", str(out), *args],
                                     stdin=subprocess.DEVNULL, stdout=self._fo, stderr=self._fe)
        self.exit_mono: float | None = None

    def wait(self, timeout_s: float) -> int | None:
        try:
            rc = self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            return None
        if self.exit_mono is None:
            self.exit_mono = time.monotonic()
        return rc

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(30)

    @property
    def stderr(self) -> str:
        return (self.dir / "companion.stderr").read_text(errors="replace")

    @property
    def stdout(self) -> str:
        return (self.dir / "companion.stdout").read_text(errors="replace")

    def close(self) -> None:
        self.kill()
        self._fo.close()
        self._fe.close()


# ----------------------------------------------------------------------------------------------- scenarios
@dataclass
class LiveResult:
    scenario: str
    transport: str
    started: bool = False  # GPS_INPUT flowed before the faults
    died_s: float | None = None  # the process ended before the SIGTERM, this long after the faults began
    exit_code: int | None = None
    sigterm_to_exit_s: float | None = None
    gps_inputs: int = 0
    stale: int = 0
    max_lag_s: float = 0.0
    unstamped: int = 0  # a 2D/3D fix with time_usec 0 or time_week 0
    wrong_time: int = 0  # stamped later than anything the autopilot sent on its current boot
    inaccurate: int = 0
    max_err_ratio: float = 0.0
    fresh_after_faults: int = 0  # fresh GPS_INPUT in the quiet window after the last fault
    hearing_judged: bool = True  # False when a SIGTERM is one of the faults: the process stops before any quiet window
    traceback: str = ""
    mcap: str = ""
    stderr_tail: list[str] = field(default_factory=list)
    violations: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def run_scenario(name: str, faults: list[Fault], *, transport: str = "tcp", workdir: Path, quiet_s: float = 6.0,
                 extra_args: tuple[str, ...] = ("--set", "streams.GPS_RAW_INT=5"), start_timeout_s: float = 90.0,
                 seed: int = 0, keep_going_s: float = 10.0, exit_timeout_s: float = 60.0) -> tuple[LiveResult, Peer, Companion]:
    """One companion process against the peer: warm up until GPS_INPUT flows, the faults, ``quiet_s`` of plain
    stream, then SIGTERM (unless a fault sent it) while the stream goes on; everything judged by :func:`judge_live`."""
    workdir = Path(workdir) / f"{name}-{transport}"
    workdir.mkdir(parents=True, exist_ok=True)
    out = workdir / "live.mcap"
    peer = Peer(transport, seed=seed)
    comp = Companion(peer.url, out, *extra_args, workdir=workdir)
    peer.companion = comp
    res = LiveResult(name, transport)
    try:
        peer.connect(start_timeout_s)
        t_start = time.monotonic()
        peer.play(lambda now: bool(peer.fresh_since(0.0)) or comp.proc.poll() is not None
                  or time.monotonic() - t_start > start_timeout_s)
        res.started = bool(peer.fresh_since(0.0))
        if res.started and comp.proc.poll() is None:
            t0 = peer.play_now()
            t0_mono = time.monotonic()
            last = max((f.at_s + f.duration_s for f in faults), default=0.0)
            sig = next((f for f in faults if isinstance(f, Sigterm)), None)
            end_faults = t0 + last
            peer.play(lambda now: now >= end_faults + quiet_s or comp.proc.poll() is not None, faults, t0)
            quiet_from = t0_mono + (last + 1.0)  # what arrives after the last fault has had 1 s to pass
            res.fresh_after_faults = len([g for g in peer.fresh_since(quiet_from)])
            res.hearing_judged = sig is None
            if comp.proc.poll() is not None and peer.sigterm_mono is None:
                res.died_s = time.monotonic() - t0_mono
            if sig is None:
                peer.sigterm()
            # the stream goes on while the companion stops (an autopilot does not pause for it)
            if peer.sigterm_mono is not None:
                stop_at = peer.sigterm_mono + keep_going_s
                peer.play(lambda now: comp.proc.poll() is not None or time.monotonic() > stop_at)
        rc = comp.wait(exit_timeout_s)
        if rc is None:
            res.notes.append(f"did not exit within {exit_timeout_s:g} s of SIGTERM: killed")
            comp.kill()
        res.exit_code = rc
        if peer.sigterm_mono is not None and rc is not None and res.died_s is None:
            res.sigterm_to_exit_s = comp.exit_mono - peer.sigterm_mono
    finally:
        comp.close()
        peer.close()
    judge_live(res, peer, comp)
    return res, peer, comp


def judge_live(res: LiveResult, peer: Peer, comp: Companion) -> None:
    err = comp.stderr
    res.stderr_tail = err.strip().splitlines()[-5:]
    for mark in TRACEBACK_MARKS:
        if mark in err:
            res.traceback = [line for line in err.strip().splitlines() if line.strip()][-1][:200]
    gi = peer.gps_inputs
    res.gps_inputs = len(gi)
    lags = [g.lag_s for g in gi if g.lag_s is not None]
    res.max_lag_s = max(lags, default=0.0)
    res.stale = sum(1 for x in lags if x > MAX_LAG_S)
    res.unstamped = sum(1 for g in gi if g.fix_type >= 2 and (g.boot_s == 0 or g.time_week == 0))
    res.wrong_time = sum(1 for g in gi if g.ahead)
    ratios = [g.err_h_m / g.h_acc_m for g in gi if g.fix_type >= 3 and g.err_h_m is not None and g.h_acc_m > 0]
    res.max_err_ratio = max(ratios, default=0.0)
    res.inaccurate = sum(1 for r in ratios if r > ACCURACY_FACTOR)
    res.mcap = check_mcap(comp.out) if comp.out.exists() else "no MCAP written"
    v = res.violations
    if not res.started:
        v.append("no_start")
    if res.died_s is not None:
        v.append("died")
    if res.started and res.died_s is None and res.hearing_judged and res.fresh_after_faults == 0:
        v.append("deaf")
    if res.exit_code != 0:
        v.append("bad_exit")
    if res.sigterm_to_exit_s is not None and res.sigterm_to_exit_s > SIGTERM_EXIT_S:
        v.append("slow_sigterm")
    if res.exit_code is None:
        v.append("hang")
    if res.traceback:
        v.append("traceback")
    if res.stale:
        v.append("stale")
    if res.unstamped:
        v.append("unstamped")
    if res.wrong_time:
        v.append("wrong_time")
    if res.inaccurate:
        v.append("inaccurate")
    if res.mcap:
        v.append("mcap")


#: the benchmark's scenarios: name -> faults (times from the first fresh GPS_INPUT)
def scenarios() -> dict[str, Callable[[], list[Fault]]]:
    ext = {
        "GPS_RAW_INT": [("lat", 900000000), ("lat", -900000000), ("lon", 1800000000), ("lon", -1800000000),
                        ("alt", 2147483647), ("alt", -2147483648)],
        "RAW_IMU": [("xacc", 32767), ("zacc", -32768), ("xgyro", 32767), ("zgyro", -32768)],
        "ATTITUDE": [("roll", math.nan), ("yaw", math.inf), ("pitch", 1e22)],
    }
    return {
        "garbage": lambda: [Garbage(1.0, 5.0)],
        "bad_crc": lambda: [BadCrc(1.0, 5.0)],
        "mavlink1_mixed": lambda: [Mavlink1(1.0, 5.0)],
        "extreme_fields": lambda: [Inject(1.0, ext, duration_s=3.0, repeat_hz=5.0)],
        "system_time_4e16": lambda: [Inject(1.0, {"SYSTEM_TIME": [("time_unix_usec", 40_000_000_000_000_000)]})],
        "future_attitude_30s": lambda: [Inject(1.0, {"ATTITUDE": [("time_boot_ms", "+30s")]})],
        "imu_forward_1e5s": lambda: [Inject(1.0, {"RAW_IMU": [("time_usec", "+100000s")]})],
        "times_back_and_forth": lambda: [Inject(1.0, {"RAW_IMU": [("time_usec", "-10s")]}),
                                         Inject(2.0, {"ATTITUDE": [("time_boot_ms", "+1000s")]}),
                                         Inject(3.0, {"GPS_RAW_INT": [("time_usec", "-5s")]})],
        "burst_14k": lambda: [Burst(1.0, 3.0)],
        "burst_40k": lambda: [Burst(1.0, 3.0, rate=40_000)],
        "sigterm_in_burst_40k": lambda: [Burst(1.0, 6.0, rate=40_000), Sigterm(3.5)],
        "silence_then_burst": lambda: [Silence(1.0, 4.0)],
        "reboot_mid_send": lambda: [Reboot(1.0, 1.5)],
    }


def run_live_fuzz(*, load=None, workdir: Path, seed: int = 0, transports=("tcp", "udp"), names=None,
                  command: str = "nice -n 10 .venv/bin/python -m replay.fuzz --live-only") -> str:
    """Every scenario over each transport; the results as a Markdown section."""
    from replay.harness.results import md_table

    rows = []
    results = []
    for name, make in scenarios().items():
        if names and name not in names:
            continue
        for tr in transports:
            res, _peer, _comp = run_scenario(name, make(), transport=tr, workdir=Path(workdir) / "live", seed=seed)
            if load is not None:
                load.sample()
            results.append(res)
            print(f"live {name} {tr}: {res.violations or 'ok'} exit {res.exit_code} sigterm->exit "
                  f"{res.sigterm_to_exit_s} stale {res.stale} max lag {res.max_lag_s:.2f} s {res.traceback}",
                  file=sys.stderr, flush=True)
            rows.append([name, tr, "yes" if not res.violations else "no", res.exit_code,
                         "-" if res.sigterm_to_exit_s is None else round(res.sigterm_to_exit_s, 2),
                         "-" if res.died_s is None else f"died {res.died_s:.1f} s in",
                         res.fresh_after_faults, res.gps_inputs, res.stale, round(res.max_lag_s, 2), res.unstamped,
                         res.wrong_time, res.inaccurate,
                         round(res.max_err_ratio, 2), res.traceback or "-", res.mcap or "ok",
                         ", ".join(res.violations) or "-"])
    head = ["scenario", "link", "ok", "exit", "SIGTERM -> exit s", "died", "fresh GPS_INPUT after faults",
            "GPS_INPUT", f"stale (> {MAX_LAG_S:g} s)", "max lag s", "fix without a time", "another boot's time",
            "error > 4 x accuracy", "max error / accuracy",
            "traceback", "MCAP", "violations"]
    import platform

    lines = [
        "## A hostile live link against `companion run --inject inject`",
        "",
        "Command (repository root):",
        "",
        f"    {command}",
        "",
        f"replay/fuzz/link.py: a fake autopilot on loopback TCP (it listens, `--connect tcp:`) and UDP (`--connect "
        f"udpin:`) plays the generated sample flight from 20 s in real time (HEARTBEAT, SYSTEM_TIME, GPS_RAW_INT 5 Hz, "
        f"RAW_IMU 50 Hz, ATTITUDE 10 Hz); faults start 1 s after the first fresh GPS_INPUT (silence_then_burst: 4 s "
        f"silent, the link declared lost and reconnected, then the backlog at once; reboot_mid_send: 1.5 s silent, "
        f"then the boot clock restarts at 1 s); 6 s of plain stream "
        f"follow the last one, then SIGTERM while the stream goes on. Lag of a GPS_INPUT = its arrival minus the "
        f"send time of the first stream message it could have been built from. {platform.machine()}, "
        f"{os.cpu_count()} cores" + (f"; {load.text()}" if load is not None else "") + ".",
        "",
        "Properties: up until the SIGTERM, fresh (lag <= 0.5 s) GPS_INPUT after the faults (not deaf), exit 0 within "
        "2 s of SIGTERM, no traceback, no GPS_INPUT lagging more than 0.5 s on the autopilot's clock (silence then "
        "burst: the held-back messages' send time is when the autopilot stamped them), no 2D/3D fix with time_usec or "
        "time_week 0, none stamped later than anything the autopilot sent on its current boot (after a reboot: the "
        "previous boot's time), no 3D fix off by more than 4 x its accuracy, a readable MCAP.",
        "",
        md_table(head, rows),
    ]
    return "\n".join(lines)
