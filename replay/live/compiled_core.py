"""What a compiled core (numba) would save the INS filter: CPU time per call of its covariance step
(``InsFilter.predict``) and of its Kalman update (``KalmanFilter.update_innovation``, 15 states, a 3-dim position
fix), the project's numpy code against the same arithmetic compiled by numba, and numba's own costs (import, the
first call's compile, the next process's cache load). numba is not a dependency of the project (decision record
0014): run it in a scratch environment,

    python3 -m venv /tmp/nb && /tmp/nb/bin/pip install -q . numba && (cd /tmp && /tmp/nb/bin/python -m replay.live.compiled_core)

twice (the second run loads the compiled code from numba's cache, NUMBA_CACHE_DIR or beside this file).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from companion.events import Attitude
from companion.nav.config import NavigatorConfig
from companion.nav.frame import LocalFrame
from companion.nav.gnss_lag import GnssLatency
from companion.nav.ins_filter import InsFilter
from replay.harness.results import md_table


def _predict(P, F0, f, C, dt, q):  # InsFilter.predict's F, phi and P = phi P phi' + Q dt
    F = F0.copy()
    F[3, 7], F[3, 8], F[4, 6], F[4, 8], F[5, 6], F[5, 7] = f[2], -f[1], -f[2], f[0], f[1], -f[0]
    for i in range(3):
        for j in range(3):
            F[3 + i, 9 + j] = -C[i, j]
            F[6 + i, 12 + j] = -C[i, j]
    Fd = F * dt
    phi = np.eye(15) + Fd + 0.5 * (Fd @ Fd)
    P = phi @ P @ phi.T
    for i in range(15):
        P[i, i] += q[i] * dt
    return P


def _update(P, y, H, R):  # KalmanFilter.update_innovation: gain, state, Joseph-form covariance
    PHT = P @ H.T
    K = PHT @ np.linalg.inv(H @ PHT + R)
    I_KH = np.eye(15) - K @ H
    return K @ y, I_KH @ P @ I_KH.T + K @ R @ K.T


def _filter() -> InsFilter:
    c = NavigatorConfig()
    return InsFilter(c, LocalFrame(0.0, 0.0, 0.0), GnssLatency(c.gnss_delay_s, c.gnss_vel_delay_s, None),
                     lambda e: None, 0.0, (0.0, 0.0, 0.0), None, Attitude(0.0, 0.02, -0.01, 0.3), 1)


def _per_call_us(fn, n: int) -> float:
    t0 = time.process_time()
    for _ in range(n):
        fn()
    return (time.process_time() - t0) / n * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=20000)
    args = ap.parse_args()
    t0 = time.process_time()
    from numba import __version__ as numba_version, njit
    import_s = time.process_time() - t0

    predict_nb, update_nb = njit(cache=True)(_predict), njit(cache=True)(_update)
    f = _filter()
    ins = f.strapdown
    P0 = f.kf.P.copy()
    fvec, C, (F0, _eye, q) = np.array(ins.f_ned), ins.dcm(), f._model
    H = np.zeros((3, 15))
    H[:, :3] = np.eye(3)
    R, y = np.eye(3) * 4.0, np.array([0.5, -0.3, 0.2])
    t0 = time.process_time()
    Pb = predict_nb(P0, F0, fvec, C, 0.1, q)
    xb, Pu = update_nb(P0, y, H, R)
    first_s = time.process_time() - t0

    def predict_np() -> None:
        f.kf.P, f.t_s, f._f_n = P0, 0.0, 0
        f.predict(0.1)

    def update_np() -> None:
        f.kf.P, f.kf.x = P0, np.zeros((15, 1))
        PHT = P0 @ H.T
        f.kf.update_innovation(y, R, H, PHT, H @ PHT + R)

    predict_np()
    d_pred = float(np.abs(f.kf.P - Pb).max())
    update_np()
    d_upd = float(max(np.abs(f.kf.P - Pu).max(), np.abs(f.kf.x.ravel() - xb).max()))
    rows = [["InsFilter.predict (covariance step)", f"{_per_call_us(predict_np, args.calls):.1f}",
             f"{_per_call_us(lambda: predict_nb(P0, F0, fvec, C, 0.1, q), args.calls):.1f}", f"{d_pred:.1e}"],
            ["KalmanFilter.update_innovation (3-dim fix)", f"{_per_call_us(update_np, args.calls):.1f}",
             f"{_per_call_us(lambda: update_nb(P0, y, H, R), args.calls):.1f}", f"{d_upd:.1e}"]]
    print(f"numba {numba_version}, numpy {np.__version__}: import {import_s:.2f} s CPU, first calls (compile, or load "
          f"from the cache) {first_s:.2f} s CPU\n")
    print(md_table(["call", "numpy us", "numba us", "largest difference"], rows))


if __name__ == "__main__":
    main()
