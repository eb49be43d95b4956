"""The navigator's mode: INS when the IMU is fast enough and an attitude initialises it, else the kinematic
constant-velocity fallback (see companion.nav.navigator); every change a ModeChange."""

from __future__ import annotations

from collections import deque

from companion.nav.config import NavigatorConfig
from companion.nav.outputs import ModeChange


class ModeSelector:
    """The mode, why, and the IMU rate it is judged on. ``note_imu`` for every IMU sample of the navigator's IMU;
    ``choose`` at every fix says which mode the stream calls for, ``switch`` records it."""

    def __init__(self, config: NavigatorConfig) -> None:
        self.config = config
        self.mode = "init"
        self.reason = "waiting for the first GNSS fix"
        self._key = "init"
        self._imu_times: deque[float] = deque()

    def note_imu(self, t: float) -> None:
        self._imu_times.append(t)

    def imu_rate_hz(self, t: float) -> float:
        """IMU samples per second over the last ``rate_window_s``."""
        w = self.config.rate_window_s
        while self._imu_times and self._imu_times[0] < t - w:
            self._imu_times.popleft()
        return len(self._imu_times) / w

    def choose(self, t: float, t0: float | None, last_imu_t: float | None,
               have_attitude: bool) -> tuple[str, str, str] | None:
        """(mode, reason, kind of reason) the stream calls for at time t, or None to stay: too little of the stream
        seen to measure the IMU rate, or an INS whose IMU is alive. ("ins", ...) from any other mode means: start it."""
        c = self.config
        if t0 is not None and t - t0 < c.rate_window_s and self.mode == "init":
            return None  # not enough stream seen to measure the IMU rate yet
        rate = self.imu_rate_hz(t)
        imu_alive = last_imu_t is not None and t - last_imu_t < c.imu_timeout_s
        if self.mode == "ins":
            if not imu_alive:
                return "kinematic", f"IMU{c.imu_index} stream stopped for > {c.imu_timeout_s:g} s", "imu_stopped"
            return None
        model = "kinematic hold / constant-velocity IMM" if c.kinematic_hold_cv else "kinematic constant-velocity model"
        if not imu_alive or last_imu_t is None:
            key = "no_imu" if last_imu_t is None else "imu_stopped"
            reason = f"no IMU{c.imu_index} samples in the source: {model}"
            if key == "imu_stopped":
                reason = f"IMU{c.imu_index} stream stopped for > {c.imu_timeout_s:g} s: {model}"
        elif rate < c.min_imu_rate_hz:
            key = "low_rate"
            # no rate in the text: the summary's IMU rate line is the one measure of the stream's rate (this window's
            # count is in ModeChange.imu_rate_hz, at the time of the decision)
            reason = (
                f"IMU{c.imu_index} slower than the {c.min_imu_rate_hz:g} Hz strapdown mechanisation needs: {model}"
            )
        elif not have_attitude:
            key = "no_attitude"
            reason = f"no attitude source to initialise the INS: {model}"
        else:
            return "ins", f"strapdown INS on IMU{c.imu_index} + error-state KF", "ins"
        return "kinematic", reason, key

    def switch(self, t: float, mode: str, reason: str, key: str) -> ModeChange | None:
        """Take the mode; a ModeChange when the mode or the kind of reason changed."""
        if mode == self.mode and key == self._key:
            return None
        self.mode, self.reason, self._key = mode, reason, key
        return ModeChange(t, mode, reason, self.imu_rate_hz(t))
