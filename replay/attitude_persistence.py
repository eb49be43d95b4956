"""How long the autopilot's attitude error persists, on the shared 50 Hz logs and on the suite's simulated flights.

    .venv/bin/python -m replay.attitude_persistence

Two measures, printed as tables (the numbers quoted under ``att_fuse_interval_s`` in companion/nav/config.py):

1. The autocorrelation of the INS filter's tilt innovations (its accepted ``attitude`` MeasurementUpdates, every
   sample fused, the navigator's defaults) at several lags: a filter whose measurement model is right sees white
   innovations; a persistent autopilot error shows as correlation.
2. A measure that does not depend on the filter: the RMS per tilt axis of the autopilot's attitude change over a lag
   against the gyros' own integration over the same lag (the body rotation from IMU0, with a constant gyro bias
   removed: the median of the two's mismatch rate over 2 s), lags spanning an IMU gap left out. A white autopilot
   error gives the same value at every lag; a persistent one grows with the lag until it decorrelates.
"""

from __future__ import annotations

import math

import numpy as np

from companion.events import Attitude, Event, ImuSample
from companion.nav.ins import dcm_from_quat, quat_from_euler
from companion.nav.navigator import NavigatorConfig, run_navigator
from companion.nav.outputs import MeasurementUpdate
from companion.sim.circle import simulate_circle_flight
from replay.harness.blockages import SHARED_LOGS, load_log

INNOVATION_LAGS_S = (0.1, 0.5, 1.0, 3.0, 10.0)
CHANGE_LAGS_S = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0)


def innovation_autocorrelation(events: list[Event], lags_s=INNOVATION_LAGS_S) -> tuple[int, list[float]]:
    """(accepted attitude updates, autocorrelation of their two tilt innovations per lag, mean over the axes)."""
    ups = [u for u in run_navigator(events, NavigatorConfig())
           if isinstance(u, MeasurementUpdate) and u.kind == "attitude" and u.accepted]
    t = np.array([u.t_s for u in ups])
    y = np.array([u.innovation[:2] for u in ups])
    y = y - y.mean(axis=0)
    out = []
    for lag in lags_s:
        j = np.minimum(np.searchsorted(t, t + lag), len(t) - 1)
        i = np.nonzero(np.abs(t[j] - (t + lag)) < 0.06)[0]
        out.append(float(np.mean([np.corrcoef(y[i, a], y[j[i], a])[0, 1] for a in range(2)])) if len(i) > 2
                   else math.nan)
    return len(ups), out


def _rot(v: np.ndarray) -> np.ndarray:
    a = float(np.linalg.norm(v))
    if a < 1e-12:
        return np.eye(3)
    k = v / a
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(a) * K + (1.0 - math.cos(a)) * K @ K


def _vee(E: np.ndarray) -> np.ndarray:
    return 0.5 * np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])


def change_vs_gyros(events: list[Event], lags_s=CHANGE_LAGS_S,
                    bias_radps: np.ndarray | None = None) -> tuple[np.ndarray, list[float]]:
    """(the constant gyro bias removed, rad/s; RMS tilt mismatch per axis per lag, rad). The bias is estimated unless
    given; an autopilot error that wanders (a random walk) biases the estimate on a short flight."""
    imu = [(e.t_s, np.asarray(e.gyro_frd_radps)) for e in events if isinstance(e, ImuSample) and e.imu_index == 0]
    att = [(e.t_s, dcm_from_quat(quat_from_euler(e.roll_rad, e.pitch_rad, e.yaw_rad)))
           for e in events if isinstance(e, Attitude)]
    ti = np.array([x[0] for x in imu])
    g = np.array([x[1] for x in imu])
    ta = np.array([x[0] for x in att])
    gaps = ti[1:][np.diff(ti) > 0.1]

    def body_rotation(bias):  # cumulative body rotation at each IMU time (not integrated across a gap)
        Q = [np.eye(3)]
        for k in range(1, len(ti)):
            d = ti[k] - ti[k - 1]
            Q.append(Q[-1] @ _rot((g[k] - bias) * d) if d < 0.1 else Q[-1])
        return Q

    def at(Q, t):
        k = int(np.searchsorted(ti, t)) - 1
        return None if k < 0 or k >= len(ti) - 1 else Q[k] @ _rot(g[k + 1] * (t - ti[k]))

    def pairs(Q, lag):
        j = np.searchsorted(ta, ta - lag)
        for i in range(len(ta)):
            k = int(j[i])
            if k >= len(ta) or abs(ta[k] - (ta[i] - lag)) > 0.03 or ((gaps > ta[k]) & (gaps <= ta[i] + 0.1)).any():
                continue
            q1, q2 = at(Q, ta[k]), at(Q, ta[i])
            if q1 is not None and q2 is not None:
                yield k, i, q1.T @ q2

    if bias_radps is None:
        Q = body_rotation(np.zeros(3))
        rates = [_vee(dR.T @ (att[k][1].T @ att[i][1])) / (ta[i] - ta[k]) for k, i, dR in pairs(Q, 2.0)]
        bias = -np.median(np.array(rates), axis=0)
    else:
        bias = np.asarray(bias_radps, dtype=float)
    Q = body_rotation(bias)
    rms = []
    for lag in lags_s:
        d = [np.sum(_vee(att[i][1] @ (att[k][1] @ dR).T)[:2] ** 2) for k, i, dR in pairs(Q, lag)]
        rms.append(float(np.sqrt(np.mean(d) / 2)) if d else math.nan)
    return bias, rms


def main() -> int:
    flights: list[tuple[str, list[Event]]] = []
    for p in sorted(SHARED_LOGS.glob("*.bin")):
        try:
            log = load_log(p)
        except ValueError:
            continue
        if log.imu_rate_hz >= 20:
            flights.append((p.name[:40], log.events))
    for seed in (1, 2):
        sim = simulate_circle_flight(120.0, np.random.default_rng(seed))
        flights.append((f"simulated circle, seed {seed}", sim.events))
    print("Tilt innovations of the INS filter, autocorrelation at lag (s):\n")
    print("| flight | updates | " + " | ".join(f"{x:g}" for x in INNOVATION_LAGS_S) + " |")
    print("|---|---:|" + "---:|" * len(INNOVATION_LAGS_S))
    for name, ev in flights:
        n, r = innovation_autocorrelation(ev)
        print(f"| {name} | {n} | " + " | ".join(f"{x:.2f}" for x in r) + " |")
    print("\nAutopilot attitude change against the gyros' integration, RMS per tilt axis (deg) at lag (s):\n")
    print("| flight | gyro bias removed deg/s | " + " | ".join(f"{x:g}" for x in CHANGE_LAGS_S) + " |")
    print("|---|---|" + "---:|" * len(CHANGE_LAGS_S))
    for name, ev in flights:
        b, rms = change_vs_gyros(ev)
        print(f"| {name} | {' '.join(f'{x:+.3f}' for x in np.degrees(b))} | "
              + " | ".join(f"{x:.2f}" for x in np.degrees(rms)) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
