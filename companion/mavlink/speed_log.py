"""A vessel's speed log on the MAVLink link: its speed through the water as NAMED_VALUE_FLOAT of a configured name (m/s).

ArduPilot has no water-speed sensor of its own; a log (paddle wheel, electromagnetic or Doppler) speaks as its own
component of the vehicle, or through a Lua script's ``gcs:send_named_float(NAME, mps)``. `NamedValueSpeedLogDecoder`
is one handler of companion.mavlink.decode.MavlinkDecoder, which puts each value on the vehicle clock. The boat's
air-data reference (companion.gravity.air_data_stage) takes it where a fixed wing takes its airspeed: on ArduRover
VFR_HUD.airspeed is the GPS's ground speed, in an outage the companion's own fixes, which must not feed back.
"""

from __future__ import annotations

import math

from companion.events import WaterSpeed
from companion.mavlink.gravimeter import named_float

#: beyond this (m/s) a value is corrupt (the fastest craft a log is fitted to are below 60 m/s)
MAX_SPEED_MPS = 100.0


class NamedValueSpeedLogDecoder:
    """NAMED_VALUE_FLOAT(name == `name`) -> WaterSpeed; a non-finite, negative or implausible value is dropped."""

    def __init__(self, name: str) -> None:
        if not name or len(name) > 10:
            raise ValueError("NAMED_VALUE_FLOAT names are 1-10 characters")
        self.name = name
        self.dropped = 0

    def value(self, msg) -> float | None:
        """The speed (m/s) if ``msg`` is a NAMED_VALUE_FLOAT of this name with a plausible value, else None."""
        v = named_float(msg, self.name)
        if v is None:
            return None
        if not (math.isfinite(v) and 0.0 <= v <= MAX_SPEED_MPS):
            self.dropped += 1
            return None
        return v

    def reading(self, t_s: float, speed_mps: float) -> WaterSpeed:
        return WaterSpeed(t_s=float(t_s), speed_mps=float(speed_mps))
