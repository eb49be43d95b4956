"""A one-line status of a running ``companion run`` at INFO every ``every_s`` seconds (journal-friendly).

``status: 152 msg/s in, GNSS 10.0 Hz, IMU0 50.0 Hz, nav ins, last fix 0.1 s ago, GPS_INPUT 10.0/s (shadow)``:
rates are over the last period (wall time), the fix age is in vehicle time (newest event minus newest
GNSS fix with a position), the mode is the navigator's.
"""

from __future__ import annotations

import asyncio
import logging
import time

log = logging.getLogger("companion.status")


def _nav_mode(runtime) -> str:
    for stage in runtime.pipeline.stages:
        if type(stage).__name__ == "Navigator":
            mode = stage.metadata().get("mode")
            if mode:
                return str(mode)
    return "-"


class StatusReporter:
    def __init__(self, runtime, every_s: float = 30.0):
        self.runtime = runtime
        self.every_s = every_s
        self._last = self._snapshot()

    def _snapshot(self):
        rt = self.runtime
        st = rt.pipeline.stats
        imu = {k: v for k, v in st.counts.items() if k.startswith("ImuSample[")}
        return (time.monotonic(), rt.link.messages_in, st.gnss_fixes, imu, getattr(rt.injector, "built", 0))

    def line(self) -> str:
        now = self._snapshot()
        (t0, m0, g0, i0, b0), (t1, m1, g1, i1, b1) = self._last, now
        self._last = now
        dt = max(t1 - t0, 1e-6)
        st = self.runtime.pipeline.stats
        parts = [f"{(m1 - m0) / dt:.0f} msg/s in", f"GNSS {(g1 - g0) / dt:.1f} Hz"]
        for k in sorted(i1):
            parts.append(f"IMU{k[len('ImuSample['):-1]} {(i1[k] - i0.get(k, 0)) / dt:.1f} Hz")
        parts.append(f"nav {_nav_mode(self.runtime)}")
        last_fix = st._fixes.last_s
        if last_fix is None or st.last_s is None:
            parts.append("no fix yet")
        else:
            parts.append(f"last fix {max(0.0, st.last_s - last_fix):.1f} s ago")
        parts.append(f"GPS_INPUT {(b1 - b0) / dt:.1f}/s ({self.runtime.config.inject.mode})")
        return "status: " + ", ".join(parts)

    async def run(self) -> None:
        while True:
            await asyncio.sleep(self.every_s)
            try:
                log.info(self.line())
            except Exception:  # noqa: BLE001 - a status line must never stop the service
                log.debug("status line failed", exc_info=True)


async def run_with_status(runtime, duration_s: float | None, every_s: float):
    """``runtime.run(duration_s)`` with a status line every ``every_s`` s (0: none)."""
    task = asyncio.ensure_future(StatusReporter(runtime, every_s).run()) if every_s > 0 else None
    try:
        return await runtime.run(duration_s)
    finally:
        if task is not None:
            task.cancel()
