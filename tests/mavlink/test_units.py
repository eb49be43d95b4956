"""Scaled MAVLink integers round-trip through the SI events, against pymavlink-packed messages."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion import units
from companion.events import GnssFix, ImuSample, MagField
from companion.mavlink.decode import MavlinkDecoder


def _wire(msg, mav=None):
    """Pack with pymavlink, parse the bytes back: exactly what arrives on a link."""
    mav = mav or mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    buf = msg.pack(mav)
    parser = mavlink.MAVLink(None)
    return parser.decode(bytearray(buf))


def _decoder():
    dec = MavlinkDecoder()
    hb = _wire(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 0, 3))
    dec.decode(hb, 0.0)
    return dec


@pytest.mark.parametrize("seed", range(5))
def test_gps_raw_int_roundtrip_degE7_mm_cm_cdeg(seed):
    rng = np.random.default_rng(seed)
    lat = int(rng.integers(-900_000_000, 900_000_000))
    lon = int(rng.integers(-1_800_000_000, 1_800_000_000))
    alt = int(rng.integers(-400_000, 9_000_000))
    vel = int(rng.integers(0, 6000))
    cog = int(rng.integers(0, 35999))
    h_acc, v_acc, vel_acc = (int(x) for x in rng.integers(1, 100000, 3))
    msg = _wire(
        mavlink.MAVLink_gps_raw_int_message(
            123_456_000, 3, lat, lon, alt, 120, 180, vel, cog, 11, 0, h_acc, v_acc, vel_acc, 0, 0
        )
    )
    (fix,) = _decoder().decode(msg, 1.0)
    assert isinstance(fix, GnssFix)
    assert fix.t_s == pytest.approx(123.456)
    assert units.degE7_from_deg(fix.lat_deg) == lat
    assert units.degE7_from_deg(fix.lon_deg) == lon
    assert units.mm_from_m(fix.alt_msl_m) == alt
    assert units.cm_from_m(fix.ground_speed_mps) == vel
    assert units.cdeg_from_deg(fix.course_deg) == cog
    assert units.mm_from_m(fix.h_acc_m) == h_acc
    assert units.mm_from_m(fix.v_acc_m) == v_acc
    assert units.mm_from_m(fix.speed_acc_mps) == vel_acc
    assert fix.hdop == pytest.approx(1.2) and fix.vdop == pytest.approx(1.8)
    assert math.hypot(fix.vel_n_mps, fix.vel_e_mps) == pytest.approx(vel / 100.0)


@pytest.mark.parametrize("mtype", ["RAW_IMU", "SCALED_IMU2", "SCALED_IMU3"])
def test_imu_roundtrip_mG_mradps(mtype):
    rng = np.random.default_rng(7)
    acc = [int(x) for x in rng.integers(-16000, 16000, 3)]
    gyr = [int(x) for x in rng.integers(-30000, 30000, 3)]
    if mtype == "RAW_IMU":
        m = mavlink.MAVLink_raw_imu_message(5_000_000, *acc, *gyr, 1, 2, 3)
    else:
        cls = getattr(mavlink, f"MAVLink_{mtype.lower()}_message")
        m = cls(5000, *acc, *gyr, 1, 2, 3)
    imu, *rest = _decoder().decode(_wire(m), 1.0)
    assert isinstance(imu, ImuSample)
    if mtype == "RAW_IMU":  # its compass field (mGauss) as a MagField at the same time
        (mag,) = rest
        assert isinstance(mag, MagField) and mag.t_s == imu.t_s
        assert [round(v * 1e3) for v in mag.field_frd_gauss] == [1, 2, 3]
    else:
        assert rest == []
    assert imu.t_s == pytest.approx(5.0)
    assert imu.imu_index == {"RAW_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2}[mtype]
    assert [units.mG_from_mps2(a) for a in imu.accel_frd_mps2] == acc
    assert [units.mradps_from_radps(w) for w in imu.gyro_frd_radps] == gyr
    # 1000 mG is one standard gravity
    assert units.mps2_from_mG(1000) == pytest.approx(9.80665)


@pytest.mark.parametrize(
    "enc,dec,values",
    [
        (units.degE7_from_deg, units.deg_from_degE7, [0, 1, -1, 900_000_000, -1_800_000_000, 1_234_567_891]),
        (units.cm_from_m, units.m_from_cm, [0, 1, -1, 65535, -32768]),
        (units.mm_from_m, units.m_from_mm, [0, 1, -1, 2_147_483_647, -2_147_483_648]),
        (units.mG_from_mps2, units.mps2_from_mG, [0, 1, -1, 32767, -32768]),
        (units.mradps_from_radps, units.radps_from_mradps, [0, 1, -1, 32767, -32768]),
        (units.cdeg_from_deg, units.deg_from_cdeg, [0, 1, 35999, 36000]),
    ],
)
def test_integer_roundtrip_edges(enc, dec, values):
    for v in values:
        assert enc(dec(v)) == v


def test_gps_without_fix_or_at_zero_carries_no_position():
    dec = _decoder()
    nofix = _wire(mavlink.MAVLink_gps_raw_int_message(1_000_000, 1, 0, 0, 0, 9999, 9999, 0, 0, 0))
    zero3d = _wire(mavlink.MAVLink_gps_raw_int_message(2_000_000, 3, 0, 0, 0, 120, 180, 0, 0, 8))
    (a,) = dec.decode(nofix, 1.0)
    (b,) = dec.decode(zero3d, 2.0)
    for fix in (a, b):
        assert not fix.has_position and fix.lat_deg is None and fix.lon_deg is None
    assert b.fix_type == 1  # a 3D "fix" at 0,0 is reported as no fix


@pytest.mark.parametrize("field", ["xacc", "zacc", "xgyro", "zgyro"])
@pytest.mark.parametrize("limit", [32767, -32768])
def test_imu_field_at_int16_limit_is_dropped_not_read(field, limit):
    """A clamped field is not a 32.8 g reading: integrated once, it put the INS 6 m/s off."""
    vals = dict(xacc=10, yacc=-20, zacc=-1000, xgyro=1, ygyro=2, zgyro=3)
    vals[field] = limit
    dec = _decoder()
    m = mavlink.MAVLink_raw_imu_message(5_000_000, *vals.values(), 1, 2, 3)
    assert dec.decode(_wire(m), 1.0) == []
    assert dec.dropped["RAW_IMU clamped (a field at its int16 limit)"] == 1
    vals[field] = limit - 1 if limit > 0 else limit + 1  # one count inside is a reading
    imu = dec.decode(_wire(mavlink.MAVLink_raw_imu_message(5_020_000, *vals.values(), 1, 2, 3)), 1.02)[0]
    assert isinstance(imu, ImuSample)


@pytest.mark.parametrize("roll,pitch,yaw,ok", [(0.1, 0.2, 3.1, True), (-3.14159, -1.5707, 6.28, True),
                                                (0.0, 1e22, 0.0, False), (4.0, 0.0, 0.0, False),
                                                (0.0, 1.7, 0.0, False), (0.0, 0.0, -7.0, False)])
def test_attitude_out_of_range_is_dropped(roll, pitch, yaw, ok):
    dec = _decoder()
    out = dec.decode(_wire(mavlink.MAVLink_attitude_message(5000, roll, pitch, yaw, 0.0, 0.0, 0.0)), 1.0)
    assert (len(out) == 1) == ok
    assert dec.dropped["ATTITUDE out of range"] == (0 if ok else 1)


@pytest.mark.parametrize("seed", range(3))
def test_global_position_int_roundtrip_is_the_autopilots_position(seed):
    from companion.events import AutopilotAltitude, AutopilotPosition

    rng = np.random.default_rng(seed)
    lat, lon = int(rng.integers(-900_000_000, 900_000_000)), int(rng.integers(-1_800_000_000, 1_800_000_000))
    alt = int(rng.integers(-400_000, 9_000_000))
    dec = _decoder()
    msg = _wire(mavlink.MAVLink_global_position_int_message(50_000, lat, lon, alt, 1000, 10, -20, 5, 9000))
    altitude, pos = dec.decode(msg, 1.0)
    assert isinstance(altitude, AutopilotAltitude) and isinstance(pos, AutopilotPosition)
    assert pos.t_s == altitude.t_s == pytest.approx(50.0) and pos.source == "GLOBAL_POSITION_INT"
    assert (units.degE7_from_deg(pos.lat_deg), units.degE7_from_deg(pos.lon_deg), units.mm_from_m(pos.alt_msl_m)) == (
        lat, lon, alt)
    # no position yet (an EKF without origin sends 0, 0): the altitude only
    none_yet = _wire(mavlink.MAVLink_global_position_int_message(50_100, 0, 0, alt, 1000, 0, 0, 0, 9000))
    assert [type(e) for e in dec.decode(none_yet, 1.1)] == [AutopilotAltitude]


def test_dataflash_pos_is_the_autopilots_position():
    from companion.events import AutopilotPosition
    from companion.mavlink.dataflash import DataflashDecoder, _Row

    dec = DataflashDecoder()
    (pos,) = dec.decode(_Row("POS", {"TimeUS": 12_500_000, "Lat": 47.3977419, "Lng": 8.5455938, "Alt": 488.2,
                                     "RelHomeAlt": 0.1, "RelOriginAlt": 0.1}))
    assert pos == AutopilotPosition(t_s=12.5, lat_deg=47.3977419, lon_deg=8.5455938, alt_msl_m=488.2, source="POS")
    assert dec.decode(_Row("POS", {"TimeUS": 12_600_000, "Lat": 0.0, "Lng": 0.0, "Alt": 0.0})) == []  # none yet
    assert dec.decode(_Row("POS", {"TimeUS": 12_700_000, "Lat": 95.0, "Lng": 8.5, "Alt": 488.0})) == []
    assert dec.dropped == {"POS position out of range": 1}


def test_highres_imu_is_an_imu_of_its_own_in_floats():
    """HIGHRES_IMU (floats: a rate of 0.4 mrad/s, which RAW_IMU's int16 mrad/s truncates to 0) arrives as IMU index 3,
    never mixed with RAW_IMU's index 0; a non-finite field drops the sample."""
    m = mavlink.MAVLink_highres_imu_message(5_000_000, 0.1, -0.2, -9.8, 0.0004, -0.0012, 0.25, 0, 0, 0, 1000.0, 0, 0,
                                            20.0, 0x3F, 0)
    dec = _decoder()
    (imu,) = dec.decode(_wire(m), 1.0)
    assert isinstance(imu, ImuSample) and imu.imu_index == 3 and imu.t_s == pytest.approx(5.0)
    assert imu.gyro_frd_radps == pytest.approx((0.0004, -0.0012, 0.25), rel=1e-6)
    assert imu.accel_frd_mps2 == pytest.approx((0.1, -0.2, -9.8), rel=1e-6)
    bad = mavlink.MAVLink_highres_imu_message(5_100_000, math.nan, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0x3F, 0)
    assert dec.decode(_wire(bad), 1.1) == []
    assert dec.dropped["HIGHRES_IMU non-finite"] == 1
