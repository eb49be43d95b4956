"""What an ArduPilot does with the GPS_INPUT it receives, as far as the simulated vehicle models it.

Observed on ArduCopter SITL with the companion as a MAVLink GPS (``GPSn_TYPE = 14``, docs/ardupilot.md)
and read in ArduPilot's source:

* AP_GPS_MAV takes a GPS_INPUT only when ``gps_id`` is its own (zero-based) instance; the driver's status is the
  message's ``fix_type``;
* EKF3 never uses a GPS below a 3D fix: a 2D fix is ignored;
* arming needs a 3D fix on every configured GPS (AP_Arming's GPS check: "GPS %i: Bad fix", one-based), reported
  through ``check_failed`` as STATUSTEXT "PreArm: ..." (the periodic pre-arm check, every PREARM_DISPLAY_PERIOD = 30 s)
  or "Arm: ..." (an arming attempt), severity CRITICAL.

Modelled cheaply: the MAVLink instance's status at an arming attempt is the last GPS_INPUT for it, if at most
``ARM_FIX_MAX_AGE_S`` old (ArduPilot keeps the status until its 4 s GPS time-out, but a GPS sending below ~5 Hz is
already "not healthy"); every other configured GPS (the flight's own receiver) is taken as 3D. Pure: no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

#: an arming attempt needs the MAVLink instance's last GPS_INPUT at most this old (playback s) and 3D
ARM_FIX_MAX_AGE_S = 1.0
#: AP_Arming's PREARM_DISPLAY_PERIOD: a failing pre-arm check is reported this often (s)
PREARM_DISPLAY_PERIOD_S = 30.0
FIX_3D = 3


def ignored_by(gps_id: int, fix_type: int, mav_instance: int | None) -> str | None:
    """Why the autopilot would not use this GPS_INPUT (None: it may). ``mav_instance``: the GPS instance configured as
    MAVLink (None: unknown, the gps_id is not judged)."""
    if mav_instance is not None and gps_id != mav_instance:
        return f"by AP_GPS: gps_id {gps_id} is not the MAVLink GPS instance {mav_instance}"
    if fix_type < FIX_3D:
        return "by EKF3: fix_type < 3"
    return None


@dataclass
class ArmingCheck:
    """The GPS part of ArduPilot's arming check for one MAVLink GPS instance (zero-based, = GPS_INPUT.gps_id)."""

    instance: int
    last_fix: tuple[float, int] | None = None  # (playback s received, fix_type) of the last GPS_INPUT for the instance
    attempts: int = 0
    armed_at_s: float | None = None
    refused_at_s: float | None = None  # the first refusal
    _next_text_s: float = float("-inf")

    def on_gps_input(self, play_s: float, gps_id: int, fix_type: int) -> None:
        if gps_id == self.instance:
            self.last_fix = (play_s, int(fix_type))

    def failure(self, now_s: float) -> str:
        """Why arming fails now ("" when the GPS check passes)."""
        f = self.last_fix
        if f is None or now_s - f[0] > ARM_FIX_MAX_AGE_S or f[1] < FIX_3D:
            return f"GPS {self.instance + 1}: Bad fix"
        return ""

    def attempt(self, now_s: float) -> tuple[bool, str | None]:
        """One arming attempt: (armed, the STATUSTEXT to send or None). A refusal is reported at once and then every
        PREARM_DISPLAY_PERIOD_S as the periodic pre-arm check does; ArduPilot's "Arm: ..." answer to each arming
        command is left out (at one attempt a second it would repeat every second)."""
        self.attempts += 1
        why = self.failure(now_s)
        if not why:
            self.armed_at_s = now_s
            return True, None
        if self.refused_at_s is None:
            self.refused_at_s = now_s
        if now_s < self._next_text_s:
            return False, None
        self._next_text_s = now_s + PREARM_DISPLAY_PERIOD_S
        return False, f"PreArm: {why}"
