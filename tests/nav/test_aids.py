"""The navigator's aids alone (companion.nav.aids, baro): the measurement each builds from known inputs."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from companion.events import Attitude, GnssFix, PositionFix
from companion.nav.aids import (AttitudeAid, PredictorAid, ZeroVelocityAid, fix_sigmas,
                                position_fix_measurements)
from companion.nav.baro import BaroAid
from companion.nav.config import NavigatorConfig
from companion.nav.frame import LocalFrame
from companion.nav.ins import euler_from_quat
from companion.nav.measurements import AttitudeMeasurement, PositionMeasurement


def _fix(hdop=2.0, h_acc=None, v_acc=None):
    return GnssFix(0.0, 3, -35.0, 149.0, 600.0, 1.0, 2.0, None, None, None, 10, hdop, 3.0, h_acc, v_acc, None,
                   None, None)


def test_fix_sigmas_short_term_follow_hdop_and_the_gate_uses_the_accuracy():
    c = NavigatorConfig()
    assert fix_sigmas(_fix(hdop=2.0), c) == pytest.approx((0.6, 1.0, 2.0 * c.uere_h_m, 3.0 * c.uere_v_m))
    assert fix_sigmas(_fix(hdop=0.8, h_acc=1.2, v_acc=2.2), c)[:3] == pytest.approx((0.3, 0.5, 1.2))
    acc = NavigatorConfig(gnss_sigma_model="accuracy")
    assert fix_sigmas(_fix(hdop=0.8, h_acc=1.2, v_acc=2.2), acc) == pytest.approx((1.2, 2.2, 1.2, 2.2))


def test_predictor_points_share_their_fix_error():
    c = NavigatorConfig()
    aid = PredictorAid(c)
    assert aid.point(1.0, None) is None  # no fix yet
    for k in range(20):  # 1 Hz fixes of a vehicle flying north at 5 m/s
        aid.add_fix(float(k), (5.0 * k, 0.0, 0.0), 0.5, 0.8, (5.0, 0.0, 0.0))
    assert aid.point(19.0, 19.0) is None  # at the fix itself: no point
    sig = []
    for k in range(1, 4):
        p, m = aid.point(19.0 + 0.1 * k, 19.0)
        assert isinstance(m, PositionMeasurement) and m.z() == pytest.approx(np.asarray(p.ned_m))
        sig.append(m.sigma_h_m / p.sigma_h_m)
    assert p.ned_m[0] == pytest.approx(5.0 * 19.3, abs=0.2)
    assert sig == pytest.approx([2.0, 2.0 * math.sqrt(2), 2.0 * math.sqrt(3)])  # scale 2, k-th point x sqrt(k)
    aid.add_fix(20.0, (100.0, 0.0, 0.0), 0.5, 0.8, (5.0, 0.0, 0.0))
    p, m = aid.point(20.1, 20.0)
    assert m.sigma_h_m / p.sigma_h_m == pytest.approx(2.0)  # a new fix, a new count
    off = PredictorAid(NavigatorConfig(fuse_predictor=False))
    off.add_fix(0.0, (0.0, 0.0, 0.0), 0.5, 0.8, None)
    off.add_fix(1.0, (5.0, 0.0, 0.0), 0.5, 0.8, None)
    assert off.point(1.1, 1.0)[1] is None  # the point, not fused


def test_zero_velocity_in_a_hover_after_the_fix_is_old_and_at_its_interval():
    hover = SimpleNamespace(hovering=True)
    hover.hover = lambda t: hover.hovering
    aid = ZeroVelocityAid(NavigatorConfig(), hover)
    assert aid.measurement(10.0, None) is None and aid.measurement(11.0, 10.0) is None  # fix 1 s old < 1.5 s
    m = aid.measurement(11.5, 10.0)
    assert m is not None and m.kind == "zero_velocity" and m.z() == pytest.approx([0.0, 0.0, 0.0])
    assert aid.measurement(12.4, 10.0) is None and aid.measurement(12.5, 10.0) is not None  # every 1 s
    hover.hovering = False
    assert aid.measurement(14.0, 10.0) is None


def _check(consistent=True, offset=math.nan):
    return SimpleNamespace(consistent=consistent, offset_rad=offset,
                           fuse_heading=lambda: consistent and math.isfinite(offset), tilt_var_rad2=lambda: 4e-4)


def test_attitude_aid_fuses_the_autopilot_heading_only_once_confirmed():
    c = NavigatorConfig()
    ev = Attitude(5.0, 0.1, -0.05, 1.0)
    m = AttitudeAid(c, _check(offset=0.02)).measurement(ev, lambda: 0.3, 4.5)
    assert isinstance(m, AttitudeMeasurement) and m.var_rad2 == pytest.approx((4e-4, 4e-4, c.att_sigma_yaw_rad ** 2))
    roll, pitch, yaw = euler_from_quat(_quat_of(m.c_meas))
    assert (roll, pitch, yaw) == pytest.approx((0.1, -0.05, 1.0), abs=1e-9)
    m = AttitudeAid(c, _check()).measurement(ev, lambda: 0.3, 4.5)  # not yet confirmed: the INS's own heading
    assert euler_from_quat(_quat_of(m.c_meas))[2] == pytest.approx(0.3) and m.var_rad2[2] == 1e6


def test_attitude_aid_keeps_a_flagged_tilt_out_of_a_gnss_gap():
    c = NavigatorConfig()
    aid = AttitudeAid(c, _check(consistent=False, offset=1.5))
    ev = Attitude(10.0, 0.1, 0.0, 0.0)
    assert aid.measurement(ev, lambda: 0.0, 9.0) is not None  # GNSS 1 s ago: fused (with its inflated variance)
    assert aid.measurement(ev, lambda: 0.0, 8.0) is None  # 2 s without GNSS >= gnss_gap_s
    assert AttitudeAid(NavigatorConfig(fuse_flagged_tilt=False), aid.heading).measurement(ev, lambda: 0.0, 9.9) is None
    every = AttitudeAid(NavigatorConfig(att_fuse_interval_s=0.5), aid.heading)
    assert [every.due(t) for t in (0.0, 0.2, 0.5, 0.6, 1.0)] == [True, False, True, False, True]
    assert not AttitudeAid(NavigatorConfig(fuse_attitude=False), aid.heading).due(0.0)


def _quat_of(C):
    """Quaternion of a rotation matrix (for reading a measurement's Euler angles back)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(C).as_quat()
    return (w, x, y, z)


def test_position_fix_in_the_local_frame_with_its_own_velocity():
    frame = LocalFrame(-35.0, 149.0, 600.0)
    lat, lon, _ = frame.geodetic_tuple(120.0, -40.0, 0.0)
    m, mv = position_fix_measurements(PositionFix(1.0, lat, lon, 5.0, 7.0), frame, NavigatorConfig())
    assert m.z() == pytest.approx([120.0, -40.0], abs=1e-6) and mv is None
    m, mv = position_fix_measurements(PositionFix(1.0, lat, lon, 5.0, 7.0, "x", 2.0, -1.0, 0.3, 0.4), frame,
                                      NavigatorConfig())
    assert mv.z() == pytest.approx([2.0, -1.0]) and mv.kind == "velocity_fix"
    assert position_fix_measurements(PositionFix(1.0, lat, lon, math.nan, 7.0), frame, NavigatorConfig()) is None


def test_baro_aid_learns_the_offset_beside_gnss_and_then_measures_height():
    c = NavigatorConfig(fuse_autopilot_alt=True)
    baro = BaroAid(c)
    ref = 600.0
    assert baro.measurement(1.0, 700.0, 650.0, ref, None) is None  # never beside GNSS: datum unknown
    for k in range(100):  # the autopilot reads 12.3 m above our altitude while GNSS aids
        assert baro.measurement(float(k), 662.3 + 0.1 * k, 650.0 + 0.1 * k, ref, float(k)) is None
    assert baro.offset_m == pytest.approx(12.3)
    m = baro.measurement(105.0, 672.3, 0.0, ref, 99.0)  # GNSS gone > alt_gnss_gap_s: our altitude is 660 m
    assert m.z() == pytest.approx([ref - 660.0]) and np.ravel(m.R()) == pytest.approx([c.alt_sigma_m ** 2])
