"""Real-autopilot A/B benchmark on ArduCopter SITL, the same scripted flight in three arms, GPS1 denied by
SIM_GPS1_ENABLE=0 in flight:

* A: ArduPilot alone, its default parameters;
* AD: ArduPilot alone at its best for a GPS loss: EKF3 drag fusion (EK3_DRAG_BCOEF_X/Y, EK3_DRAG_MCOEF: the values
  SITL itself suggests for its frame) with the dead-reckoning failsafe (FS_DR_ENABLE, FS_DR_TIMEOUT);
* B: A plus the real ``companion run`` process as GPS2 in the recommended set-up (docs/ardupilot.md):
  ``inject.activate = "takeover"``, the companion carrying the vehicle through the outage when its trust monitor
  judged its solution fit at the loss, else sending no fix (EKF3 loses its position as in A);
* BD: the same companion on top of AD.

    nice -n 5 .venv/bin/python -m replay.live.sitl --sitl-bin PATH/build/sitl/bin/arducopter \\
        --scenarios lap-deny-30 short-hover-deny-30 --runs 2

The SITL binary is the user's (``--sitl-bin`` or env ``COMPANION_SITL_BIN``); nothing of ArduPilot is in this
repository. Parameters: ArduPilot's copter defaults (Tools/autotest/default_params/copter.parm relative to the binary,
``--sitl-defaults none`` for none) then the harness's own file; every parameter the harness sets is read back from the
autopilot before take-off and the run fails on one it does not hold (names differ between ArduPilot versions: the
waypoint speed is WP_SPD in m/s on newer builds, WPNAV_SPEED in cm/s on older ones; a probe run finds which).

Processes: SITL in a temporary directory (fresh EEPROM) on 127.0.0.1, instance -I chosen so its ports are free
(SERIAL0 = 5760 + 10 I for the harness, SERIAL1 = 5762 + 10 I for the companion). Every wait is for a condition
with a bound; every process is stopped by its PID. Vehicle time is the autopilot's boot time from the messages.
Pure analysis: replay.live.sitl_core; tables and plot: replay.live.sitl_report.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import subprocess
import sys
import tempfile
import time
from contextlib import suppress
from pathlib import Path

from replay.live import sitl_core as core
from replay.live import sitl_report as report
from replay.live.sitl_vehicle import (
    HarnessError,
    Vehicle,
    free_instance,
    machine_state,
    resolve_bin,
    resolve_defaults,
    sitl_commit,
    stop_pid,
    suggested_drag,
    write_params,
)

REPO = Path(__file__).resolve().parents[2]
RESULTS = REPO / "replay" / "results"
RESULTS_MD = RESULTS / "sitl_ab.md"
HOME = "-35.363261,149.165230,584,353"  # ArduPilot's usual SITL home (CMAC); any will do
ARMS = ("A", "AD", "B", "BD")
DEFAULT_ARMS = ("A", "AD", "B")

#: set in every arm: quad frame, no fence and no RC failsafe (the harness has no RC), GPS1 on
VEHICLE_PARAMS = {"FRAME_CLASS": 1, "FRAME_TYPE": 0, "FENCE_ENABLE": 0, "FS_THR_ENABLE": 0, "SIM_GPS1_ENABLE": 1}
#: AD and B: the dead-reckoning failsafe as ArduCopter documents it (the action as dead reckoning starts, RTL, and the
#: time it may dead-reckon before the EKF failsafe, 30 s); the drag coefficients come from SITL (suggested_drag)
DR_FAILSAFE_PARAMS = {"FS_DR_ENABLE": 2, "FS_DR_TIMEOUT": 30}
#: B and BD: the set-up of docs/ardupilot.md (instance 2 = MAVLink; GPS1 primary, GPS2 taken only when GPS1 has no 3D fix)
COMPANION_PARAMS = {
    "GPS2_TYPE": 14, "GPS2_DELAY_MS": 100, "GPS_AUTO_SWITCH": 4, "GPS_PRIMARY": 0, "SERIAL1_PROTOCOL": 2,
    "EK3_SRC1_POSXY": 3, "EK3_SRC1_VELXY": 3, "EK3_SRC1_POSZ": 1, "EK3_SRC1_VELZ": 3,
}
#: B's companion settings besides --companion-set (systemd/companion.toml recommends the same): the takeover, the GNSS
#: latency measured online, the autopilot's heading fused, no fix while armed beside a healthy GPS1, no motion prior
#: (its hold/constant-velocity blend widens the stated accuracy of an INS that carries the vehicle, without making it
#: more accurate: docs/decisions/0001-takeover-trust.md), and fixes for the epoch GPS2_DELAY_MS = 100 tells EKF3
COMPANION_SETS = ['inject.activate="takeover"', "navigator.gnss_delay_estimate=true",
                  "navigator.fuse_attitude_yaw=true", "inject.backup_fix_when_armed=false", "navigator.motion_prior=false",
                  "inject.autopilot_lag_s=0.1", "inject.max_v_acc_alt_m=20"]
STREAMS_HZ = {  # requested on the harness's own link (SERIAL0) with SET_MESSAGE_INTERVAL
    "GLOBAL_POSITION_INT": 25, "SIMSTATE": 50, "ATTITUDE": 50, "LOCAL_POSITION_NED": 10, "GPS_RAW_INT": 5,
    "GPS2_RAW": 5, "EKF_STATUS_REPORT": 2, "SYS_STATUS": 1, "HEARTBEAT": 1,
}
EKF_READY_FLAGS = 0x10 | 0x200  # ESTIMATOR_POS_HORIZ_ABS | ESTIMATOR_PRED_POS_HORIZ_ABS


# -- the probe: what this build calls things, and what drag its frame has ----------------------------------------------
def probe(a, work: Path) -> dict:
    """Start SITL once: which waypoint-speed parameters the build has, and the drag coefficients it suggests."""
    run_dir = work / "probe"
    run_dir.mkdir(parents=True, exist_ok=True)
    inst = free_instance()
    cmd = [str(a.sitl_bin_path), "--model", "+", "--speedup", "1", "-I", str(inst), "--home", a.home]
    if a.defaults_path:
        cmd += ["--defaults", str(a.defaults_path)]
    log = core.FlightLog()
    sitl = veh = None
    try:
        sitl = subprocess.Popen(cmd, cwd=run_dir, stdout=open(run_dir / "sitl.out", "w"), stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL)
        veh = Vehicle(f"tcp:127.0.0.1:{5760 + 10 * inst}", log.on_message, lambda: log.t_boot)
        veh.pump(lambda: log.modes != [], 30, "first HEARTBEAT")
        names = veh.read_params(["WP_SPD", "WP_ACC", "WPNAV_SPEED", "WPNAV_ACCEL"])
    finally:
        if veh is not None:
            veh.close()
        stop_pid(sitl)
    drag = suggested_drag((run_dir / "sitl.out").read_text(errors="replace"))
    if drag is None:
        raise HarnessError("SITL printed no suggested EK3_DRAG_* coefficients for its frame (see probe/sitl.out)")
    return {"new_wp_names": names["WP_SPD"] is not None, "drag": drag}


def speed_params(sc: core.Scenario, new_names: bool) -> dict[str, float]:
    if new_names:
        return {"WP_SPD": sc.speed_mps, "WP_ACC": 2.5}
    return {"WPNAV_SPEED": sc.speed_mps * 100.0, "WPNAV_ACCEL": 250.0}


def arm_params(sc: core.Scenario, arm: str, a, found: dict) -> dict[str, float]:
    params = {**VEHICLE_PARAMS, **speed_params(sc, found["new_wp_names"]), **sc.sim_params()}
    if arm in ("AD", "BD"):
        params.update(found["drag"])
        params.update(DR_FAILSAFE_PARAMS)
    if arm in ("B", "BD"):
        params.update(COMPANION_PARAMS)
    for kv in a.param or []:
        k, v = kv.split("=", 1)
        params[k] = float(v)
    return params


# -- one arm of one scenario -------------------------------------------------------------------------------------------
def fly(sc: core.Scenario, arm: str, a, work: Path, found: dict, run: int = 1) -> core.ArmResult:
    log = core.FlightLog()
    params = arm_params(sc, arm, a, found)
    tag = f"{sc.name}_{arm}_{run}"
    ours = work / f"harness_{tag}.parm"
    write_params(ours, params)
    defaults = ",".join(str(p) for p in (a.defaults_path, ours) if p)
    inst = free_instance()
    base = 5760 + 10 * inst
    cmd = [str(a.sitl_bin_path), "--model", "+", "--speedup", str(a.speedup), "-I", str(inst), "--home", a.home,
           "--defaults", defaults]
    run_dir = work / f"sitl_{tag}"
    run_dir.mkdir(parents=True, exist_ok=True)
    sitl = comp = veh = None
    mcap = work / f"companion_{tag}.mcap"
    notes: list[str] = []
    try:
        sitl = subprocess.Popen(cmd, cwd=run_dir, stdout=open(run_dir / "sitl.out", "w"), stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL)
        veh = Vehicle(f"tcp:127.0.0.1:{base}", log.on_message, lambda: log.t_boot)
        veh.pump(lambda: log.modes != [], 30, "first HEARTBEAT")
        veh.request_streams(STREAMS_HZ)
        veh.verify_params(params)
        if arm in ("B", "BD"):
            ccmd = [sys.executable, "-m", "companion.cli", "run", "--connect", f"tcp:127.0.0.1:{base + 2}",
                    "--inject", "inject", "--gps-id", "1", "--out", str(mcap)] + sum((["--set", s] for s in _sets(a)), [])
            comp = subprocess.Popen(ccmd, cwd=REPO, stdout=open(work / f"companion_{tag}.out", "w"),
                                    stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        veh.pump(lambda: log.truth != [] and log.ekf != [], 30, "SIMSTATE and GLOBAL_POSITION_INT streams")
        veh.pump(lambda: log.gps_fix(1) >= 3, 90, "GPS1 3D fix")
        if arm in ("B", "BD") and not veh.pump(lambda: log.gps_fix(2) >= 3, 90, "GPS2 (companion) 3D fix", must=False):
            notes.append("GPS2 never reported a 3D fix before arming")
        veh.pump(lambda: bool(log.ekf_flags) and (log.ekf_flags[-1][1] & EKF_READY_FLAGS) == EKF_READY_FLAGS, 120,
                 "EKF absolute horizontal position")
        veh.set_mode(core.MODE_GUIDED, lambda: log.mode)
        mav = veh.mavutil.mavlink
        deadline = time.monotonic() + a.arm_timeout
        while not log.armed and time.monotonic() < deadline:
            veh.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, wait_ack=True)
            veh.pump(lambda: log.armed, 3.0, "armed", must=False)
        if not log.armed:
            log.mark("end")
            notes.append("arming refused")
            return _finish(sc, arm, log, [], notes, run, mcap)
        veh.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, sc.alt_m)
        veh.pump(lambda: bool(log.ekf) and log.ekf[-1][3] >= sc.alt_m - 1.0, 60 / min(a.speedup, 1) + 30,
                 "climb to altitude")
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
            (work / f"log_{tag}.json").write_text(json.dumps(log.to_dict()).replace("NaN", "null"))
        with suppress(OSError):
            (run_dir / "texts.txt").write_text("".join(f"{t:9.3f} {sev} {txt}\n" for t, sev, txt in log.texts)
                                               + "".join(f"{t:9.3f} harness: {txt}\n" for t, txt in log.events)
                                               + "".join(f"{t:9.3f} mode {m} armed {a}\n" for t, m, a in log.modes))
    return _finish(sc, arm, log, [], notes, run, mcap)


def _sets(a) -> list[str]:
    return COMPANION_SETS + list(a.companion_set or [])


def _finish(sc, arm, log, records, notes, run, mcap: Path) -> core.ArmResult:
    takeover, trust, shed = "", {}, (0, 0)
    if arm in ("B", "BD") and mcap.exists():
        records, takeover, trust = read_companion(mcap, log.marks.get("deny_on", math.nan))
        shed = companion_shed(mcap)
        notes.append(f"companion MCAP: {len(records)} GPS_INPUT records")
    r = core.analyse(sc, arm, log, records)
    r.run, r.takeover, r.trust, r.imu_coalesced = run, takeover, trust, shed
    r.notes += notes
    return r


def _script(veh: Vehicle, sc: core.Scenario, a, log: core.FlightLog, start_ne) -> None:
    """Hover, then the route's laps, with GPS1 switched off/on on vehicle time; ends when the denial's recovery time
    and the laps are both done (or, with no route, after the hover)."""
    sched: list[tuple[float, str]] = []
    left = {"v": False}

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
            left["v"] = True  # a failsafe took the vehicle: stop steering it, keep recording

    veh.hooks.append(tick)
    try:
        t_h = log.t_boot
        end_t = math.inf
        if sc.deny_in == "hover":
            deny(t_h + sc.deny_at_s)
            end_t = t_h + sc.deny_at_s + sc.deny_s + sc.recover_s
        hover_end = t_h + sc.hover_s
        if sc.laps == 0:
            veh.wait_vehicle_time(max(hover_end, end_t) if math.isfinite(end_t) else hover_end, a.speedup, "end of hover")
            _confirm_gps1(veh, log)
            return
        veh.wait_vehicle_time(hover_end, a.speedup, "end of hover")
        log.mark("route")
        if sc.deny_in == "route" and sc.deny_lap == 0:
            deny(log.t_boot + sc.deny_at_s)
            end_t = log.t_boot + sc.deny_at_s + sc.deny_s + sc.recover_s
        n0, e0 = start_ne
        lap = 0
        while not left["v"] and (log.t_boot or 0) < end_t:
            lap += 1
            if sc.denies and sc.deny_in == "route" and sc.deny_lap == lap:
                deny(log.t_boot + sc.deny_at_s)
                end_t = log.t_boot + sc.deny_at_s + sc.deny_s + sc.recover_s
            log.note(f"lap {lap}")
            for dn, de in core.route_corners(sc):
                tn, te = n0 + dn, e0 + de
                if left["v"] or (log.t_boot or 0) >= end_t:
                    break
                veh.goto_ned(tn, te, -sc.alt_m)
                leg_s = math.hypot(dn, de) / sc.speed_mps * 2.5 + 15
                veh.pump(lambda: left["v"] or (log.t_boot or 0) >= end_t or (
                    log.local is not None and math.hypot(log.local[0] - tn, log.local[1] - te) < 2.0),
                    leg_s / a.speedup + 30, "corner", must=False)
            if lap >= sc.laps or (not sc.denies and lap >= sc.laps):
                break
        if math.isfinite(end_t):  # after a failsafe's mode change keep recording to the scripted end
            veh.wait_vehicle_time(end_t, a.speedup, "scripted end")
        _confirm_gps1(veh, log)
    finally:
        veh.hooks.remove(tick)


def _confirm_gps1(veh: Vehicle, log: core.FlightLog) -> None:
    if "deny_on" in log.marks and not veh.set_param("SIM_GPS1_ENABLE", 1.0):
        log.note("SIM_GPS1_ENABLE=1 not acknowledged at the end")


def read_companion(path: Path, deny_on: float) -> tuple[list[dict], str, dict]:
    """The companion's GPS_INPUT records, its takeover decision at the loss (the /inject/state reason nearest after
    ``deny_on``) and its trust verdict then (/estimation/trust)."""
    from companion.record.inspect import RecordError, iter_payloads

    recs, states, verdicts = [], [], []
    lists = {"/inject/gps_input": recs, "/inject/state": states, "/estimation/trust": verdicts}
    with suppress(RecordError):
        for topic, _t, data in iter_payloads(path):
            if topic in lists:
                with suppress(ValueError):
                    lists[topic].append(json.loads(data))
    takeover, trust = "", {}
    if math.isfinite(deny_on):
        after = [s for s in states if s.get("t_s") is not None and s["t_s"] >= deny_on - 1.0
                 and str(s.get("reason", "")).startswith(("takeover", "no takeover"))]
        if after:
            takeover = str(after[0]["reason"])
            t_dec = after[0]["t_s"]
            before = [v for v in verdicts if v.get("t_s") is not None and v["t_s"] <= t_dec]
            trust = before[-1] if before else {}
    return recs, takeover, trust


def companion_shed(path: Path) -> tuple[int, int]:
    """(IMU samples coalesced because the companion fell behind its link, IMU samples it took in while behind) from its
    record's metadata; a run that coalesced more than a few samples did not keep up (its INS saw fewer samples)."""
    from companion.record.inspect import RecordError, summarize

    with suppress(RecordError):
        for _name, data in summarize(path).metadata:
            if "shed.imu_samples_coalesced" in data:
                return int(data["shed.imu_samples_coalesced"]), int(data.get("shed.imu_samples_in", 0))
    return 0, 0


# -- results -----------------------------------------------------------------------------------------------------------
def write_results(results: list[core.ArmResult], a, argv: list[str], started: str, load_before: str, found: dict,
                  after: str | None = None, note: str = "") -> None:
    from replay.harness.results import write_section

    RESULTS.mkdir(parents=True, exist_ok=True)
    png = RESULTS / f"sitl_ab{a.tag}.png"
    report.plot(results, png)
    if not RESULTS_MD.exists():
        RESULTS_MD.write_text("# ArduPilot SITL A/B: ArduPilot alone vs ArduPilot + companion\n\n"
                              "Written by `python -m replay.live.sitl`; each block names the command that produced it.\n")
    sc0 = core.SCENARIOS[a.scenarios[0]]
    text = [
        f"## {', '.join(dict.fromkeys(r.scenario for r in results))}"
        + (f" (companion --set {' '.join(a.companion_set)})" if a.companion_set else "") + "\n",
        f"Command: `{' '.join(['python -m replay.live.sitl'] + argv)}`  ",
        f"SITL: `{a.sitl_bin_path}` at ArduPilot commit {sitl_commit(a.sitl_bin_path)}; `--speedup {a.speedup}`; "
        f"defaults: {a.defaults_path or 'none (harness params only)'} + the harness's own params, each read back from "
        "the autopilot before take-off.  ",
        f"Started {started}; machine before: {load_before}; after: {after or machine_state()}.  "
        + (f"\n{note}  " if note else ""),
        f"Every arm: {', '.join(f'{k}={v}' for k, v in VEHICLE_PARAMS.items())}, the scenario's waypoint speed and "
        f"SITL wind (e.g. {', '.join(f'{k}={v:g}' for k, v in arm_params(sc0, 'A', a, found).items() if k.startswith(('WP', 'SIM_WIND')))}). "
        f"AD adds {', '.join(f'{k}={v:g}' for k, v in {**found['drag'], **DR_FAILSAFE_PARAMS}.items())} (drag: the "
        f"coefficients SITL suggests for its frame). B adds to A, BD to AD, "
        f"{', '.join(f'{k}={v}' for k, v in COMPANION_PARAMS.items())} and the companion with `--set {' '.join(_sets(a))}`.\n",
        "EKF error = GLOBAL_POSITION_INT vs SIMSTATE truth interpolated to its time_boot_ms. Times after the denial are "
        "from the moment SIM_GPS1_ENABLE=0 was sent. After a failsafe's mode change (LAND, RTL) the harness stops "
        "steering and the vehicle is no longer on its route.\n",
        "### EKF horizontal error per phase, failsafes\n", report.phase_table(results), "",
    ]
    for title, body in (("EKF horizontal error (m) every 5 s after GPS1 is denied", report.marks_table(results)),
                        ("Mode changes and failsafe messages after the denial", report.events_lines(results)),
                        ("The companion (arms B, BD): its decision, its fixes, their honesty, GPS1's return",
                         report.companion_table(results)),
                        ("Delay on the route (before any denial)", report.lag_table(results))):
        if body:
            text += [f"### {title}\n", body, ""]
    verdicts = report.ab_verdicts(results)
    if verdicts:
        text += ["### Against the targets\n"] + verdicts + [""]
    text += ["### Arming and notes\n", report.arming_lines(results), ""]
    if png.exists():
        text += [f"![EKF error after the denial]({png.name})", ""]
    write_section(RESULTS_MD, f"sitl-ab{a.tag}", "\n".join(text),
                  "ArduPilot SITL A/B: ArduPilot alone vs ArduPilot + companion")
    (RESULTS / f"sitl_ab{a.tag}.json").write_text(json.dumps([_summary(r) for r in results], indent=1))


def _summary(r: core.ArmResult) -> dict:
    d = {k: v for k, v in r.__dict__.items() if k not in ("t_err", "err", "own_t", "own_err", "own_hacc", "own_fix")}
    return json.loads(json.dumps(d, default=str).replace("NaN", "null"))


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m replay.live.sitl", description=__doc__.split("\n\n")[0])
    p.add_argument("--sitl-bin", help="ArduCopter SITL binary (default: env COMPANION_SITL_BIN)")
    p.add_argument("--sitl-defaults", help="ArduPilot defaults file (default: copter.parm relative to the binary; 'none')")
    p.add_argument("--scenarios", nargs="+", default=core.DEFAULT_SCENARIOS, choices=sorted(core.SCENARIOS))
    p.add_argument("--arms", nargs="+", default=list(DEFAULT_ARMS), choices=list(ARMS))
    p.add_argument("--runs", type=int, default=1, help="fly every scenario and arm this many times")
    p.add_argument("--speedup", type=float, default=1.0)
    p.add_argument("--home", default=HOME)
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="extra SITL parameter for every arm")
    p.add_argument("--companion-set", action="append", metavar="SECTION.KEY=VALUE", help="passed to companion run --set")
    p.add_argument("--arm-timeout", type=float, default=90.0)
    p.add_argument("--tag", default="", help="suffix of the results block/PNG/JSON (e.g. _wind)")
    p.add_argument("--clean", action="store_true", help="delete the temporary directory at the end (default: kept "
                   "for --from-dir)")
    p.add_argument("--no-write", action="store_true", help="print only; do not touch replay/results")
    p.add_argument("--from-dir", help="re-analyse the flights kept in this directory instead of flying")
    a = p.parse_args(argv)
    if a.runs < 1:
        p.error("--runs must be >= 1")
    a.sitl_bin_path = resolve_bin(a.sitl_bin)
    a.defaults_path = resolve_defaults(a.sitl_defaults, a.sitl_bin_path)
    return a


def _flights(a):
    for run in range(1, a.runs + 1):
        for name in a.scenarios:
            for arm in a.arms:
                yield run, name, arm


def reanalyse(a, work: Path) -> int:
    """Rebuild the results of a kept run from its flight logs, with the run's own options (scenarios, tag ...)."""
    meta = json.loads((work / "run.json").read_text())
    no_write = a.no_write
    a = parse_args(meta["argv"])
    results = []
    for run, name, arm in _flights(a):
        tag = f"{name}_{arm}_{run}"
        p = work / f"log_{tag}.json"
        if p.exists():
            log = core.FlightLog.from_dict(json.loads(p.read_text()))
            results.append(_finish(core.SCENARIOS[name], arm, log, [], [], run, work / f"companion_{tag}.mcap"))
    _print(results)
    if not no_write and results:
        write_results(results, a, meta["argv"], meta["started"], meta["load_before"], meta["found"],
                      after=meta.get("load_after"), note=meta.get("note", ""))
    return 0


def _print(results) -> None:
    for t in (report.phase_table(results), report.marks_table(results), report.companion_table(results),
              "\n".join(report.ab_verdicts(results))):
        print(t)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    try:
        a = parse_args(argv)
    except HarnessError as e:  # no binary, no defaults file: one line, as for any bad argument
        print(f"sitl: error: {e}", file=sys.stderr)
        return 2
    if a.from_dir:
        return reanalyse(a, Path(a.from_dir))
    # SIGTERM unwinds like Ctrl-C, through the finally blocks that stop SITL and the companion: a companion left
    # running would reconnect to the next SITL on the same ports and take its serial port from the next flight
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(128 + signal.SIGTERM))
    started = time.strftime("%Y-%m-%d %H:%M:%S %Z")
    load_before = machine_state()
    work = Path(tempfile.mkdtemp(prefix="sitl_ab_"))
    print(f"flights and logs in {work}", flush=True)
    found = probe(a, work)
    meta = {"argv": argv, "started": started, "load_before": load_before, "found": found}
    (work / "run.json").write_text(json.dumps(meta))
    results = []
    try:
        for run, name, arm in _flights(a):
            t0 = time.monotonic()
            r = fly(core.SCENARIOS[name], arm, a, work, found, run)
            results.append(r)
            print(f"{name} run {run} {arm}: armed={r.armed} phases="
                  + ", ".join(f"{k} {v[0]:.2f}/{v[1]:.2f}" for k, v in r.phases.items())
                  + f" failsafe={r.failsafe_s:.1f} left_guided={r.left_guided_s:.1f} {r.takeover} "
                  + f"({time.monotonic() - t0:.0f} s wall) " + "; ".join(r.notes), flush=True)
    finally:
        with suppress(OSError):
            (work / "run.json").write_text(json.dumps({**meta, "load_after": machine_state()}))
        if a.clean:
            import shutil

            shutil.rmtree(work, ignore_errors=True)
        else:
            print(f"kept {work}")
    _print(results)
    if not a.no_write and results:
        write_results(results, a, argv, started, load_before, found)
        print(f"wrote {RESULTS_MD}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
