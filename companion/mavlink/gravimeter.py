"""A gravimeter on the MAVLink link: its readings as NAMED_VALUE_FLOAT of a configured name (mGal).

E.g. an ArduPilot Lua script calling ``gcs:send_named_float("GRAV", mgal)``, or a gravimeter sending as its own
component of the vehicle. `NamedValueGravityDecoder` is one handler of companion.mavlink.decode.MavlinkDecoder,
which puts each reading on the vehicle clock; it accepts the message from any component of the autopilot's system.
"""

from __future__ import annotations

import math

from companion.events import GravityReading

DEFAULT_NAMED_VALUE = "GRAV"  # NAMED_VALUE_FLOAT.name is at most 10 characters


def named_float(msg, name: str) -> float | None:
    """The value of ``msg`` if it is a NAMED_VALUE_FLOAT called ``name`` (its NUL padding aside), else None. A
    sensor's own plausibility test is the caller's."""
    if msg is None or msg.get_type() != "NAMED_VALUE_FLOAT":
        return None
    got = msg.name.decode("ascii", "ignore") if isinstance(msg.name, bytes) else str(msg.name)
    return float(msg.value) if got.rstrip("\x00").strip() == name else None


class NamedValueGravityDecoder:
    """NAMED_VALUE_FLOAT(name == `name`) -> GravityReading; time from time_boot_ms (s), else the receive time."""

    def __init__(self, name: str = DEFAULT_NAMED_VALUE, sigma_mgal: float | None = None, eotvos_corrected: bool = True):
        if not name or len(name) > 10:
            raise ValueError("NAMED_VALUE_FLOAT names are 1-10 characters")
        self.name = name
        self.sigma_mgal = sigma_mgal
        self.eotvos_corrected = bool(eotvos_corrected)  # False: the readings still hold the Eotvos term

    def value(self, msg) -> float | None:
        """The reading (mGal) if ``msg`` is a NAMED_VALUE_FLOAT of this name with a finite value, else None."""
        v = named_float(msg, self.name)
        return v if v is not None and math.isfinite(v) else None

    def reading(self, t_s: float, value_mgal: float) -> GravityReading:
        return GravityReading(t_s=float(t_s), gravity_mgal=value_mgal, sigma_mgal=self.sigma_mgal,
                              eotvos_corrected=self.eotvos_corrected, sensor=f"mavlink:{self.name}")

    def decode(self, msg, recv_s: float | None = None) -> GravityReading | None:
        """Standalone use: time = time_boot_ms (s), else the receive time. (On a live link the MavlinkDecoder puts
        the reading on its vehicle clock instead.)"""
        v = self.value(msg)
        if v is None:
            return None
        t = msg.time_boot_ms / 1000.0 if getattr(msg, "time_boot_ms", 0) else recv_s
        return None if t is None else self.reading(t, v)
