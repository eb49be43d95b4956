"""Everything that knows MAVLink (pymavlink): link addressing, byte transports, the autopilot link manager, the
MAVLink and dataflash decoders, the gravimeter's NAMED_VALUE_FLOAT and the GPS_INPUT wire encoding.

The rest of the package sees only :mod:`companion.events` in SI units."""
