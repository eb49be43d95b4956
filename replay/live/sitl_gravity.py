"""Gravity aiding on a real ArduPilot vehicle, A/B in SITL: a survey over a gravity grid with GNSS for
``--healthy-min``, denied (SIM_GPS1_ENABLE 0) for ``--denial-min`` in a wind (a boat: a current) that turns, then back
for ``--back-min``.

* alone: ArduPilot at its documented best for a GNSS loss (Plane: airspeed sensor fused, EKF3 wind estimation and
  dead reckoning on air data; Rover: its defaults, whose EKF failsafe holds the boat), the same mission and weather;
* companion: the same plus ``companion run`` as GPS2 (docs/ardupilot.md), its sequential gravity filter on the
  readings of a simulated gravimeter (companion.sim.sitl_gravimeter_link: SITL's truth -> NAMED_VALUE_FLOAT GRAV
  routed by the autopilot), its gravity-aided solution sent as 3D GPS_INPUT with its honest h_acc; on the boat its
  reference is a simulated water-speed log on the same link (NAMED_VALUE_FLOAT WSPD), and EKF3's GPS accuracy checks
  are off for GPS2's fixes to be used (COMPANION_VEHICLE_PARAMS).

    nice -n 5 python -m replay.live.sitl_gravity --sitl-bin PATH/arduplane --vehicle plane \\
        --map ../shared/data/gravity/AK_gulf_grav.nc --origin 56.2,-143.0 --denial-min 60 --seed 1 --speedup 4 \\
        --outdir out/sitl_gravity

Writes DIR/summary.json (``{"arms": {"alone": ARM, "companion": ARM}}``, replay.live.sitl_gravity_core.arm_summary),
DIR/table.md and DIR/error.png; prints the table. A run whose companion fell behind its input (its ``lag`` summary
line: an input event processed later than inject.max_lag_s after it arrived) or whose truth stream has gaps is
marked ``kept_up: false`` and is not a valid result. Processes: replay.live.sitl_vehicle (every parameter read back).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import suppress
from pathlib import Path

import numpy as np

from companion.gravity.data import AK_GULF, shared_gravity_dir
from companion.gravity.maps import LocalGravityMap, load_grid
from replay.live import sitl_core as core
from replay.live import sitl_gravity_core as gc
from replay.live.sitl_vehicle import HarnessError, Vehicle, free_instance, machine_state, resolve_bin, sitl_commit, stop_pid, write_params

REPO = Path(__file__).resolve().parents[2]
LAG_RE = re.compile(r"at most ([0-9.]+) s after it arrived; (\d+) of (\d+) events beyond inject.max_lag_s ([0-9.]+) s")
MODE_AUTO = 10  # AUTO on Plane and Rover
BIN_ENV = {"plane": "COMPANION_SITL_PLANE_BIN", "rover": "COMPANION_SITL_ROVER_BIN"}
MODEL = {"plane": "plane", "rover": "motorboat"}
#: ArduPilot's own defaults for the SITL model, relative to the binary in its checkout
DEFAULTS = {"plane": ["Tools/autotest/models/plane.parm"],
            "rover": ["Tools/autotest/default_params/rover.parm", "Tools/autotest/default_params/motorboat.parm"]}
#: every arm: EKF3 alone (plane.parm enables EKF2), no RC/GCS failsafe (the harness has no RC), GPS1 on, SERIAL2 for
#: the gravimeter; Plane: the airspeed sensor (SITL's) fused, EKF3 estimating wind; Rover: no SmartRTL (an hour's
#: survey fills its path buffer, 300 points, and it switches itself off with a warning)
VEHICLE_PARAMS = {
    "plane": {"AHRS_EKF_TYPE": 3, "EK2_ENABLE": 0, "EK3_ENABLE": 1, "ARSPD_TYPE": 100, "ARSPD_USE": 1,
              "EK3_WIND_PSCALE": 1.0, "AIRSPEED_CRUISE": 22.0, "THR_FAILSAFE": 0, "FS_LONG_ACTN": 0,
              "FS_SHORT_ACTN": 0, "SIM_GPS1_ENABLE": 1, "SERIAL2_PROTOCOL": 2},
    "rover": {"AHRS_EKF_TYPE": 3, "EK3_ENABLE": 1, "WP_SPEED": 8.0, "CRUISE_SPEED": 8.0, "FS_THR_ENABLE": 0,
              "FS_GCS_ENABLE": 0, "SIM_GPS1_ENABLE": 1, "SERIAL2_PROTOCOL": 2, "SRTL_POINTS": 0},
}
#: Plane, both arms: a MEMS gyro rather than SITL's (its default drift is a 0-0.25 deg/s triangle on every axis, ten
#: minutes a cycle): residual biases after a boot calibration of 21 / -31 / 41 deg/h (x / y / z) and an in-run drift
#: of 5 deg/h an hour on every axis (SITL's drift is a ramp: SIM_DRIFT_SPEED deg/s per minute for SIM_DRIFT_TIME min),
#: the bias instability of a consumer MEMS gyro (docs/decisions/0012)
IMU_PARAMS = {"plane": {"SIM_GYR1_BIAS_X": 1.0e-4, "SIM_GYR1_BIAS_Y": -1.5e-4, "SIM_GYR1_BIAS_Z": 2.0e-4,
                        "SIM_DRIFT_SPEED": 5.0 / 3600.0 / 60.0, "SIM_DRIFT_TIME": 120.0},
              "rover": {}}
#: the companion arm: GPS2 = MAVLink GPS (the companion), GPS1 primary while it has a 3D fix
COMPANION_PARAMS = {"GPS2_TYPE": 14, "GPS_AUTO_SWITCH": 4, "GPS_PRIMARY": 0, "SERIAL1_PROTOCOL": 2,
                    "EK3_SRC1_POSXY": 3, "EK3_SRC1_VELXY": 3, "EK3_SRC1_POSZ": 1}
#: ... and per vehicle. Rover: EKF3 re-runs its GPS quality checks (AP_NavEKF3_VehicleStatus calcGpsGoodToAlign) after
#: a GPS loss before it uses a GPS again; the companion's fixes state hundreds of metres (checked against 5 m), a
#: speed accuracy of 50 m/s (against 1 m/s) and the HDOP of those, so without these bits EKF3 never takes them and
#: the boat's EKF failsafe holds it where it is. EK3_GPS_CHECK 17 keeps the default's satellite and yaw checks (31:
#: bits 0-4) and drops its accuracy (POS_ERR, SPD_ERR) and HDOP ones. EKF3 checks a GPS velocity against its
#: EK3_VELNE_M_NSE (0.3 m/s), not against the reported speed accuracy (AP_NavEKF3_PosVelFusion: "we don't want the
#: acceptance radius to increase with reported GPS accuracy"): where the gravity filter moves its position faster
#: than its velocity says, EKF3's velocity (following the positions) leaves the stated one by metres per second, the
#: velocity test fails and ArduRover's EKF failsafe holds the boat (flown: 22 min into the denial on both maps).
#: EK3_VELNE_M_NSE 5 (its maximum) checks it against 5 m/s; GPS1's own velocity is then weighed at 5 m/s too.
COMPANION_VEHICLE_PARAMS = {"plane": {}, "rover": {"EK3_GPS_CHECK": 17, "EK3_VELNE_M_NSE": 5.0}}
#: the boat's water-speed log (companion.sim.speed_log through the gravimeter's link): its NAMED_VALUE_FLOAT name
SPEED_LOG = "WSPD"
#: the companion's settings: the recommended set-up (replay.live.sitl.COMPANION_SETS) in ``backup`` (in the outage a fix
#: only while gravity aids it), the sequential gravity filter on air-data dead reckoning (companion.gravity.air_data_stage:
#: the navigator's INS on ArduPlane's MEMS IMU does not hold, docs/decisions/0012), its heading the autopilot's gyro
#: integrated (HIGHRES_IMU: RAW_IMU truncates to whole mrad/s), bias fitted to ATTITUDE yaw with GNSS and frozen in the
#: outage (EKF3's yaw turns with the fixes it fuses; the compass was worse: 0012), readings Eotvos-uncorrected,
#: white per reading and describing the vehicle half the gravimeter's 30 s window before their stamp, the held wind's
#: error a random walk of 0.1 m/s per sqrt(s) from a 1 m/s prior, plus a 5 m/s step along the Eotvos direction when
#: the readings show a wind shift (docs/decisions/0017); its states sent as 3D fixes with their honest h_acc
#: (EKF3 weighs a GPS by its reported accuracy, capped at 100 m: AP_NavEKF3_PosVelFusion) and a speed accuracy of 50 m/s
#: (EKF3's cap: their velocity, made of EKF3's own yaw, is not to steer that yaw)
COMPANION_SETS = ['inject.activate="backup"', "navigator.gnss_delay_estimate=true", "navigator.fuse_attitude_yaw=true",
                  "inject.backup_fix_when_armed=false", "navigator.motion_prior=false", "gravity.matcher=sequential",
                  'gravity.reference="air_data"', 'gravity.air_heading="gyro"', 'gravity.air_gyro_source="HIGHRES_IMU"',
                  "gravity.eotvos_corrected=false", "gravity.seq_noise_corr_s=1",
                  "gravity.reading_delay_s=15", "gravity.seq_init_vel_sigma_mps=1", "gravity.seq_wind_walk_mps_rts=0.1",
                  "gravity.seq_wind_shift_mps=5",
                  "gravity.seq_particles=500", "gravity.air_speed_sigma_floor_mps=50", "inject.max_h_acc_3d_m=20000", "inject.max_h_acc_2d_m=40000",
                  "inject.max_v_acc_3d_m=200"]
STREAMS_HZ = {"GLOBAL_POSITION_INT": 5, "SIMSTATE": 5, "ATTITUDE": 5, "GPS_RAW_INT": 1, "GPS2_RAW": 1,
              "EKF_STATUS_REPORT": 1, "HEARTBEAT": 1}
EKF_READY_FLAGS = 0x10 | 0x200
MAX_TRUTH_GAP_S = 2.0


def defaults_for(vehicle: str, sitl_bin: Path) -> list[Path]:
    root = sitl_bin.parents[3] if len(sitl_bin.parents) > 3 else sitl_bin.parent
    return [p for p in ((root / d).resolve() for d in DEFAULTS[vehicle]) if p.exists()]


def arm_params(a, arm: str) -> dict[str, float]:
    p = {**VEHICLE_PARAMS[a.vehicle], **IMU_PARAMS[a.vehicle], **a.schedule.sim_params()}
    if arm == "companion":
        p.update(COMPANION_PARAMS)
        p.update(COMPANION_VEHICLE_PARAMS[a.vehicle])
    for kv in a.param or []:
        k, v = kv.split("=", 1)
        p[k] = float(v)
    return p


#: ArduPlane's and ArduRover's 50 Hz main loops refuse a 50 Hz RAW_IMU stream ("Requested rate ... too fast"): ask
#: for 25 Hz; the boat's reference speed is its log (on ArduRover VFR_HUD.airspeed is the GPS's ground speed), and
#: its EKF3 fuses the states, so their correction moves at most 2 m/s beyond the reckoning (decision 0020)
VEHICLE_SETS = {"plane": ["streams.RAW_IMU=25"],
                "rover": ["streams.RAW_IMU=25", f'gravity.air_speed_log="{SPEED_LOG}"', "gravity.air_correction_rate_mps=2"]}


def companion_sets(a) -> list[str]:
    return COMPANION_SETS + VEHICLE_SETS[a.vehicle] + [f"gravity.map={json.dumps(str(a.map_path))}"] + list(a.companion_set or [])


# -- the mission -------------------------------------------------------------------------------------------------------
def upload_mission(veh: Vehicle, a, wall_s: float = 60.0) -> int:
    """Home, (Plane) a take-off, the survey's corners, a DO_JUMP back to the first corner for ever."""
    mav = veh.mavutil.mavlink
    fr = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    lat0, lon0 = a.survey.origin
    items = [(mav.MAV_CMD_NAV_WAYPOINT, mav.MAV_FRAME_GLOBAL_INT, 0, 0, 0, 0, lat0, lon0, 0.0)]
    if a.vehicle == "plane":
        items.append((mav.MAV_CMD_NAV_TAKEOFF, fr, 15.0, 0, 0, 0, lat0, lon0, a.survey.alt_m))
    first = len(items)
    for lat, lon in a.survey.corners_lat_lon()[1:]:
        items.append((mav.MAV_CMD_NAV_WAYPOINT, fr, 0, 0, 0, 0, lat, lon, a.survey.alt_m))
    items.append((mav.MAV_CMD_DO_JUMP, fr, first, -1, 0, 0, 0, 0, 0))
    done: list[int] = []

    def hook(m):
        kind = m.get_type()
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST") and m.seq < len(items):
            c, f, p1, p2, p3, p4, la, lo, alt = items[m.seq]
            veh.m.mav.mission_item_int_send(1, 1, m.seq, f, c, 0, 1, p1, p2, p3, p4, int(round(la * 1e7)),
                                            int(round(lo * 1e7)), alt, 0)
        elif kind == "MISSION_ACK":
            done.append(int(m.type))

    veh.hooks.append(hook)
    try:
        veh.m.mav.mission_count_send(1, 1, len(items), 0)
        veh.pump(lambda: bool(done), wall_s, "MISSION_ACK")
    finally:
        veh.hooks.remove(hook)
    if done[0] != mav.MAV_MISSION_ACCEPTED:
        raise HarnessError(f"mission refused: MISSION_ACK type {done[0]}")
    return len(items)


# -- one arm -----------------------------------------------------------------------------------------------------------
def fly(a, arm: str) -> dict:
    work = a.outdir / arm
    work.mkdir(parents=True, exist_ok=True)
    log = core.FlightLog()
    params = arm_params(a, arm)
    ours = work / "harness.parm"
    write_params(ours, params)
    parallel = a.jobs > 1 and len(a.arms) > 1
    inst = (a.alone_instance if arm == "alone" else free_instance_after(a.alone_instance)) if parallel else free_instance()
    base = 5760 + 10 * inst
    lat0, lon0 = a.survey.origin
    home = f"{lat0:.7f},{lon0:.7f},0,{a.survey.heading_deg:g}"
    cmd = [str(a.sitl_bin_path), "--model", MODEL[a.vehicle], "--speedup", str(a.speedup), "-I", str(inst),
           "--home", home, "--defaults", ",".join(str(p) for p in [*a.defaults, ours])]
    sitl = grav = comp = veh = None
    notes: list[str] = []
    comp_out = work / "companion.out"
    mcap = work / "companion.mcap"
    t_wall = time.monotonic()
    try:
        sitl = subprocess.Popen(cmd, cwd=work, stdout=open(work / "sitl.out", "w"), stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL)
        veh = Vehicle(f"tcp:127.0.0.1:{base}", log.on_message, lambda: log.t_boot, connect_s=60.0)
        veh.pump(lambda: log.modes != [], 60, "first HEARTBEAT")
        veh.request_streams(STREAMS_HZ)
        veh.verify_params(params)
        grav = subprocess.Popen(
            [sys.executable, "-m", "companion.sim.sitl_gravimeter_link", "--connect", f"tcp:127.0.0.1:{base + 3}",
             "--map", str(a.map_path), "--seed", str(a.seed), "--record", str(work / "gravimeter.jsonl")]
            + (["--origin", a.origin] if a.local_map else []) + (["--speed-log", SPEED_LOG] if a.vehicle == "rover" else []),
            cwd=REPO, stdout=open(work / "gravimeter.out", "w"), stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        if arm == "companion":
            ccmd = [sys.executable, "-m", "companion.cli", "run", "--connect", f"tcp:127.0.0.1:{base + 2}", "--inject",
                    "inject", "--gps-id", "1", "--out", str(mcap), "--status-every", "600"]
            ccmd += sum((["--set", s] for s in companion_sets(a)), [])
            comp = subprocess.Popen(ccmd, cwd=REPO, stdout=open(comp_out, "w"), stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL)
        veh.pump(lambda: log.truth != [] and log.ekf != [], 60, "SIMSTATE and GLOBAL_POSITION_INT")
        veh.pump(lambda: log.gps_fix(1) >= 3, 120, "GPS1 3D fix")
        veh.pump(lambda: bool(log.ekf_flags) and (log.ekf_flags[-1][1] & EKF_READY_FLAGS) == EKF_READY_FLAGS, 180,
                 "EKF absolute horizontal position")
        upload_mission(veh, a)
        veh.set_mode(MODE_AUTO, lambda: log.mode)
        mav = veh.mavutil.mavlink
        deadline = time.monotonic() + 120
        while not log.armed and time.monotonic() < deadline:
            veh.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, wait_ack=True)
            veh.pump(lambda: log.armed, 3.0, "armed", must=False)
        if not log.armed:
            raise HarnessError("arming refused: " + "; ".join(core.arm_refusals(log)[:3]))
        climb = a.survey.alt_m - 20.0 if a.vehicle == "plane" else -1e9
        veh.pump(lambda: bool(log.ekf) and log.ekf[-1][3] >= climb, 120 + 300 / a.speedup, "take-off")
        log.mark("route")
        run_schedule(veh, a, log)
    except HarnessError as e:
        notes.append(f"harness: {e}")
        print(f"{arm}: harness: {e}", flush=True)
    finally:
        if veh is not None and "deny_on" in log.marks:
            with suppress(Exception):
                veh.set_param("SIM_GPS1_ENABLE", 1.0)
        stop_pid(comp, 60.0)
        stop_pid(grav)
        if veh is not None:
            veh.close()
        stop_pid(sitl)
        with suppress(OSError, ValueError, TypeError):
            (work / "log.json").write_text(json.dumps(log.to_dict()).replace("NaN", "null"))
    return {"arm": arm, "log": log, "notes": notes, "wall_s": time.monotonic() - t_wall, "work": work}


def free_instance_after(i0: int) -> int:
    return free_instance(limit=30, start=i0 + 1)


def run_schedule(veh: Vehicle, a, log: core.FlightLog) -> None:
    """The denial, the wind's turns, GNSS back and the end, on vehicle time from the survey start."""
    events = a.schedule.events(log.t_boot)
    end = events[-1][0]

    def tick(_m=None):
        while events and log.t_boot is not None and log.t_boot >= events[0][0]:
            t, label, params = events.pop(0)
            for k, v in params.items():
                veh.m.mav.param_set_send(1, 1, k.encode(), float(v), 9)
            if label in ("deny_on", "deny_off", "end"):
                log.mark(label, t)
            log.note(label)

    veh.hooks.append(tick)
    try:
        veh.pump(lambda: (log.t_boot or 0) >= end and not events, 120 + 1.5 * (end - log.t_boot) / a.speedup,
                 "the scheduled end")
    finally:
        veh.hooks.remove(tick)


# -- analysis ------------------------------------------------------------------------------------------------------------
def truth_kept_up(log: core.FlightLog) -> tuple[bool, float]:
    """(no gap in the truth stream longer than MAX_TRUTH_GAP_S of vehicle time, the longest gap)."""
    tr = np.asarray([x[0] for x in log.truth], float)
    if tr.size < 2:
        return False, math.nan
    g = float(np.max(np.diff(tr)))
    return g <= MAX_TRUTH_GAP_S, g


def companion_lag(path: Path) -> dict | None:
    from replay.live.long_denial import summary_lines

    if not path.exists():
        return None
    for line in summary_lines(path.read_text(errors="replace")):
        if line.startswith("lag "):
            m = LAG_RE.search(line)
            if m:
                return {"max_s": float(m.group(1)), "late": int(m.group(2)), "events": int(m.group(3)),
                        "max_lag_s": float(m.group(4))}
    return None


def summarise(a, flown: dict[str, dict]) -> dict:
    modes = gc.PLANE_MODES if a.vehicle == "plane" else gc.ROVER_MODES
    out: dict = {"arms": {}}
    level = None
    for arm in ("alone", "companion"):
        if arm not in flown:
            continue
        f = flown[arm]
        ok, gap = truth_kept_up(f["log"])
        records = None
        lag = None
        if arm == "companion":
            from replay.live.sitl import read_companion

            lag = companion_lag(f["work"] / "companion.out")
            ok = ok and lag is not None and lag["late"] == 0
            mcap = f["work"] / "companion.mcap"
            records = read_companion(mcap, math.nan)[0] if mcap.exists() else []
        s = gc.arm_summary(f["log"], a.survey, modes, ok, records, healthy_level_m=level)
        if arm == "alone":
            level = s.get("healthy_p95_m")
        s["truth_max_gap_s"] = gc._f(gap)
        s["companion_lag"] = lag
        s["notes"] = f["notes"]
        s["wall_s"] = round(f["wall_s"], 1)
        out["arms"][arm] = s
    return out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(prog="python -m replay.live.sitl_gravity", description=__doc__.splitlines()[0])
    p.add_argument("--sitl-bin", help="ArduPlane/ArduRover SITL binary (default: env COMPANION_SITL_PLANE_BIN / _ROVER_BIN)")
    p.add_argument("--vehicle", choices=("plane", "rover"), default="plane")
    p.add_argument("--map", default=str(shared_gravity_dir() / AK_GULF), help="gravity grid (netCDF, mGal, lat/lon)")
    p.add_argument("--origin", default="56.2,-143.0", help="LAT,LON of home and the survey's first line")
    p.add_argument("--healthy-min", type=float, default=20.0)
    p.add_argument("--denial-min", type=float, default=60.0)
    p.add_argument("--back-min", type=float, default=5.0)
    p.add_argument("--line-km", type=float, default=None, help="survey line length (default 30 plane, 8 boat)")
    p.add_argument("--spacing-km", type=float, default=None, help="line spacing (default 4 plane, 1.5 boat)")
    p.add_argument("--lines", type=int, default=4)
    p.add_argument("--heading-deg", type=float, default=0.0)
    p.add_argument("--wind-mps", type=float, default=7.0)
    p.add_argument("--turb-mps", type=float, default=2.0)
    p.add_argument("--current-mps", type=float, default=None,
                   help="boat: the water's current (SITL's SIM_TIDE_SPEED; default 0.5, 0: still water)")
    p.add_argument("--current-dir-deg", type=float, default=200.0, help="boat: where the current comes from")
    p.add_argument("--current-turn-deg", type=float, default=7.5,
                   help="boat: the current turns by this every 15 min of the denial (7.5: a rotary tide's 30 deg/h)")
    p.add_argument("--seed", type=int, default=1, help="the gravimeter's draws (bias, drift, noise, misfit start)")
    p.add_argument("--speedup", type=float, default=4.0)
    p.add_argument("--arms", nargs="+", choices=("alone", "companion"), default=["alone", "companion"])
    p.add_argument("--jobs", type=int, default=2, help="fly the arms at the same time (1: one after the other)")
    p.add_argument("--param", action="append", metavar="NAME=VALUE", help="extra SITL parameter for every arm")
    p.add_argument("--companion-set", action="append", metavar="SECTION.KEY=VALUE")
    p.add_argument("--outdir", default="out/sitl_gravity")
    p.add_argument("--results", metavar="NAME", help="also write replay/results/sitl_gravity_NAME.md and its plot")
    p.add_argument("--from-dir", metavar="DIR", help="analyse the flights kept in DIR (a finished run's --outdir) again, "
                   "with that run's options, instead of flying")
    a = p.parse_args(argv)
    prior = None
    if a.from_dir:
        prior = json.loads((Path(a.from_dir) / "summary.json").read_text())
        results, from_dir = a.results, a.from_dir
        argv = [x for x in prior["run"]["argv"]]
        a = p.parse_args(argv)
        a.results, a.outdir = results, from_dir
    try:
        a.sitl_bin_path = resolve_bin(a.sitl_bin, BIN_ENV[a.vehicle])
    except HarnessError as e:
        print(f"sitl_gravity: error: {e}", file=sys.stderr)
        return 2
    a.map_path = Path(a.map).resolve()
    gmap = load_grid(a.map_path)
    a.local_map = gmap.axes != "geographic_deg"
    if a.local_map and "companion" in a.arms:
        print("sitl_gravity: error: the live companion needs a geographic (lat/lon) grid", file=sys.stderr)
        return 2
    lat0, lon0 = (float(x) for x in a.origin.split(","))
    boat = a.vehicle == "rover"
    a.survey = gc.Survey((lat0, lon0), a.line_km or (8.0 if boat else 30.0), a.spacing_km or (1.5 if boat else 4.0),
                         a.lines, a.heading_deg, 0.0 if boat else 150.0)
    if a.current_mps is None:  # a run kept from before the current was simulated flew in still water
        a.current_mps = 0.5 if boat and (prior is None or "current_mps" in prior["run"]["schedule"]) else 0.0
    a.schedule = gc.Schedule(a.healthy_min, a.denial_min, a.back_min, a.wind_mps, turb_mps=a.turb_mps,
                             current_mps=a.current_mps if boat else 0.0, current_dir_deg=a.current_dir_deg,
                             current_turn_deg=a.current_turn_deg)
    a.defaults = defaults_for(a.vehicle, a.sitl_bin_path)
    a.outdir = Path(a.outdir).resolve()
    a.outdir.mkdir(parents=True, exist_ok=True)
    sig = gc.map_signal(a.survey, LocalGravityMap.around(gmap), origin_lat_lon=(lat0, lon0))
    started, load_before = time.strftime("%Y-%m-%d %H:%M:%S %Z"), machine_state()
    print(f"survey: {a.survey}; map along it: {sig}; {load_before}", flush=True)
    a.alone_instance = free_instance()
    if prior is not None:
        run0 = prior["run"]
        started, load_before = run0["started"], run0["load_before"]
        flown = {arm: {"log": core.FlightLog.from_dict(json.loads((a.outdir / arm / "log.json").read_text())),
                       "notes": s["notes"], "wall_s": s["wall_s"], "work": a.outdir / arm}
                 for arm, s in prior["arms"].items()}
    elif a.jobs > 1 and len(a.arms) > 1:
        with ThreadPoolExecutor(len(a.arms)) as ex:
            futs = {arm: ex.submit(fly, a, arm) for arm in a.arms}
            flown = {arm: f.result() for arm, f in futs.items()}
    else:
        flown = {arm: fly(a, arm) for arm in a.arms}
    summary = summarise(a, flown)
    load_after = prior["run"]["load_after"] if prior is not None else machine_state()
    summary["run"] = {"argv": argv, "started": started, "load_before": load_before, "load_after": load_after,
                      "sitl": f"{a.sitl_bin_path} ({sitl_commit(a.sitl_bin_path)})", "speedup": a.speedup,
                      "defaults": [str(d) for d in a.defaults], "map_along_survey": sig,
                      "params": {arm: arm_params(a, arm) for arm in a.arms},
                      "companion_sets": companion_sets(a) if "companion" in a.arms else [],
                      "survey": a.survey.__dict__, "schedule": a.schedule.__dict__}
    (a.outdir / "summary.json").write_text(json.dumps(summary, indent=1))
    from replay.live import sitl_gravity_report as rep

    table = rep.table(summary, a.vehicle)
    (a.outdir / "table.md").write_text(table + "\n")
    rep.plot(a, flown, a.outdir / "error.png")
    print(table)
    print(f"wrote {a.outdir / 'summary.json'}, table.md, error.png")
    if a.results:
        rep.write_results(a, summary, table, a.outdir / "error.png", REPO / "replay" / "results")
    return 0 if all(s["kept_up"] for s in summary["arms"].values()) else 3


if __name__ == "__main__":
    raise SystemExit(main())
