"""Regenerate the shipped sample log: ``python -m companion.sim.make_sample [--out logs/sample_flight.tlog]``.

Deterministic (fixed seed, fixed boot epoch, no wall clock): the output is byte-for-byte the same on
every run with the same numpy/pymavlink.
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from companion.sim.flight import SAMPLE_OUTAGE_S, SAMPLE_SEED, SimulatedFlight, sample_flight
from companion.sim.mavlink_out import pack_stream, telemetry_messages
from companion.sim.tlog import tlog_bytes

REPO = Path(__file__).resolve().parents[2]
# in a checkout: logs/sample_flight.tlog, a link to the package data companion/data/sample_flight.tlog
# (the truth CSV goes beside the link); installed: logs/ in the current directory, never site-packages
DEFAULT_OUT = (REPO if (REPO / "pyproject.toml").exists() else Path(".")) / "logs" / "sample_flight.tlog"
TRUTH_RATE_HZ = 10.0


def flight_tlog_bytes(flight: SimulatedFlight) -> tuple[bytes, Counter]:
    msgs = telemetry_messages(flight)
    counts = Counter(o.msg.get_type() for o in msgs)
    return tlog_bytes(pack_stream(msgs, flight.config.boot_epoch_us)), counts


def _fixed(v: float, decimals: int) -> str:
    """``v`` with ``decimals`` decimals, never "-0.000...": the sign of a value below the resolution depends on the
    numpy build's last bits (the sample must regenerate byte for byte on any)."""
    s = f"{v:.{decimals}f}"
    return s[1:] if s.startswith("-") and float(s) == 0.0 else s


def truth_csv_text(flight: SimulatedFlight, rate_hz: float = TRUTH_RATE_HZ) -> str:
    """Truth at ``rate_hz``: time, geodetic position, NED position and velocity, attitude."""
    tr = flight.profile.sample_rate(rate_hz)
    import io

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(
        ["t_s", "lat_deg", "lon_deg", "alt_msl_m", "n_m", "e_m", "d_m", "vn_mps", "ve_mps", "vd_mps",
         "roll_rad", "pitch_rad", "yaw_rad"]
    )
    for k in range(len(tr)):
        w.writerow(
            [_fixed(tr.t_s[k], 1), _fixed(tr.lat_deg[k], 9), _fixed(tr.lon_deg[k], 9), _fixed(tr.alt_msl_m[k], 4)]
            + [_fixed(v, 4) for v in tr.pos_ned_m[k]]
            + [_fixed(v, 4) for v in tr.vel_ned_mps[k]]
            + [_fixed(v, 6) for v in tr.euler_rad[k]]
        )
    return buf.getvalue()


def plot_flight(flight: SimulatedFlight, path: Path) -> None:
    """Track (NE) with the GNSS fixes, height and horizontal GNSS error over time; outages shaded."""
    from companion.extras import require

    matplotlib = require("matplotlib", "plots", "the sample flight's plot")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tr = flight.profile.sample_rate(TRUTH_RATE_HZ)
    g = flight.gnss
    fix = g.has_fix
    gps_ned = flight.profile.frame.to_ned_m(g.lat_deg[fix], g.lon_deg[fix], g.alt_msl_m[fix])
    fig = plt.figure(figsize=(11, 7))
    ax = fig.add_subplot(1, 2, 1)
    ax.plot(tr.pos_ned_m[:, 1], tr.pos_ned_m[:, 0], "k-", lw=1, label="truth")
    ax.plot(gps_ned[:, 1], gps_ned[:, 0], ".", ms=2, color="tab:blue", label="GPS_RAW_INT fixes")
    out = flight.config.gnss.outages_s
    for t0, t1 in out:
        sel = (tr.t_s >= t0) & (tr.t_s < t1)
        ax.plot(tr.pos_ned_m[sel, 1], tr.pos_ned_m[sel, 0], "-", color="tab:red", lw=3, label="GNSS outage")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal")
    ax.legend(loc="best", fontsize=8)
    ax.set_title("sample flight: horizontal track")
    ax2 = fig.add_subplot(2, 2, 2)
    ax2.plot(tr.t_s, -tr.pos_ned_m[:, 2], "k-", lw=1, label="height above home (truth)")
    ax2.plot(tr.t_s, np.hypot(tr.vel_ned_mps[:, 0], tr.vel_ned_mps[:, 1]), "-", color="tab:green", lw=1,
             label="ground speed (m/s)")
    ax2.set_ylabel("m, m/s")
    ax2.legend(loc="best", fontsize=8)
    ax3 = fig.add_subplot(2, 2, 4, sharex=ax2)
    err = g.pos_error_ned_m
    # no line across an outage: NaN where there is no fix (and between fixes further apart than 3 periods)
    t_err, h_err = _break_gaps(g.t_s, np.where(fix, np.hypot(err[:, 0], err[:, 1]), np.nan))
    _, d_err = _break_gaps(g.t_s, np.where(fix, err[:, 2], np.nan))
    ax3.plot(t_err, h_err, "-", color="tab:blue", lw=1, label="horizontal")
    ax3.plot(t_err, d_err, "-", color="tab:orange", lw=1, label="down")
    ax3.set_ylabel("GNSS error (m)")
    ax3.set_xlabel("boot time (s)")
    for a in (ax2, ax3):
        for k, (t0, t1) in enumerate(out):
            a.axvspan(t0, t1, color="tab:red", alpha=0.2, label="GNSS outage" if a is ax3 and k == 0 else None)
    ax3.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _break_gaps(t: np.ndarray, y: np.ndarray, factor: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """``t``, ``y`` with a NaN point inserted wherever consecutive times are more than ``factor`` median steps apart,
    so a plotted line stops at a gap instead of drawing straight across it."""
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    if t.size < 3:
        return t, y
    dt = np.diff(t)
    cut = np.flatnonzero(dt > factor * np.median(dt)) + 1
    return np.insert(t, cut, t[cut - 1] + dt[cut - 1] / 2), np.insert(y, cut, np.nan)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output .tlog (default: %(default)s)")
    ap.add_argument(
        "--truth", type=Path, default=None, help="truth CSV (default: <out stem>_truth.csv beside the tlog)"
    )
    ap.add_argument("--plot", type=Path, default=None, help="also draw the flight (track, height, GNSS error) to this PNG")
    args = ap.parse_args(argv)
    flight = sample_flight()
    data, counts = flight_tlog_bytes(flight)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_bytes(data)
    truth = args.truth or args.out.with_name(args.out.stem + "_truth.csv")
    truth.write_text(truth_csv_text(flight))
    print(f"wrote {args.out} ({len(data)} bytes, {sum(counts.values())} messages, {flight.duration_s:.2f} s)")
    for name, n in sorted(counts.items()):
        print(f"  {name:12s} {n:6d}")
    print(f"wrote {truth} ({truth.stat().st_size} bytes)")
    print(f"seed {SAMPLE_SEED}; GNSS outage {SAMPLE_OUTAGE_S[0]:.1f}-{SAMPLE_OUTAGE_S[1]:.1f} s; armed "
          f"{flight.armed_s[0]:.2f}-{flight.armed_s[1]:.2f} s")
    if args.plot is not None:
        plot_flight(flight, args.plot)
        print(f"wrote {args.plot}")
    np.set_printoptions(precision=4, suppress=True)
    print(f"IMU biases: accel {flight.imu.accel_bias_frd_mps2} m/s^2, gyro {flight.imu.gyro_bias_frd_radps} rad/s")
    if flight.imu2 is not None:
        print(f"IMU2 biases: accel {flight.imu2.accel_bias_frd_mps2} m/s^2, gyro {flight.imu2.gyro_bias_frd_radps} rad/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
