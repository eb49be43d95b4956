"""GPS_INPUT injection: the fused solution encoded for ArduPilot's MAVLink GPS driver."""

from companion.inject.gps_input import (
    GpsInputRecord,
    InjectConfig,
    InjectorDrop,
    InjectorState,
    Injector,
    decode_gps_input,
    encode_gps_input,
    gps_week_from_unix,
)

__all__ = [
    "GpsInputRecord",
    "InjectConfig",
    "Injector",
    "InjectorDrop",
    "InjectorState",
    "decode_gps_input",
    "encode_gps_input",
    "gps_week_from_unix",
]
