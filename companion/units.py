"""MAVLink scaled integers <-> SI. The only place degE7, cm, mm, mG, mrad/s and cdeg are known.

Decoders take the integer field as it arrives on the wire; encoders round to the nearest integer the
wire can carry (encode(decode(x)) == x for every integer x, tested against pymavlink-packed messages).
"""

from __future__ import annotations

from companion.constants import G0_MPS2

#: ArduPilot's GRAVITY_MSS, used by RAW_IMU/SCALED_IMU to express acceleration in mG.
STANDARD_GRAVITY_MPS2 = G0_MPS2



def deg_from_degE7(v: int) -> float:
    return v * 1e-7


def degE7_from_deg(deg: float) -> int:
    return int(round(deg * 1e7))


def m_from_cm(v: int) -> float:
    return v * 0.01


def cm_from_m(m: float) -> int:
    return int(round(m * 100.0))


def m_from_mm(v: int) -> float:
    return v * 0.001


def mm_from_m(m: float) -> int:
    return int(round(m * 1000.0))


def mps2_from_mG(v: int) -> float:
    return v * 0.001 * STANDARD_GRAVITY_MPS2


def mG_from_mps2(a: float) -> int:
    return int(round(a / STANDARD_GRAVITY_MPS2 * 1000.0))


def radps_from_mradps(v: int) -> float:
    return v * 0.001


def mradps_from_radps(w: float) -> int:
    return int(round(w * 1000.0))


def deg_from_cdeg(v: int) -> float:
    return v * 0.01


def cdeg_from_deg(deg: float) -> int:
    return int(round(deg * 100.0))


def s_from_ms(v: int) -> float:
    return v * 1e-3


def s_from_us(v: int) -> float:
    return v * 1e-6


def us_from_s(t: float) -> int:
    return int(round(t * 1e6))


def ms_from_s(t: float) -> int:
    return int(round(t * 1e3))
