"""The gyro heading (companion.gravity.gyro_heading) on a kept SITL gravity flight, against SITL's true yaw: how well
the autopilot's first gyro, as the companion received it (RAW_IMU at 25 Hz, its recorded ``/input/imu``), integrated
and levelled by ATTITUDE roll/pitch, holds the heading through the denial, and what it costs in the turns.

    python -m replay.live.sitl_gyro_heading out/plane_ak_s1/companion [--window-s 1200]

Reads DIR/companion.mcap (the companion's recorded inputs) and DIR/log.json (the harness's: SIMSTATE yaw, ATTITUDE yaw,
the denial's marks). Learns while GNSS1 has a 3D fix, freezes at the denial's start, as the air-data stage does.
Prints, every 5 min of the denial, the gyro heading's error against SIMSTATE yaw, its stated sigma and EKF3's ATTITUDE
yaw error; the RMS over the denial and the share within 2 sigma; and the integration's error over each turn (the
change of ``I - true yaw`` across it, less the learnt bias times its duration) and the bare integral's drift against the
truth since the denial's start. Nothing is flown.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from companion import events as ev
from companion.gravity.gyro_heading import GyroHeading, GyroHeadingConfig
from replay.live.sitl_gravity_rerun import recorded_inputs

GNSS_TIMEOUT_S = 0.6


def analyse(arm_dir: Path, cfg: GyroHeadingConfig, imu_index: int = 3) -> dict:
    log = json.loads((arm_dir / "log.json").read_text())
    on, off = float(log["marks"]["deny_on"]), float(log["marks"].get("deny_off", math.inf))
    ty = np.asarray(log["truth_yaw"], float)
    t_tr, yaw_tr = ty[:, 0], np.unwrap(ty[:, 1])
    gh = GyroHeading(cfg)
    good_t = -math.inf
    rows = []  # t, heading (or nan), sigma, integral
    events = sorted(recorded_inputs(arm_dir / "companion.mcap"), key=lambda e: e.t_s)
    for e in events:
        if isinstance(e, ev.GnssFix) and e.instance == 0 and e.fix_type >= 3 and e.has_position and e.t_s < on:
            good_t = e.t_s
        elif isinstance(e, ev.Attitude):
            gh.attitude(e.t_s, e.roll_rad, e.pitch_rad, e.yaw_rad, learn=e.t_s - good_t <= GNSS_TIMEOUT_S)
        elif isinstance(e, ev.ImuSample) and e.imu_index == imu_index:
            if e.t_s >= on:
                gh.freeze(on)
            gh.gyro(e.t_s, e.gyro_frd_radps)
            h = gh.heading_rad(e.t_s)
            rows.append((e.t_s, math.nan if h is None else h, gh.sigma_rad(e.t_s) or math.nan, gh.integral_rad))
    a = np.asarray(rows, float)
    sel = (a[:, 0] >= on) & (a[:, 0] < off) & (a[:, 0] <= t_tr[-1])
    t = a[sel, 0]
    err = np.angle(np.exp(1j * (a[sel, 1] - np.interp(t, t_tr, yaw_tr))))
    sig = a[sel, 2]
    att = np.asarray(log["yaw"], float)
    asel = (att[:, 0] >= on) & (att[:, 0] < off)
    att_err = np.angle(np.exp(1j * (att[asel, 1] - np.interp(att[asel, 0], t_tr, yaw_tr))))
    d_int = a[:, 3] - np.interp(a[:, 0], t_tr, yaw_tr)  # the bare integral against the truth
    d_on = float(np.interp(on, a[:, 0], d_int))
    marks = {}
    for m in range(5, int((min(off, t[-1]) - on) / 60.0) + 1, 5):
        k = int(np.searchsorted(t, on + 60.0 * m))
        ka = int(np.searchsorted(att[asel, 0], on + 60.0 * m))
        if k < t.size:
            marks[str(m)] = {"gyro_deg": float(np.degrees(err[k])), "sigma_deg": float(np.degrees(sig[k])),
                             "attitude_deg": float(np.degrees(att_err[min(ka, att_err.size - 1)])),
                             "integral_drift_deg": float(np.degrees(np.interp(on + 60.0 * m, a[:, 0], d_int) - d_on))}
    # turns: the truth turning faster than 1 deg/s, joined while closer than 10 s, by more than 30 deg in all
    rate = np.gradient(yaw_tr, t_tr)
    turning = np.abs(rate) > math.radians(1.0)
    d_all = d_int
    turns = []
    i = 0
    idx = np.nonzero(turning)[0]
    while i < idx.size:
        j = i
        while j + 1 < idx.size and t_tr[idx[j + 1]] - t_tr[idx[j]] < 10.0:
            j += 1
        t0, t1 = t_tr[idx[i]] - 5.0, t_tr[idx[j]] + 5.0
        turned = float(np.interp(t1, t_tr, yaw_tr) - np.interp(t0, t_tr, yaw_tr))
        if abs(turned) > math.radians(30.0) and a[0, 0] < t0 and t1 < a[-1, 0]:
            b = gh.bias_radps or 0.0
            dd = float(np.interp(t1, a[:, 0], d_all) - np.interp(t0, a[:, 0], d_all)) - b * (t1 - t0)
            turns.append({"t_s": float(t0), "turned_deg": float(np.degrees(turned)), "error_deg": float(np.degrees(dd))})
        i = j + 1
    f = gh.fit()
    return {"denial_s": [on, off], "marks": marks,
            "gyro_rms_deg": float(np.degrees(np.sqrt(np.nanmean(err**2)))),
            "gyro_within_2sigma": float(np.mean(np.abs(err) <= 2.0 * sig)),
            "attitude_rms_deg": float(np.degrees(np.sqrt(np.mean(att_err**2)))),
            "bias_degph": None if f is None else float(np.degrees(f[1]) * 3600.0),
            "sigma_bias_degph": None if f is None else float(np.degrees(f[3]) * 3600.0),
            "sigma_align_deg": None if f is None else float(np.degrees(f[2])),
            "gaps": gh.gaps, "unlevelled": gh.unlevelled, "samples": int(a.shape[0]), "turns": turns}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("arm_dir", type=Path, help="a kept flight's companion arm (its --outdir/companion)")
    p.add_argument("--window-s", type=float, default=GyroHeadingConfig.window_s)
    p.add_argument("--imu-index", type=int, default=3, help="0: RAW_IMU, 3: HIGHRES_IMU (companion.mavlink.decode)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    a = p.parse_args(argv)
    r = analyse(a.arm_dir, GyroHeadingConfig(window_s=a.window_s), a.imu_index)
    if a.json:
        print(json.dumps(r, indent=1))
        return 0
    print(f"bias learnt {r['bias_degph']:.1f} deg/h (sigma {r['sigma_bias_degph']:.2f}), alignment sigma "
          f"{r['sigma_align_deg']:.2f} deg; {r['samples']} gyro samples, {r['gaps']} gaps, {r['unlevelled']} unlevelled")
    for m, v in r["marks"].items():
        print(f"+{m:>3} min: gyro {v['gyro_deg']:+6.2f} deg (sigma {v['sigma_deg']:.2f}), ATTITUDE yaw "
              f"{v['attitude_deg']:+6.2f} deg; the bare integral drifted {v['integral_drift_deg']:+.2f} deg")
    print(f"denial: gyro heading {r['gyro_rms_deg']:.2f} deg RMS, {100 * r['gyro_within_2sigma']:.0f} % within 2 sigma; "
          f"ATTITUDE yaw {r['attitude_rms_deg']:.2f} deg RMS")
    for tr in r["turns"]:
        print(f"turn at {tr['t_s']:.0f} s: {tr['turned_deg']:+.0f} deg turned, integration error {tr['error_deg']:+.2f} deg")
    return 0


if __name__ == "__main__":
    sys.exit(main())
