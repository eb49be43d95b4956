"""What summing a fast IMU's samples between strapdown steps saves (companion.nav.imu_accumulator): CPU time per
sample of the INS filter's IMU path on a 400 Hz IMU, stepping every sample against ``ins_rate_hz`` 50, and the
attitude and speed after 30 s on the coning mount (companion.sim.coning; both with the Earth's rate, the truth
without: the two are compared with each other).

    .venv-test/bin/python -m replay.live.imu_rate [--repeat 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

from companion.events import Attitude
from companion.nav.config import NavigatorConfig
from companion.nav.frame import LocalFrame
from companion.nav.gnss_lag import GnssLatency
from companion.nav.ins import StrapdownIns
from companion.nav.ins_filter import InsFilter
from companion.sim.coning import ConingMount
from replay.harness.results import md_table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--imu-hz", type=float, default=400.0)
    args = ap.parse_args()
    mount = ConingMount()
    samples = mount.samples(args.imu_hz, 30.0, StrapdownIns(0, 0, 0, 0).gravity())
    rows = []
    for rate in (args.imu_hz, 50.0):
        us, err = [], None
        for _ in range(args.repeat):
            c = NavigatorConfig(ins_rate_hz=rate)
            f = InsFilter(c, LocalFrame(0.0, 0.0, 0.0), GnssLatency(c.gnss_delay_s, c.gnss_vel_delay_s, None),
                          lambda e: None, 0.0, (0.0, 0.0, 0.0), None, Attitude(0.0, 0.0, 0.0, 0.0), 1)
            f.strapdown.q = mount.attitude(0.0)
            t0 = time.process_time()
            for t, a, w in samples:
                f.step_imu(t, a, w)
            f.predict(samples[-1][0])
            us.append((time.process_time() - t0) / len(samples) * 1e6)
            err = mount.errors(f.strapdown.q, f.strapdown.vel_ned, samples[-1][0])
        rows.append([f"{rate:g}", f"{statistics.median(us):.2f}", f"{err[0]:.4f}", f"{err[1]:.4f}"])
    print(f"{args.imu_hz:g} Hz IMU, 30 s, CPU us per sample: median of {args.repeat}; load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores\n")
    print(md_table(["ins_rate_hz", "CPU us per sample", "attitude error deg", "speed error m/s"], rows))


if __name__ == "__main__":
    main()
