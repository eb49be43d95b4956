"""The process and MAVLink side of the SITL harnesses (replay.live.sitl, replay.live.sitl_gravity): start an ArduPilot
SITL binary on loopback, talk to it as a ground station, set and verify parameters, stop everything by PID.

Nothing of ArduPilot is in this repository: the binary is the user's (``--sitl-bin`` or the environment variable the
harness names). Every wait is for a condition with a bound on wall time; vehicle time comes from the messages.
Parameter names differ between ArduPilot versions and SITL ignores an unknown name in a defaults file without a word,
so every parameter a run sets is read back (PARAM_REQUEST_READ -> PARAM_VALUE) and the run fails on one that is
missing or holds another value (:meth:`Vehicle.verify_params`).
"""

from __future__ import annotations

import math
import os
import re
import signal
import socket
import subprocess
import time
from contextlib import suppress
from pathlib import Path


class HarnessError(RuntimeError):
    pass


# -- processes -----------------------------------------------------------------------------------------------------
def stop_pid(proc: subprocess.Popen | None, term_s: float = 10.0) -> None:
    """SIGTERM this process, then SIGKILL it if it is still there after ``term_s``."""
    if proc is None or proc.poll() is not None:
        return
    with suppress(ProcessLookupError):
        os.kill(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout=term_s)
    except subprocess.TimeoutExpired:
        with suppress(ProcessLookupError):
            os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=5)


def _port_free(port: int) -> bool:
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


#: an instance handed out stays claimed this long (wall time), so that runs started together take different ones
#: before any of their SITLs has bound its ports
CLAIM_S = 60.0


def free_instance(limit: int = 20, start: int = 0, registry: Path | None = None, claim_s: float = CLAIM_S) -> int:
    """A SITL instance number -I (from ``start``) whose ports 5760+10i .. 5763+10i are free on loopback and which no
    harness on this machine was handed in the last ``claim_s`` (the claims are a file in the temp directory, read and
    written under an exclusive lock)."""
    import fcntl
    import tempfile

    path = registry or Path(tempfile.gettempdir()) / "companion-sitl-instances"
    with open(path, "a+") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        f.seek(0)
        now = time.time()
        claims = {}
        for line in f.read().splitlines():
            with suppress(ValueError):
                i, t = line.split()
                if now - float(t) < claim_s:
                    claims[int(i)] = float(t)
        for i in range(start, limit):
            if i not in claims and all(_port_free(5760 + 10 * i + k) for k in range(4)):
                claims[i] = now
                f.seek(0)
                f.truncate()
                f.write("".join(f"{k} {v}\n" for k, v in claims.items()))
                return i
    raise HarnessError(f"no SITL instance from {start} below {limit} with free ports 5760+10i..5763+10i")


def resolve_bin(arg: str | None, env: str = "COMPANION_SITL_BIN") -> Path:
    b = arg or os.environ.get(env)
    if not b:
        raise HarnessError(f"no SITL binary: pass --sitl-bin or set {env}")
    p = Path(b).expanduser().resolve()
    if not (p.is_file() and os.access(p, os.X_OK)):
        raise HarnessError(f"SITL binary not executable: {p}")
    return p


def resolve_defaults(arg: str | None, sitl_bin: Path, vehicle: str = "copter") -> Path | None:
    """ArduPilot's own defaults file for the vehicle (Tools/autotest/default_params/<vehicle>.parm relative to the
    binary of a checkout), ``arg`` when given, None for ``arg == "none"`` or when there is none."""
    if arg == "none":
        return None
    if arg:
        return Path(arg).resolve()
    p = (sitl_bin.parent / f"../../../Tools/autotest/default_params/{vehicle}.parm").resolve()
    return p if p.exists() else None


def write_params(path: Path, params: dict) -> None:
    path.write_text("".join(f"{k} {v}\n" for k, v in params.items()))


def sitl_commit(sitl_bin: Path) -> str:
    try:
        root = sitl_bin.parents[3]
        return subprocess.run(["git", "-C", str(root), "log", "-1", "--format=%H %cd %s"], capture_output=True,
                              text=True, timeout=10).stdout.strip() or "unknown"
    except (IndexError, OSError, subprocess.SubprocessError):
        return "unknown"


def machine_state() -> str:
    la = os.getloadavg()
    return f"load average {la[0]:.2f} / {la[1]:.2f} / {la[2]:.2f} on {os.cpu_count()} cores"


_DRAG_RE = re.compile(r"Suggested EK3_DRAG_BCOEF_\* = ([0-9.]+), EK3_DRAG_MCOEF = ([0-9.]+)")


def suggested_drag(sitl_output: str) -> dict[str, float] | None:
    """EKF3's drag-fusion coefficients that match SITL's multicopter model, from the line SITL prints for its frame
    at start ("Suggested EK3_DRAG_BCOEF_* = B, EK3_DRAG_MCOEF = M"); None when it printed none. A ballistic
    coefficient of 0 means the frame has no body drag (momentum drag only)."""
    m = _DRAG_RE.search(sitl_output)
    if m is None:
        return None
    b, mc = float(m.group(1)), float(m.group(2))
    return {"EK3_DRAG_BCOEF_X": b, "EK3_DRAG_BCOEF_Y": b, "EK3_DRAG_MCOEF": mc}


def param_mismatches(wanted: dict[str, float], got: dict[str, float | None], rel: float = 1e-4) -> list[str]:
    """One line per parameter the autopilot does not hold as asked: unknown to it (None) or another value (PARAM_VALUE
    carries a float32: equal within ``rel`` of the value, or 1e-6 absolute)."""
    out = []
    for name, v in wanted.items():
        g = got.get(name)
        if g is None:
            out.append(f"{name}: unknown to this autopilot (no PARAM_VALUE)")
        elif not math.isclose(float(g), float(v), rel_tol=rel, abs_tol=1e-6):
            out.append(f"{name}: holds {g:g}, not {float(v):g}")
    return out


# -- the MAVLink side ------------------------------------------------------------------------------------------------
class Vehicle:
    """A ground-station link to SITL (its SERIAL0): every message goes to ``on_message`` (a flight log) and to the
    hooks; commands, parameters and bounded waits."""

    def __init__(self, url: str, on_message, clock, connect_s: float = 30.0):
        """``clock()`` is the vehicle time the log has reached (s, or None before the first stamped message)."""
        from pymavlink import mavutil

        self.mavutil = mavutil
        self.on_message = on_message
        self.clock = clock
        deadline = time.monotonic() + connect_s
        while True:  # SITL binds its port shortly after start: retry until it accepts (bounded)
            try:
                self.m = mavutil.mavlink_connection(url, dialect="ardupilotmega", source_system=250,
                                                    source_component=190, retries=0)
                break
            except OSError as e:
                if time.monotonic() > deadline:
                    raise HarnessError(f"SITL never accepted {url}: {e}") from e
                time.sleep(0.2)
        from companion.sim.sitl_gravimeter_link import raise_on_eof

        raise_on_eof(self.m)  # SITL gone: a HarnessError from pump, not a loop on a closed socket
        self.hooks: list = []

    def close(self) -> None:
        with suppress(Exception):
            self.m.close()

    def pump(self, until, wall_s: float, what: str, must: bool = True) -> bool:
        """Read messages until ``until()`` is true or ``wall_s`` of wall time passed."""
        deadline = time.monotonic() + wall_s
        while True:
            if until():
                return True
            if time.monotonic() > deadline:
                if must:
                    raise HarnessError(f"timed out after {wall_s:g} s waiting for {what}")
                return False
            try:
                m = self.m.recv_match(blocking=True, timeout=0.1)
                while m is not None:
                    self.on_message(m)
                    for h in list(self.hooks):
                        h(m)
                    m = self.m.recv_match(blocking=False)
            except ConnectionError as e:
                raise HarnessError(f"the autopilot's link closed while waiting for {what}: {e}") from e

    def wait_vehicle_time(self, t: float, speedup: float, what: str) -> None:
        now = self.clock() or 0.0
        self.pump(lambda: (self.clock() or 0.0) >= t, 30.0 + 3.0 * max(0.0, t - now) / speedup, what)

    def request_streams(self, streams_hz: dict[str, float]) -> None:
        mav = self.mavutil.mavlink
        for name, hz in streams_hz.items():
            mid = getattr(mav, f"MAVLINK_MSG_ID_{name}")
            self.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mid, 1e6 / hz, wait_ack=False)

    def command(self, cmd: int, *params: float, wait_ack: bool = True, wall_s: float = 5.0) -> int | None:
        p = list(params) + [0.0] * (7 - len(params))
        got: list[int] = []

        def hook(m):
            if m.get_type() == "COMMAND_ACK" and m.command == cmd:
                got.append(int(m.result))

        self.hooks.append(hook)
        try:
            self.m.mav.command_long_send(1, 1, cmd, 0, *p)
            if not wait_ack:
                return None
            self.pump(lambda: bool(got), wall_s, f"COMMAND_ACK {cmd}", must=False)
            return got[0] if got else None
        finally:
            self.hooks.remove(hook)

    def read_params(self, names, wall_s: float = 10.0) -> dict[str, float | None]:
        """Each parameter's value as the autopilot holds it (PARAM_REQUEST_READ by name, re-asked every second),
        None for a name it never answered: it does not have it."""
        got: dict[str, float] = {}
        want = list(names)

        def hook(m):
            if m.get_type() == "PARAM_VALUE":
                pid = m.param_id.rstrip("\x00") if isinstance(m.param_id, str) else m.param_id.decode().rstrip("\x00")
                if pid in want:
                    got[pid] = float(m.param_value)

        self.hooks.append(hook)
        try:
            deadline = time.monotonic() + wall_s
            while time.monotonic() < deadline and len(got) < len(want):
                for n in want:
                    if n not in got:
                        self.m.mav.param_request_read_send(1, 1, n.encode(), -1)
                self.pump(lambda: len(got) == len(want), 1.0, "PARAM_VALUE", must=False)
        finally:
            self.hooks.remove(hook)
        return {n: got.get(n) for n in want}

    def verify_params(self, wanted: dict[str, float]) -> None:
        """Fail the run unless the autopilot holds every parameter as asked (see module docstring)."""
        bad = param_mismatches(wanted, self.read_params(wanted))
        if bad:
            raise HarnessError("parameters not accepted: " + "; ".join(bad))

    def set_param(self, name: str, value: float, wall_s: float = 10.0) -> bool:
        """PARAM_SET until the autopilot echoes the value (PARAM_VALUE), within ``wall_s``."""
        ok: list[float] = []

        def hook(m):
            if m.get_type() == "PARAM_VALUE" and m.param_id.rstrip("\x00") == name:
                ok.append(m.param_value)

        self.hooks.append(hook)
        try:
            deadline = time.monotonic() + wall_s
            while time.monotonic() < deadline:
                self.m.mav.param_set_send(1, 1, name.encode(), float(value), 9)
                if self.pump(lambda: bool(ok) and abs(ok[-1] - value) < 1e-3, 1.0, f"PARAM_VALUE {name}", must=False):
                    return True
            return False
        finally:
            self.hooks.remove(hook)

    def set_mode(self, mode: int, current, wall_s: float = 15.0) -> None:
        """Switch to ``mode`` (custom mode number); ``current()`` is the mode the log last saw."""
        mav = self.mavutil.mavlink
        deadline = time.monotonic() + wall_s
        while current() != mode:
            if time.monotonic() > deadline:
                raise HarnessError(f"mode {mode} not accepted")
            self.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode, wait_ack=True)
            self.pump(lambda: current() == mode, 2.0, "mode", must=False)

    def goto_ned(self, n: float, e: float, d: float) -> None:
        mask = 0b0000_1111_1111_1000  # position only
        self.m.mav.set_position_target_local_ned_send(0, 1, 1, self.mavutil.mavlink.MAV_FRAME_LOCAL_NED, mask,
                                                      n, e, d, 0, 0, 0, 0, 0, 0, 0, 0)
