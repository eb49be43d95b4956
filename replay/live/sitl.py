"""Real-autopilot A/B benchmark: ArduCopter SITL alone (arm A) against ArduCopter SITL + the real `companion run`
process feeding GPS2 with GPS_INPUT (arm B), on the same scripted flight, with GPS1 denied by SIM_GPS1_ENABLE=0.

    nice -n 5 .venv/bin/python -m replay.live.sitl --sitl-bin PATH/build/sitl/bin/arducopter \
        --scenarios healthy hover-deny-30 square-deny-30

The SITL binary is the user's (``--sitl-bin`` or env ``COMPANION_SITL_BIN``); nothing of ArduPilot is in this
repository. Parameters: the harness writes its own small defaults file into the run's temporary directory (the
vehicle set-up below and, for arm B, the README's "ArduPilot set-up"); ``--sitl-defaults`` adds ArduPilot's own
copter defaults in front of it (default: Tools/autotest/default_params/copter.parm relative to the binary, when
present; ``--sitl-defaults none`` to use only ours).

Processes: SITL in a temporary directory (fresh EEPROM) on 127.0.0.1, instance -I chosen so its ports are free
(SERIAL0 = 5760 + 10 I for the harness, SERIAL1 = 5762 + 10 I for the companion); the companion on SERIAL1.
Every wait is for a condition with a bound; every process is stopped by its PID (SIGTERM, then SIGKILL).
Vehicle time is the autopilot's boot time from the messages; the flight script runs on it.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from contextlib import suppress
from pathlib import Path

from replay.live import sitl_core as core

REPO = Path(__file__).resolve().parents[2]
RESULTS = REPO / "replay" / "results"
RESULTS_MD = RESULTS / "sitl_ab.md"
HOME = "-35.363261,149.165230,584,353"  # ArduPilot's usual SITL home (CMAC); any will do

#: set for both arms: quad frame, calibrated-looking INS, the square's speed; everything else SITL's defaults
VEHICLE_PARAMS = {
    "FRAME_CLASS": 1,
    "FRAME_TYPE": 0,
    "WP_SPD": 8.0,
    "WP_ACC": 2.5,
    "FENCE_ENABLE": 0,
    "FS_THR_ENABLE": 0,
    "SIM_GPS1_ENABLE": 1,
}
#: arm B: the README's "ArduPilot set-up" (instance 2 = MAVLink; GPS1 primary, GPS2 taken only when GPS1 has no 3D fix)
COMPANION_PARAMS = {
    "GPS2_TYPE": 14,
    "GPS_AUTO_SWITCH": 4,
    "GPS_PRIMARY": 0,
    "SERIAL1_PROTOCOL": 2,
    "EK3_SRC1_POSXY": 3,
    "EK3_SRC1_VELXY": 3,
    "EK3_SRC1_POSZ": 1,
    "EK3_SRC1_VELZ": 3,
}
#: arm B's companion settings besides --companion-set: the GNSS latency measured online (companion.nav.gnss_lag), the
#: autopilot's heading fused (SITL's gyros drift, SIM_DRIFT_SPEED), and no fix while armed beside a healthy GPS1 (no
#: GPS_AUTO_SWITCH switch to GPS2 when GPS1 is lost)
COMPANION_SETS = ["navigator.gnss_delay_estimate=true", "navigator.fuse_attitude_yaw=true",
                  "inject.backup_fix_when_armed=false"]
STREAMS_HZ = {  # requested on the harness's own link (SERIAL0) with SET_MESSAGE_INTERVAL
    "GLOBAL_POSITION_INT": 25, "SIMSTATE": 50, "ATTITUDE": 50, "LOCAL_POSITION_NED": 10, "GPS_RAW_INT": 5,
    "GPS2_RAW": 5, "EKF_STATUS_REPORT": 2, "SYS_STATUS": 1, "HEARTBEAT": 1,
}
EKF_READY_FLAGS = 0x10 | 0x200  # ESTIMATOR_POS_HORIZ_ABS | ESTIMATOR_PRED_POS_HORIZ_ABS


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


def free_instance(limit: int = 20) -> int:
    for i in range(limit):
        if all(_port_free(5760 + 10 * i + k) for k in range(4)):
            return i
    raise HarnessError("no SITL instance with free ports 5760+10i..5763+10i")


def resolve_bin(arg: str | None) -> Path:
    b = arg or os.environ.get("COMPANION_SITL_BIN")
    if not b:
        raise HarnessError("no SITL binary: pass --sitl-bin or set COMPANION_SITL_BIN")
    p = Path(b).expanduser().resolve()
    if not (p.is_file() and os.access(p, os.X_OK)):
        raise HarnessError(f"SITL binary not executable: {p}")
    return p


def resolve_defaults(arg: str | None, sitl_bin: Path) -> Path | None:
    if arg == "none":
        return None
    if arg:
        return Path(arg).resolve()
    p = (sitl_bin.parent / "../../../Tools/autotest/default_params/copter.parm").resolve()
    return p if p.exists() else None


def write_params(path: Path, params: dict) -> None:
    path.write_text("".join(f"{k} {v}\n" for k, v in params.items()))


# -- the MAVLink side ------------------------------------------------------------------------------------------------
class Vehicle:
    """The harness's GCS link on SERIAL0: feeds every message into a FlightLog; commands; bounded waits."""

    def __init__(self, url: str, log: core.FlightLog, connect_s: float = 30.0):
        from pymavlink import mavutil

        self.mavutil = mavutil
        self.log = log
        deadline = time.monotonic() + connect_s
        last = None
        while True:  # SITL binds its port shortly after start: retry until it accepts (bounded)
            try:
                self.m = mavutil.mavlink_connection(url, dialect="ardupilotmega", source_system=250, source_component=190, retries=0)
                break
            except OSError as e:
                last = e
                if time.monotonic() > deadline:
                    raise HarnessError(f"SITL never accepted {url}: {last}") from e
                time.sleep(0.2)
        self.hooks: list = []

    def close(self) -> None:
        with suppress(Exception):
            self.m.close()

    def pump(self, until, wall_s: float, what: str, must: bool = True) -> bool:
        """Read messages into the log until ``until()`` is true or ``wall_s`` of wall time passed."""
        deadline = time.monotonic() + wall_s
        while True:
            if until():
                return True
            if time.monotonic() > deadline:
                if must:
                    raise HarnessError(f"timed out after {wall_s:g} s waiting for {what}")
                return False
            m = self.m.recv_match(blocking=True, timeout=0.1)
            while m is not None:
                self.log.on_message(m)
                for h in list(self.hooks):
                    h(m)
                m = self.m.recv_match(blocking=False)

    def wait_vehicle_time(self, t: float, speedup: float, what: str) -> None:
        now = self.log.t_boot or 0.0
        self.pump(lambda: (self.log.t_boot or 0.0) >= t, 30.0 + 3.0 * max(0.0, t - now) / speedup, what)

    def request_streams(self) -> None:
        mav = self.mavutil.mavlink
        for name, hz in STREAMS_HZ.items():
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

    def set_param(self, name: str, value: float, wall_s: float = 10.0) -> bool:
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

    def set_mode(self, mode: int, wall_s: float = 15.0) -> None:
        mav = self.mavutil.mavlink
        deadline = time.monotonic() + wall_s
        while self.log.mode != mode:
            if time.monotonic() > deadline:
                raise HarnessError(f"mode {mode} not accepted")
            self.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode, wait_ack=True)
            self.pump(lambda: self.log.mode == mode, 2.0, "mode", must=False)

    def goto_ned(self, n: float, e: float, d: float) -> None:
        mask = 0b0000_1111_1111_1000  # position only
        self.m.mav.set_position_target_local_ned_send(0, 1, 1, self.mavutil.mavlink.MAV_FRAME_LOCAL_NED, mask,
                                                      n, e, d, 0, 0, 0, 0, 0, 0, 0, 0)


# -- one arm of one scenario -------------------------------------------------------------------------------------------
def fly(sc: core.Scenario, arm: str, a, work: Path) -> core.ArmResult:
    log = core.FlightLog()
    params = dict(VEHICLE_PARAMS)
    if arm == "B":
        params.update(COMPANION_PARAMS)
        params["GPS_AUTO_SWITCH"] = a.gps_auto_switch
    for kv in a.param or []:
        k, v = kv.split("=", 1)
        params[k] = float(v)
    ours = work / f"harness_{arm}.parm"
    write_params(ours, params)
    defaults = ",".join(str(p) for p in (a.defaults_path, ours) if p)
    inst = free_instance()
    base = 5760 + 10 * inst
    cmd = [str(a.sitl_bin_path), "--model", "+", "--speedup", str(a.speedup), "-I", str(inst), "--home", a.home,
           "--defaults", defaults]
    run_dir = work / f"sitl_{sc.name}_{arm}"
    run_dir.mkdir(parents=True, exist_ok=True)
    sitl = comp = None
    veh = None
    records: list[dict] = []
    mcap = work / f"companion_{sc.name}.mcap"
    notes: list[str] = []
    try:
        sitl = subprocess.Popen(cmd, cwd=run_dir, stdout=open(run_dir / "sitl.out", "w"), stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL)
        veh = Vehicle(f"tcp:127.0.0.1:{base}", log)
        veh.pump(lambda: log.modes != [], 30, "first HEARTBEAT")
        veh.request_streams()
        if arm == "B":
            ccmd = [sys.executable, "-m", "companion.cli", "run", "--connect", f"tcp:127.0.0.1:{base + 2}",
                    "--inject", "inject", "--gps-id", "1", "--out", str(mcap)] + sum((["--set", s] for s in _sets(a)), [])
            comp = subprocess.Popen(ccmd, cwd=REPO, stdout=open(work / f"companion_{sc.name}.out", "w"),
                                    stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        veh.pump(lambda: log.truth != [] and log.ekf != [], 30, "SIMSTATE and GLOBAL_POSITION_INT streams")
        veh.pump(lambda: log.gps_fix(1) >= 3, 90, "GPS1 3D fix")
        if arm == "B":
            ok = veh.pump(lambda: log.gps_fix(2) >= 3, 90, "GPS2 (companion) 3D fix", must=False)
            if not ok:
                notes.append("GPS2 never reported a 3D fix before arming")
        veh.pump(lambda: bool(log.ekf_flags) and (log.ekf_flags[-1][1] & EKF_READY_FLAGS) == EKF_READY_FLAGS, 120,
                 "EKF absolute horizontal position")
        veh.set_mode(core.MODE_GUIDED)
        mav = veh.mavutil.mavlink
        deadline = time.monotonic() + a.arm_timeout
        while not log.armed and time.monotonic() < deadline:
            veh.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, wait_ack=True)
            veh.pump(lambda: log.armed, 3.0, "armed", must=False)
        if not log.armed:
            log.mark("end")
            notes.append("arming refused")
            return _finish(sc, arm, log, records, notes)
        veh.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, sc.alt_m)
        veh.pump(lambda: bool(log.ekf) and log.ekf[-1][3] >= sc.alt_m - 1.0, 60 / min(a.speedup, 1) + 30, "climb to altitude")
        log.mark("hover")
        start_ne = log.local[:2] if log.local else (0.0, 0.0)
        _script(veh, sc, a, log, start_ne)
        log.mark("end")
    except HarnessError as e:
        notes.append(f"harness: {e}")
        if log.t_boot is not None:
            log.mark("end")
    finally:
        stop_pid(comp)
        if veh is not None:
            veh.close()
        stop_pid(sitl)
        with suppress(OSError, ValueError, TypeError):
            (work / f"log_{sc.name}_{arm}.json").write_text(json.dumps(log.to_dict()).replace("NaN", "null"))
        with suppress(OSError):
            (run_dir / "texts.txt").write_text("".join(f"{t:9.3f} {sev} {txt}\n" for t, sev, txt in log.texts)
                                               + "".join(f"{t:9.3f} harness: {txt}\n" for t, txt in log.events)
                                               + "".join(f"{t:9.3f} mode {m} armed {a}\n" for t, m, a in log.modes))
    if arm == "B" and mcap.exists():
        records = read_gps_input(mcap)
        notes.append(f"companion MCAP: {len(records)} GPS_INPUT records")
    return _finish(sc, arm, log, records, notes)


def _sets(a) -> list[str]:
    return COMPANION_SETS + list(a.companion_set or [])


def _finish(sc, arm, log, records, notes) -> core.ArmResult:
    r = core.analyse(sc, arm, log, records)
    r.notes += notes
    return r


def _script(veh: Vehicle, sc: core.Scenario, a, log: core.FlightLog, start_ne) -> None:
    """Hover, then the square's laps, with GPS1 switched off/on on vehicle time; ends when the denial's recovery
    time and the laps are both done (or, with no square, after the hover)."""
    sched: list[tuple[float, str]] = []
    landed = {"v": False}

    def deny(t_on: float) -> None:
        sched.append((t_on, "off"))
        sched.append((t_on + sc.deny_s, "on"))

    def tick(_m=None) -> None:
        while sched and log.t_boot is not None and log.t_boot >= sched[0][0]:
            _t, what = sched.pop(0)
            # the param set is sent from inside the read loop: mark the vehicle time it was due at
            veh.m.mav.param_set_send(1, 1, b"SIM_GPS1_ENABLE", 0.0 if what == "off" else 1.0, 9)
            log.mark("deny_on" if what == "off" else "deny_off", _t)
            log.note(f"SIM_GPS1_ENABLE {'0' if what == 'off' else '1'}")
        if log.mode is not None and log.mode != core.MODE_GUIDED:
            landed["v"] = True

    veh.hooks.append(tick)
    try:
        t_h = log.t_boot
        if sc.deny_in == "hover":
            deny(t_h + sc.deny_at_s)
        hover_end = t_h + sc.hover_s
        if sc.laps == 0:
            end = max(hover_end, t_h + sc.deny_at_s + sc.deny_s + sc.recover_s) if sc.denies else hover_end
            veh.wait_vehicle_time(end, a.speedup, "end of hover")
            _confirm_gps1(veh, log)
            return
        veh.wait_vehicle_time(hover_end, a.speedup, "end of hover")
        log.mark("square")
        t_sq = log.t_boot
        if sc.deny_in == "square" and sc.deny_lap == 0:
            deny(t_sq + sc.deny_at_s)
        end_t = (t_sq + sc.deny_at_s + sc.deny_s + sc.recover_s) if (sc.denies and sc.deny_lap == 0) else math.inf
        n0, e0 = start_ne
        lap = 0
        while True:
            lap += 1
            if sc.denies and sc.deny_lap == lap:
                deny(log.t_boot + sc.deny_at_s)
                end_t = log.t_boot + sc.deny_at_s + sc.deny_s + sc.recover_s
            log.note(f"lap {lap}")
            for dn, de in core.square_corners(sc.side_m):
                tn, te = n0 + dn, e0 + de
                if landed["v"]:
                    break
                veh.goto_ned(tn, te, -sc.alt_m)
                leg_s = sc.side_m / sc.speed_mps * 2.5 + 15
                veh.pump(lambda: landed["v"] or (log.t_boot or 0) >= end_t or (
                    log.local is not None and math.hypot(log.local[0] - tn, log.local[1] - te) < 2.0),
                    leg_s / a.speedup + 30, "corner", must=False)
                if (log.t_boot or 0) >= end_t:
                    break
            if landed["v"] or (log.t_boot or 0) >= end_t:
                break
            if lap >= sc.laps and not math.isfinite(end_t):
                break
            if lap >= sc.laps and (log.t_boot or 0) >= end_t:
                break
        if math.isfinite(end_t):  # after a mode change (failsafe LAND) keep recording to the scripted end
            veh.wait_vehicle_time(end_t, a.speedup, "scripted end")
        _confirm_gps1(veh, log)
    finally:
        veh.hooks.remove(tick)


def _confirm_gps1(veh: Vehicle, log: core.FlightLog) -> None:
    if "deny_on" in log.marks and not veh.set_param("SIM_GPS1_ENABLE", 1.0):
        log.note("SIM_GPS1_ENABLE=1 not acknowledged at the end")


def read_gps_input(path: Path) -> list[dict]:
    from companion.record.inspect import RecordError, iter_payloads

    out = []
    with suppress(RecordError):
        for _topic, _t, data in iter_payloads(path, "/inject/gps_input"):
            with suppress(ValueError):
                out.append(json.loads(data))
    return out


# -- results -----------------------------------------------------------------------------------------------------------
def plot(results: list[core.ArmResult], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    denied = [r for r in results if math.isfinite(r.deny_on)]
    scen = list(dict.fromkeys(r.scenario for r in denied))
    if not scen:
        return
    fig, axes = plt.subplots(len(scen), 1, figsize=(12, 3.2 * len(scen)), squeeze=False)
    for ax, sc in zip(axes[:, 0], scen):
        d = core.SCENARIOS[sc].deny_s
        ax.axvspan(0, d, color="0.9", label=f"GPS1 denied ({d:g} s)")
        x0, x1 = -20.0, d + core.SCENARIOS[sc].recover_s
        top = 1.0
        for r in (x for x in denied if x.scenario == sc):
            col = "tab:blue" if r.arm == "A" else "tab:red"
            tx = r.t_err - r.deny_on
            ax.plot(tx, r.err, color=col, lw=1.2, label=f"EKF, {core.ARM_NAMES[r.arm]}")
            sel = (tx >= x0) & (tx <= x1)
            top = max(top, float(r.err[sel].max()) if sel.any() else 0.0)
            if r.arm == "B" and len(r.own_t):
                ox = r.own_t - r.deny_on
                ax.plot(ox, r.own_err, color="tab:orange", lw=0.9, ls="--", label="companion's own GPS_INPUT (B)")
                sel = (ox >= x0) & (ox <= x1)
                top = max(top, float(r.own_err[sel].max()) if sel.any() else 0.0)
            fs, land = r.failsafe_s, r.land_s
            if math.isfinite(fs) and math.isfinite(land) and abs(fs - land) < 0.5:
                ax.axvline(fs, color=col, ls=":", lw=1.3, label=f"EKF failsafe -> LAND ({r.arm}) +{fs:.0f} s")
            else:
                for v, ls, what in ((fs, ":", "EKF failsafe"), (land, "-.", "LAND")):
                    if math.isfinite(v):
                        ax.axvline(v, color=col, ls=ls, lw=1.3, label=f"{what} ({r.arm}) +{v:.0f} s")
        ax.set_xlim(x0, x1)
        ax.set_ylim(0, top * 1.15)
        ax.set_title(f"{sc}: horizontal position error vs SITL truth (A: ArduPilot alone, B: + companion as GPS2)",
                     fontsize=9)
        ax.set_xlabel("time since GPS1 denied (s)")
        ax.set_ylabel("error (m)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)  # beside the data
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def machine_state() -> str:
    la = os.getloadavg()
    return f"load average {la[0]:.2f} / {la[1]:.2f} / {la[2]:.2f} on {os.cpu_count()} cores"


def sitl_commit(sitl_bin: Path) -> str:
    try:
        root = sitl_bin.parents[3]
        return subprocess.run(["git", "-C", str(root), "log", "-1", "--format=%H %cd %s"], capture_output=True,
                              text=True, timeout=10).stdout.strip() or "unknown"
    except (IndexError, OSError, subprocess.SubprocessError):
        return "unknown"


def write_results(results: list[core.ArmResult], a, argv: list[str], started: str, load_before: str,
                  after: str | None = None) -> None:
    from replay.harness.results import write_section

    RESULTS.mkdir(parents=True, exist_ok=True)
    png = RESULTS / f"sitl_ab{a.tag}.png"
    plot(results, png)
    if not RESULTS_MD.exists():
        RESULTS_MD.write_text("# ArduPilot SITL A/B: ArduPilot alone vs ArduPilot + companion\n\n"
                              "Written by `python -m replay.live.sitl`; each block names the command that produced it.\n")
    params_b = {**COMPANION_PARAMS, "GPS_AUTO_SWITCH": a.gps_auto_switch}
    text = [
        f"## {', '.join(dict.fromkeys(r.scenario for r in results))}"
        + (f" (arm B with GPS_AUTO_SWITCH={a.gps_auto_switch})" if a.gps_auto_switch != 4 else "")
        + (f" (companion --set {' '.join(a.companion_set)})" if a.companion_set else "") + "\n",
        f"Command: `{' '.join(['python -m replay.live.sitl'] + argv)}`  ",
        f"SITL: `{a.sitl_bin_path}` at ArduPilot commit {sitl_commit(a.sitl_bin_path)}; `--speedup {a.speedup}`; "
        f"defaults: {a.defaults_path or 'none (harness params only)'} + the harness's own params.  ",
        f"Started {started}; machine before: {load_before}; after: {after or machine_state()}.  ",
        f"Both arms: {', '.join(f'{k}={v}' for k, v in VEHICLE_PARAMS.items())}. Arm B adds "
        f"{', '.join(f'{k}={v}' for k, v in params_b.items())}"
        + f" and `--set {' '.join(_sets(a))}`" + ".\n",
        "EKF error = GLOBAL_POSITION_INT vs SIMSTATE truth interpolated to its time_boot_ms (SIMSTATE stamped with "
        "the newest time_boot_ms on the stream, SIMSTATE and ATTITUDE both at 50 Hz: <= 20 ms). Times after the "
        "denial are from the moment SIM_GPS1_ENABLE=0 was sent. An EKF failsafe switches to LAND (FS_EKF_ACTION default): "
        "from then on the vehicle descends and the recovery columns describe a landing vehicle, not the flight.\n",
        "### EKF horizontal error per phase, failsafe timing\n",
        core.phase_table(results), "",
    ]
    mt = core.marks_table(results)
    if mt:
        text += ["### EKF horizontal error (m) every 5 s after GPS1 is denied\n", mt, ""]
    ct = core.companion_table(results)
    if ct:
        text += ["### The companion's GPS_INPUT (arm B)\n",
                 "Own error: the companion's sent GPS_INPUT position vs truth at the time_usec it claims.\n", ct, ""]
    lt = core.lag_table(results)
    if lt:
        text += ["### Delay on the square (before any denial)\n",
                 "The time shift tau that best aligns the position with the truth at t - tau (0.01 s steps): "
                 "what a delayed source costs at 8 m/s is about 8 m/s x tau.\n", lt, ""]
    verdicts = core.ab_verdicts(results)
    if verdicts:
        text += ["### Against the targets\n"] + verdicts + [""]
    text += ["### Arming and notes\n", core.arming_lines(results), ""]
    if png.exists():
        text += [f"![EKF error after the denial]({png.name})", ""]
    write_section(RESULTS_MD, f"sitl-ab{a.tag}", "\n".join(text), "ArduPilot SITL A/B: ArduPilot alone vs ArduPilot + companion")
    (RESULTS / f"sitl_ab{a.tag}.json").write_text(json.dumps([_summary(r) for r in results], indent=1))


def _summary(r: core.ArmResult) -> dict:
    d = {k: v for k, v in r.__dict__.items() if k not in ("t_err", "err", "own_t", "own_err")}
    return json.loads(json.dumps(d, default=str).replace("NaN", "null"))


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m replay.live.sitl", description=__doc__.split("\n\n")[0])
    p.add_argument("--sitl-bin", help="ArduCopter SITL binary (default: env COMPANION_SITL_BIN)")
    p.add_argument("--sitl-defaults", help="ArduPilot defaults file (default: copter.parm relative to the binary; 'none')")
    p.add_argument("--scenarios", nargs="+", default=core.DEFAULT_SCENARIOS, choices=sorted(core.SCENARIOS))
    p.add_argument("--arms", nargs="+", default=["A", "B"], choices=["A", "B"])
    p.add_argument("--speedup", type=float, default=1.0)
    p.add_argument("--home", default=HOME)
    p.add_argument("--gps-auto-switch", type=int, default=4, help="GPS_AUTO_SWITCH for arm B (README: 4)")
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="extra SITL parameter for both arms")
    p.add_argument("--companion-set", action="append", metavar="SECTION.KEY=VALUE", help="passed to companion run --set")
    p.add_argument("--arm-timeout", type=float, default=90.0)
    p.add_argument("--tag", default="", help="suffix of the results block/PNG/JSON (e.g. _autoswitch2)")
    p.add_argument("--keep", action="store_true", default=True,
                   help="keep the temporary directory: SITL and companion output, flight logs for --from-dir (default)")
    p.add_argument("--clean", dest="keep", action="store_false", help="delete the temporary directory at the end")
    p.add_argument("--no-write", action="store_true", help="print only; do not touch replay/results")
    p.add_argument("--from-dir", help="re-analyse the flights kept in this directory (--keep) instead of flying")
    a = p.parse_args(argv)
    a.sitl_bin_path = resolve_bin(a.sitl_bin)
    a.defaults_path = resolve_defaults(a.sitl_defaults, a.sitl_bin_path)
    return a


def reanalyse(a, work: Path) -> int:
    """Rebuild the results of a kept run from its flight logs, with the run's own options (scenarios, tag ...)."""
    run = json.loads((work / "run.json").read_text())
    no_write = a.no_write
    a = parse_args(run["argv"])
    results = []
    for name in a.scenarios:
        for arm in a.arms:
            p = work / f"log_{name}_{arm}.json"
            if not p.exists():
                continue
            log = core.FlightLog.from_dict(json.loads(p.read_text()))
            mcap = work / f"companion_{name}.mcap"
            recs = read_gps_input(mcap) if arm == "B" and mcap.exists() else []
            r = core.analyse(core.SCENARIOS[name], arm, log, recs)
            if arm == "B":
                r.notes.append(f"companion MCAP: {len(recs)} GPS_INPUT records")
            results.append(r)
    print(core.phase_table(results))
    print(core.marks_table(results))
    print(core.companion_table(results))
    print(core.lag_table(results))
    if not no_write and results:
        write_results(results, a, run["argv"], run["started"], run["load_before"], after=run.get("load_after"))
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    a = parse_args(argv)
    if a.from_dir:
        return reanalyse(a, Path(a.from_dir))
    started = time.strftime("%Y-%m-%d %H:%M:%S %Z")
    load_before = machine_state()
    work = Path(tempfile.mkdtemp(prefix="sitl_ab_"))
    (work / "run.json").write_text(json.dumps({"argv": argv, "started": started, "load_before": load_before}))
    results = []
    try:
        for name in a.scenarios:
            for arm in a.arms:
                t0 = time.monotonic()
                r = fly(core.SCENARIOS[name], arm, a, work)
                results.append(r)
                print(f"{name} {arm}: armed={r.armed} phases="
                      + ", ".join(f"{k} {v[0]:.2f}/{v[1]:.2f}" for k, v in r.phases.items())
                      + f" failsafe={r.failsafe_s:.1f} land={r.land_s:.1f} ({time.monotonic() - t0:.0f} s wall) "
                      + "; ".join(r.notes), flush=True)
    finally:
        if a.keep:
            print(f"kept {work}")
        else:
            import shutil

            shutil.rmtree(work, ignore_errors=True)
    with suppress(OSError):
        run = json.loads((work / "run.json").read_text()) if (work / "run.json").exists() else {}
        (work / "run.json").write_text(json.dumps({**run, "load_after": machine_state()}))
    print(core.phase_table(results))
    print(core.marks_table(results))
    print(core.companion_table(results))
    print(core.lag_table(results))
    if not a.no_write and results:
        write_results(results, a, argv, started, load_before)
        print(f"wrote {RESULTS_MD}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
