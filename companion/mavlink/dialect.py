"""The MAVLink dialect every module speaks (ArduPilot's, MAVLink 2): one place that names it.

Enum values (MAV_TYPE_*, GPS_FIX_TYPE_*, GPS_INPUT_IGNORE_FLAG_*, ...) are taken from here, never re-declared."""

from pymavlink.dialects.v20 import ardupilotmega as mavlink

__all__ = ["mavlink"]
