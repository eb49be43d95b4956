"""GPS_INPUT (common.xml, message 232) on the wire: the record the injector builds -> the pymavlink message and back,
GPS time of week (:func:`companion.gpstime.gps_week_from_unix`), and the ignore flags, all from the dialect (companion.mavlink.dialect)."""

from __future__ import annotations

from typing import Any

from companion import units
from companion.gpstime import gps_week_from_unix
from companion.mavlink.dialect import mavlink

IGNORE_ALT = mavlink.GPS_INPUT_IGNORE_FLAG_ALT
IGNORE_HDOP = mavlink.GPS_INPUT_IGNORE_FLAG_HDOP
IGNORE_VDOP = mavlink.GPS_INPUT_IGNORE_FLAG_VDOP
IGNORE_VEL_HORIZ = mavlink.GPS_INPUT_IGNORE_FLAG_VEL_HORIZ
IGNORE_VEL_VERT = mavlink.GPS_INPUT_IGNORE_FLAG_VEL_VERT
IGNORE_SPEED_ACCURACY = mavlink.GPS_INPUT_IGNORE_FLAG_SPEED_ACCURACY
IGNORE_HORIZONTAL_ACCURACY = mavlink.GPS_INPUT_IGNORE_FLAG_HORIZONTAL_ACCURACY
IGNORE_VERTICAL_ACCURACY = mavlink.GPS_INPUT_IGNORE_FLAG_VERTICAL_ACCURACY


def encode_gps_input(rec):
    """The pymavlink GPS_INPUT message for a record (companion.inject.gps_input.GpsInputRecord); scaled integers through :mod:`companion.units`."""
    lat, lon = units.degE7_from_deg(rec.lat_deg), units.degE7_from_deg(rec.lon_deg)
    if lat == 0 and lon == 0:
        raise ValueError("refusing to encode lat = lon = 0")
    return mavlink.MAVLink_gps_input_message(
        rec.time_boot_us, rec.gps_id, rec.ignore_flags, rec.time_week_ms, rec.time_week, rec.fix_type,
        lat, lon, rec.alt_msl_m, rec.hdop, rec.vdop, rec.vel_n_mps, rec.vel_e_mps, rec.vel_d_mps,
        rec.speed_acc_mps, rec.h_acc_m, rec.v_acc_m, rec.satellites, rec.yaw_cdeg,
    )


def decode_gps_input(msg) -> dict[str, Any]:
    """A received GPS_INPUT in SI (for the vehicle simulator and tests)."""
    return {
        "time_boot_us": int(msg.time_usec),
        "gps_id": int(msg.gps_id),
        "ignore_flags": int(msg.ignore_flags),
        "time_week": int(msg.time_week),
        "time_week_ms": int(msg.time_week_ms),
        "fix_type": int(msg.fix_type),
        "lat_deg": units.deg_from_degE7(msg.lat),
        "lon_deg": units.deg_from_degE7(msg.lon),
        "alt_msl_m": float(msg.alt),
        "hdop": float(msg.hdop),
        "vdop": float(msg.vdop),
        "vel_ned_mps": (float(msg.vn), float(msg.ve), float(msg.vd)),
        "speed_acc_mps": float(msg.speed_accuracy),
        "h_acc_m": float(msg.horiz_accuracy),
        "v_acc_m": float(msg.vert_accuracy),
        "satellites": int(msg.satellites_visible),
        "yaw_cdeg": int(msg.yaw),
    }
