"""The navigator's mode logic: INS when the IMU is fast enough and an attitude initialises it, else the kinematic
constant-velocity fallback (see companion.nav.navigator); every change a ModeChange. A mixin of
companion.nav.navigator.Navigator (its state lives on the navigator)."""

from __future__ import annotations

from companion.events import GnssFix
from companion.nav.outputs import ModeChange


class Modes:
    """Mixin: choose and switch the navigator's mode."""

    def _set_mode(self, t: float, mode: str, reason: str, key: str) -> None:
        """Switch mode; a ModeChange is emitted when the mode or the kind of reason changes."""
        if mode != self.mode or key != self._reason_key:
            self.mode, self.mode_reason, self._reason_key = mode, reason, key
            self._out.append(ModeChange(t, mode, reason, self._imu_rate(t)))

    def _imu_rate(self, t: float) -> float:
        w = self.config.rate_window_s
        while self._imu_times and self._imu_times[0] < t - w:
            self._imu_times.popleft()
        return len(self._imu_times) / w

    def _update_mode(self, t: float, ev: GnssFix, z, vel) -> None:
        c = self.config
        if self._t0 is not None and t - self._t0 < c.rate_window_s and self.mode == "init":
            return  # not enough stream seen to measure the IMU rate yet
        rate = self._imu_rate(t)
        imu_alive = self._last_imu_t is not None and t - self._last_imu_t < c.imu_timeout_s
        if self.mode == "ins":
            if not imu_alive:
                self._set_mode(
                    t, "kinematic", f"IMU{c.imu_index} stream stopped for > {c.imu_timeout_s:g} s", "imu_stopped"
                )
                self.ins = None
            return
        model = "kinematic hold / constant-velocity IMM" if c.kinematic_hold_cv else "kinematic constant-velocity model"
        if not imu_alive or self._last_imu_t is None:
            key = "no_imu" if self._last_imu_t is None else "imu_stopped"
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
        elif self._att is None:
            key = "no_attitude"
            reason = f"no attitude source to initialise the INS: {model}"
        else:
            self._ins_init(t, z, vel)
            self._set_mode(t, "ins", f"strapdown INS on IMU{c.imu_index} + error-state KF", "ins")
            return
        self._set_mode(t, "kinematic", reason, key)
