"""Re-run the companion (navigator + sequential gravity stage + injector, shadow mode) on the inputs it recorded in a
kept gravity-aided SITL flight (replay.live.sitl_gravity, its ``DIR/companion``), with other settings, and score its
own GPS_INPUT in the GNSS denial against SITL's truth: settings compared on the same flight without flying again
(nothing reaches the autopilot in a re-run, so the vehicle's path is the recorded one).

    python -m replay.live.sitl_gravity_rerun out/plane_ak_s1/companion --map GRID.nc --set gravity.seq_accel_bias_ug=2000

Prints the companion's error / stated h_acc / fix type every 5 min of the denial, its mean error and the share of its
3D fixes within 2x their h_acc, and the velocity it stated against SITL's (its steps between messages, its RMS
error). ``--truth-heading``, ``--truth-wind``, ``--perfect-gravimeter`` put SITL's truth in
place of one input (replay.live.sitl_gravity_truth: what limits the error); ``--trace`` prints the filter's wind,
heading and position error estimates beside the true ones.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np

from companion import events as ev
from companion.config import load_config, parse_override
from companion.inject.gps_input import GpsInputRecord, Injector
from companion.pipeline.core import build_pipeline
from replay.live import sitl_core as core

#: the recorded inputs of a live companion (companion.pipeline.core topics) and their event types
INPUTS = {"/input/imu": ev.ImuSample, "/input/imu1": ev.ImuSample, "/input/imu2": ev.ImuSample, "/input/imu3": ev.ImuSample,
          "/input/gnss": ev.GnssFix, "/input/gnss1": ev.GnssFix, "/input/attitude": ev.Attitude, "/input/air_data": ev.AirData,
          "/input/water_speed": ev.WaterSpeed, "/input/mag": ev.MagField,
          "/input/heartbeat": ev.Heartbeat, "/input/system_time": ev.SystemTime,
          "/input/altitude": ev.AutopilotAltitude, "/input/autopilot_position": ev.AutopilotPosition,
          "/input/gravity": ev.GravityReading}


def recorded_inputs(mcap: Path):
    from companion.record.inspect import iter_payloads

    for topic, _t, data in iter_payloads(mcap):
        cls = INPUTS.get(topic)
        if cls is None:
            continue
        d = json.loads(data)
        kw = {}
        for f in dataclasses.fields(cls):
            v = d.get(f.name)
            kw[f.name] = tuple(v) if isinstance(v, list) else (math.nan if v is None and f.type == "float" else v)
        yield cls(**kw)


class _Keep:
    def __init__(self) -> None:
        self.records: list[GpsInputRecord] = []

    def write(self, item, topic=None) -> None:
        if isinstance(item, GpsInputRecord):
            self.records.append(item)

    def write_location(self, *a, **k) -> None:
        pass

    def write_log(self, *a, **k) -> None:
        pass


def recorded_tas(events) -> tuple[np.ndarray, np.ndarray]:
    """(t_s, TAS m/s) of the recorded airspeeds as the air-data stage turns them into true airspeed."""
    from companion.gravity.air_data import tas_from_eas_mps

    alt, out = None, []
    for e in events:
        if isinstance(e, ev.AutopilotAltitude) and math.isfinite(e.alt_msl_m):
            alt = float(e.alt_msl_m)
        elif isinstance(e, ev.AirData) and alt is not None:
            out.append((e.t_s, tas_from_eas_mps(e.airspeed_mps, alt)))
    a = np.asarray(out, float).reshape(-1, 2)
    return a[:, 0], a[:, 1]


def rerun(arm_dir: Path, sets: list[str], *, truth_heading: bool = False, truth_wind: bool = False,
          perfect_gravimeter: bool = False, wind_window_s: float = 60.0, trace: bool = False,
          filter_seed: int | None = None) -> dict:
    """The companion's own figures in the denial with ``sets`` (section.key=value, as ``companion run --set``) and
    SITL's truth in place of the inputs asked for (replay.live.sitl_gravity_truth); ``trace``: its filter's estimates
    beside the truth's (``FilterTrace``, under "trace"); ``filter_seed``: the particle filter's draws (the stage's own
    seed otherwise)."""
    from companion.gravity.stage import live_gravity_stage
    from companion.sim.truth_gravimeter import GravimeterSpec
    from replay.live import sitl_gravity_truth as tru

    log = core.FlightLog.from_dict(json.loads((arm_dir / "log.json").read_text()))
    cfg = load_config(None, dict(parse_override(s) for s in ['link.connect="tcp:127.0.0.1:1"', 'inject.mode="shadow"', *sets]))
    sink = _Keep()
    stage = live_gravity_stage(cfg.gravity)
    if filter_seed is not None:
        from companion.gravity.sequential import SequentialGravityFilter

        stage.filter = SequentialGravityFilter(stage.lmap, stage.cfg, np.random.default_rng(filter_seed))
    events = list(recorded_inputs(arm_dir / "companion.mcap"))
    track = tru.TruthTrack(log.truth, log.truth_yaw) if (truth_heading or truth_wind or perfect_gravimeter or trace) else None
    wind = tru.TruthWind(track, *recorded_tas(events), window_s=wind_window_s) if (truth_wind or trace) else None
    if truth_heading or truth_wind:
        stage.dr = tru.TruthReckoner(stage.dr.cfg, yaw=track if truth_heading else None,
                                     wind=wind if truth_wind else None)
    tracer = tru.FilterTrace(stage, track, wind) if trace else None
    pipe = build_pipeline(sink, nav_config=cfg.nav_config(),
                          extra_stages=[stage, Injector(cfg.inject, trust=cfg.trust)])
    window_s = GravimeterSpec().window_s
    for e in events:
        if perfect_gravimeter and isinstance(e, ev.GravityReading):
            e = dataclasses.replace(e, gravity_mgal=tru.perfect_reading_mgal(track, stage.lmap, e.t_s, window_s))
        pipe.process(e)
    pipe.finish()
    on, off = log.marks["deny_on"], log.marks["deny_off"]
    recs = [{"sent": True, "lat_deg": r.lat_deg, "lon_deg": r.lon_deg, "time_boot_us": r.time_boot_us,
             "fix_type": r.fix_type, "h_acc_m": r.h_acc_m} for r in sink.records]
    t, err, fx, hacc = core.companion_error(recs, log.truth)
    den = (t >= on) & (t < off)
    d3 = den & (fx >= 3)
    vel = velocity_figures(sink.records, log.truth, on, off)
    marks = {}
    for m in range(5, int((off - on) / 60.0) + 1, 5):
        i = int(np.argmin(np.abs(t - (on + 60.0 * m)))) if len(t) else 0
        marks[m] = (float(err[i]), float(hacc[i]), int(fx[i])) if len(t) and abs(t[i] - on - 60.0 * m) < 5 else None
    return {"marks": marks, "mean_m": float(err[den].mean()) if den.any() else math.nan,
            "mean_3d_m": float(err[d3].mean()) if d3.any() else math.nan,
            "share_3d": float(d3.sum() / max(1, den.sum())),
            "within_2hacc": float(np.mean(err[d3] <= 2 * hacc[d3])) if d3.any() else math.nan,
            "trace": tracer, "deny_on_s": on, "velocity": vel, "stage": stage.summary_lines()}


def velocity_figures(records: list[GpsInputRecord], truth, on_s: float, off_s: float) -> dict[str, float]:
    """The velocity the companion stated in its 3D fixes of the denial against SITL's: the steps between messages
    (median and 95th percentile, m/s^2) beside the truth's at the same times, and the RMS error (m/s)."""
    rs = [r for r in records if r.sent and r.fix_type >= 3 and on_s <= r.time_boot_us / 1e6 < off_s]
    if len(rs) < 3:
        return {}
    t = np.array([r.time_boot_us / 1e6 for r in rs])
    v = np.array([(r.vel_n_mps, r.vel_e_mps) for r in rs])
    vt = core.truth_velocity_ne(truth, t)
    ok = np.all(np.isfinite(vt), axis=1)
    if ok.sum() < 3:  # no truth around them
        return {}
    st, tr = core.velocity_steps_mps2(t[ok], v[ok]), core.velocity_steps_mps2(t[ok], vt[ok])
    return {"step_median_mps2": float(np.median(st)), "step_p95_mps2": float(np.percentile(st, 95)),
            "truth_step_median_mps2": float(np.median(tr)), "truth_step_p95_mps2": float(np.percentile(tr, 95)),
            "error_rms_mps": float(np.sqrt(np.mean(np.sum((v[ok] - vt[ok]) ** 2, axis=1))))}


def _dcm(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = (f(x) for x in (roll, pitch, yaw) for f in (math.cos, math.sin))
    return np.array([[cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
                     [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy], [-sp, sr * cp, cr * cp]])


def imu_attitude_residual(mcap: Path, t0_s: float, t1_s: float, g_mps2: float = 9.80665) -> dict[str, float]:
    """Whether the autopilot's IMU (RAW_IMU) and attitude (ATTITUDE) agree with its GNSS: mean over [t0, t1) of the
    1 s mean specific force rotated to NED by ATTITUDE, plus gravity, minus the GNSS velocity change over that second
    (m/s^2), north/east/down and along/across the heading. Zero when the three are consistent; otherwise what an INS
    integrating these samples with this attitude would see beyond the vehicle's real acceleration."""
    imu, att, gn = [], [], []
    for topic, _t, data in __import__("companion.record.inspect", fromlist=["iter_payloads"]).iter_payloads(mcap):
        if topic not in ("/input/imu", "/input/attitude", "/input/gnss"):
            continue
        d = json.loads(data)
        if topic == "/input/imu":
            imu.append([d["t_s"], *d["accel_frd_mps2"]])
        elif topic == "/input/attitude":
            att.append([d["t_s"], d["roll_rad"], d["pitch_rad"], d["yaw_rad"]])
        elif d.get("vel_n_mps") is not None:
            gn.append([d["t_s"], d["vel_n_mps"], d["vel_e_mps"], d.get("vel_d_mps") or 0.0])
    imu_a, att_a, gn_a = np.array(imu), np.array(att), np.array(gn)
    rows = []
    for t in np.arange(t0_s, t1_s, 1.0):
        sel = (imu_a[:, 0] >= t - 0.5) & (imu_a[:, 0] < t + 0.5)
        if not sel.any():
            continue
        r, p, y = (float(np.interp(t, att_a[:, 0], att_a[:, k])) for k in (1, 2, 3))
        dv = np.array([np.interp(t + 0.5, gn_a[:, 0], gn_a[:, k]) - np.interp(t - 0.5, gn_a[:, 0], gn_a[:, k])
                       for k in (1, 2, 3)])
        res = _dcm(r, p, y) @ imu_a[sel, 1:].mean(axis=0) + np.array([0.0, 0.0, g_mps2]) - dv
        rows.append([*res, y])
    a = np.array(rows)
    along = a[:, 0] * np.cos(a[:, 3]) + a[:, 1] * np.sin(a[:, 3])
    across = -a[:, 0] * np.sin(a[:, 3]) + a[:, 1] * np.cos(a[:, 3])
    return {"north": float(a[:, 0].mean()), "east": float(a[:, 1].mean()), "down": float(a[:, 2].mean()),
            "along": float(along.mean()), "across": float(across.mean()), "seconds": len(a)}


def main(argv: list[str] | None = None) -> int:
    from replay.live.sitl_gravity import COMPANION_SETS, VEHICLE_SETS

    p = argparse.ArgumentParser(prog="python -m replay.live.sitl_gravity_rerun", description=__doc__.split("\n\n")[0])
    p.add_argument("dir", help="the companion arm of a kept run (DIR/companion of replay.live.sitl_gravity)")
    p.add_argument("--map", required=True, help="the gravity grid the run flew over")
    p.add_argument("--vehicle", choices=tuple(VEHICLE_SETS), default="plane")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="on top of the run's companion settings (replay.live.sitl_gravity.COMPANION_SETS)")
    p.add_argument("--truth-heading", action="store_true", help="the reference's heading = SIMSTATE yaw")
    p.add_argument("--truth-wind", action="store_true", help="the held wind replaced by the true wind at each step")
    p.add_argument("--truth-wind-window-s", type=float, default=60.0, help="the true wind's averaging window")
    p.add_argument("--perfect-gravimeter", action="store_true",
                   help="readings = the map at the true positions (+ the true Eotvos term), no misfit, bias or noise")
    p.add_argument("--filter-seed", type=int, default=None, help="the particle filter's seed (the stage's own: 0)")
    p.add_argument("--trace", action="store_true",
                   help="the filter's wind/heading/position error estimates beside the truth, every --trace-step-min")
    p.add_argument("--trace-step-min", type=float, default=2.5)
    p.add_argument("--imu-check", metavar="T0,T1", help="only the IMU/attitude/GNSS consistency over boot seconds T0..T1")
    a = p.parse_args(argv)
    arm = Path(a.dir)
    if a.imu_check:
        t0, t1 = (float(x) for x in a.imu_check.split(","))
        r = imu_attitude_residual(arm / "companion.mcap", t0, t1)
        print("IMU rotated by ATTITUDE + gravity - GNSS acceleration (m/s^2), mean over "
              f"{r['seconds']} s: N {r['north']:+.3f} E {r['east']:+.3f} D {r['down']:+.3f}; along the heading "
              f"{r['along']:+.3f}, across {r['across']:+.3f}")
        return 0
    if not (arm / "companion.mcap").exists() or not (arm / "log.json").exists():
        print(f"no companion.mcap and log.json in {arm}", file=sys.stderr)
        return 2
    sets = COMPANION_SETS + VEHICLE_SETS[a.vehicle] + [f"gravity.map={json.dumps(str(Path(a.map).resolve()))}"] + a.set
    r = rerun(arm, sets, truth_heading=a.truth_heading, truth_wind=a.truth_wind, perfect_gravimeter=a.perfect_gravimeter,
              wind_window_s=a.truth_wind_window_s, trace=a.trace, filter_seed=a.filter_seed)
    truth = [n for n, on in (("heading", a.truth_heading), ("wind", a.truth_wind), ("gravimeter", a.perfect_gravimeter))
             if on]
    print(f"settings: --set {' --set '.join(a.set) or '(the run s own)'}; truth for: {', '.join(truth) or 'nothing'}")
    print("  error / h_acc / fix every 5 min: " + "  ".join(
        f"{k}: {v[0]:.0f}/{v[1]:.0f}/{v[2]}" if v else f"{k}: -" for k, v in r["marks"].items()))
    print("\n".join("  " + line for line in r["stage"]))
    print(f"  mean {r['mean_m']:.0f} m (3D fixes {r['mean_3d_m']:.0f} m, {r['share_3d']:.0%} of the denial's "
          f"GPS_INPUT); within 2x h_acc {r['within_2hacc']:.0%}")
    v = r["velocity"]
    if v:
        print(f"  stated velocity: steps median / p95 {v['step_median_mps2']:.2f} / {v['step_p95_mps2']:.1f} m/s^2 "
              f"(the truth's {v['truth_step_median_mps2']:.2f} / {v['truth_step_p95_mps2']:.1f}), error RMS "
              f"{v['error_rms_mps']:.2f} m/s")
    if r["trace"] is not None:
        print("\n".join(r["trace"].lines(r["deny_on_s"], np.arange(a.trace_step_min, 60.01, a.trace_step_min))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
