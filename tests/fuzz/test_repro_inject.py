"""Reproducers: what the decoder calls a fix and what the injector checks against the receiver (in-process, on the
project's simulated flight decoded as a live link would decode it)."""

from __future__ import annotations

import bisect
import math
from dataclasses import replace

import pytest



def _decoded_flight(gnss_hz: float = 10.0):
    """Events of a simulated flight (10 Hz receiver), through the live link's MAVLink decoder."""
    from companion.sim.flight import SimConfig, sample_profile, simulate_flight
    from companion.sim.playback import playback_from_flight
    from companion.mavlink.decode import MavlinkDecoder

    flight = simulate_flight(sample_profile(), 7, replace(SimConfig(), gnss_rate_hz=gnss_hz))
    dec = MavlinkDecoder()
    for it in playback_from_flight(flight).items:
        if it.msg.get_type() in ("GLOBAL_POSITION_INT", "SCALED_IMU2"):
            continue
        yield from dec.decode(it.msg, it.play_s)


def test_every_state_is_cross_checked_against_a_recent_receiver_fix():
    from companion.events import GnssFix
    from companion.nav.frame import LocalFrame
    from companion.inject.gps_input import GpsInputRecord, InjectConfig, Injector
    from companion.pipeline import build_pipeline

    t0, t1, shift_m = 60.0, 75.0, 300.0  # the receiver jumps 300 m north (a glitch the navigator's gate refuses)
    cfg = InjectConfig(mode="shadow")
    inj = Injector(cfg)
    pipe = build_pipeline(None, extra_stages=[inj])
    built: list[GpsInputRecord] = []
    process = inj.process
    inj.process = lambda item: [*_keep(process(item), built)]
    fixes: list[GnssFix] = []
    for ev in _decoded_flight():
        if isinstance(ev, GnssFix) and ev.has_position:
            if t0 <= ev.t_s < t1:
                ev = replace(ev, lat_deg=ev.lat_deg + shift_m / 111_111.0)
            fixes.append(ev)
        pipe.process(ev)
    pipe.finish()
    ft = [f.t_s for f in fixes]
    bad = []
    for r in built:
        i = bisect.bisect_right(ft, r.t_s + 0.05)  # the newest fix the injector could have seen
        f = fixes[i - 1] if i else None
        if f is None or r.t_s - f.t_s > cfg.consistency_window_s or f.fix_type < 3:
            continue
        n, e, _ = LocalFrame(f.lat_deg, f.lon_deg, 0.0).to_ned_m(r.lat_deg, r.lon_deg, 0.0)
        d = math.hypot(float(n), float(e))
        rx = f.h_acc_m or (f.hdop or 1.0) * cfg.uere_m
        if d * d > cfg.consistency_chi2 * (r.h_acc_m**2 + rx**2) + (math.hypot(r.vel_n_mps, r.vel_e_mps) * 0.2) ** 2 + 1:
            bad.append((r.t_s, d, r.h_acc_m))
    assert len(built) > 1000
    assert float(inj.metadata()["cross_check.fraction"]) > 0.99  # every state met a fix within the window
    assert len(bad) <= 2, (f"{len(bad)} GPS_INPUT built while {bad[0][1]:.0f} m from a fresh 3D receiver fix (claiming "
                     f"{bad[0][2]:.1f} m), first at {bad[0][0]:.1f} s")


def _keep(outs, into):
    from companion.inject.gps_input import GpsInputRecord

    into.extend(o for o in outs if isinstance(o, GpsInputRecord))
    return outs


@pytest.mark.parametrize("field,value", [("lat", 900000000), ("lat", -900000000), ("lon", 1800000000),
                                         ("lon", -1800000000), ("alt", 2147483647), ("alt", -2147483648)])
def test_gps_raw_int_at_the_limits_is_not_a_fix(field, value):
    from pymavlink.dialects.v20 import ardupilotmega as mav

    from companion.events import GnssFix
    from companion.mavlink.decode import MavlinkDecoder

    packer = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    parser = mav.MAVLink(None)
    dec = MavlinkDecoder()

    def feed(msg, t):
        return [e for m in parser.parse_buffer(bytes(msg.pack(packer))) or [] for e in dec.decode(m, t)]

    feed(mav.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3), 0.0)
    feed(mav.MAVLink_attitude_message(1000, 0, 0, 0, 0, 0, 0), 1.0)
    good = dict(time_usec=1_100_000, fix_type=3, lat=-353600000, lon=1491650000, alt=600000, eph=80, epv=120, vel=0,
                cog=0, satellites_visible=12)
    ok = [e for e in feed(mav.MAVLink_gps_raw_int_message(**good), 1.1) if isinstance(e, GnssFix)]
    assert ok and ok[0].has_position  # the plain fix is one
    bad = dict(good, time_usec=1_200_000, **{field: value})
    got = [e for e in feed(mav.MAVLink_gps_raw_int_message(**bad), 1.2) if isinstance(e, GnssFix)]
    assert not any(e.has_position and e.fix_type >= 3 for e in got), f"{field} = {value}: {got}"
