"""Physical and convention constants, one home for each: standard gravity, WGS84, chi-square gates, GPS time.

Also the receiver's 1-sigma position error from what it reports (:func:`receiver_sigma`). Pure: no I/O.
"""

from __future__ import annotations

#: Standard gravity (CGPM 1901), m/s^2: the unit of the accelerometer's "g" and of MAVLink's mG.
G0_MPS2 = 9.80665

#: WGS84 ellipsoid: semi-major axis, flattening, first eccentricity squared, Earth rotation rate.
WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
EARTH_RATE_RADPS = 7.2921150e-5

#: 99.9 % quantiles of the chi-square distribution with 1, 2 and 3 degrees of freedom (innovation gates).
CHI2_1DOF_999 = 10.828
CHI2_2DOF_999 = 13.816
CHI2_3DOF_999 = 16.266

#: GPS epoch 1980-01-06T00:00:00Z as a Unix time; GPS time = UTC + the leap seconds since (companion.gpstime).
GPS_EPOCH_UNIX_S = 315964800
WEEK_S = 604800

#: Assumed 1-sigma user range error when a receiver gives only DOPs (typical single-frequency u-blox).
UERE_M = 2.5


def receiver_sigma(fix, uere_m: float = UERE_M, uere_v_m: float | None = None) -> tuple[float | None, float | None]:
    """The receiver's own 1-sigma (horizontal, vertical) position error in metres from a GnssFix.

    Its reported accuracy (h_acc / v_acc) when it gives one (> 0), else its DOP times the user range error
    (``uere_m`` horizontally, ``uere_v_m`` vertically, default the same); None where it says neither."""
    uv = uere_m if uere_v_m is None else uere_v_m
    h = fix.h_acc_m if fix.h_acc_m is not None and fix.h_acc_m > 0 else (
        fix.hdop * uere_m if fix.hdop is not None and fix.hdop > 0 else None)
    v = fix.v_acc_m if fix.v_acc_m is not None and fix.v_acc_m > 0 else (
        fix.vdop * uv if fix.vdop is not None and fix.vdop > 0 else None)
    return h, v
