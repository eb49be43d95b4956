"""Gravity sources (line protocol, NAMED_VALUE_FLOAT, UDP, simulated with placement) and the end-to-end chain:
GNSS withheld -> Navigator on IMU -> simulated gravimeter + Viterbi matcher -> fixes back into the Navigator."""

import asyncio

import numpy as np
import pytest

from companion.sim.circle import simulate_circle_flight
from companion.gravity.matchers.li_viterbi import ViterbiConfig, ViterbiMatcher
from companion.events import GravityReading, PositionFix
from companion.gravity.placement import Placement
from companion.mavlink.gravimeter import NamedValueGravityDecoder
from companion.sim.gravimeter import SimulatedGravimeter, SimulatedGravitySource
from companion.sources.gravity import UdpGravitySource, format_gravity_line, parse_gravity_line
from companion.gravity.stage import FixAcceptance, GravityMatchStage, gravity_replay_pipeline
from companion.pipeline.denial import DenialErrorStage, GnssDenial
from tests.helpers import Collect, bumpy_map


def test_line_protocol_round_trip_and_errors():
    r = parse_gravity_line("GRAV,12.5,-3.25,0.8  # comment")
    assert (r.t_s, r.gravity_mgal, r.sigma_mgal) == (12.5, -3.25, 0.8)
    r2 = parse_gravity_line(format_gravity_line(r).encode())
    assert (r2.t_s, r2.gravity_mgal, r2.sigma_mgal) == (12.5, -3.25, 0.8)
    assert parse_gravity_line("GRAV 1 2").sigma_mgal is None
    assert parse_gravity_line("   # only a comment") is None
    for bad in ("FOO,1,2", "GRAV,1", "GRAV,1,x", "GRAV,1,nan", "GRAV,1,2,-1", b"GRAV,\xff"):
        with pytest.raises(ValueError):
            parse_gravity_line(bad)


def test_named_value_float_decoder():
    from pymavlink.dialects.v20 import ardupilotmega as mav

    dec = NamedValueGravityDecoder("GRAV", sigma_mgal=1.5)
    msg = mav.MAVLink_named_value_float_message(123456, b"GRAV", 17.25)
    r = dec.decode(msg, recv_s=1.0)
    assert r.t_s == pytest.approx(123.456) and r.gravity_mgal == pytest.approx(17.25) and r.sigma_mgal == 1.5
    assert dec.decode(mav.MAVLink_named_value_float_message(1, b"OTHER", 1.0)) is None
    assert dec.decode(mav.MAVLink_named_value_float_message(0, b"GRAV", 2.0), recv_s=9.0).t_s == 9.0
    with pytest.raises(ValueError):
        NamedValueGravityDecoder("WAY_TOO_LONG_NAME")


def test_udp_source_receives_lines_and_skips_bad_ones():
    async def go():
        src = UdpGravitySource("127.0.0.1", 0)
        await src.start()
        loop = asyncio.get_running_loop()
        tr, _ = await loop.create_datagram_endpoint(asyncio.DatagramProtocol, remote_addr=("127.0.0.1", src.bound_port))
        tr.sendto(b"GRAV,1.0,10.5\nGARBAGE\nGRAV,2.0,11.5,0.5\n")
        out = []
        it = src.__aiter__()
        out.append(await asyncio.wait_for(it.__anext__(), 2.0))
        out.append(await asyncio.wait_for(it.__anext__(), 2.0))
        tr.close()
        await src.aclose()
        return out, src.bad_lines

    out, bad = asyncio.run(go())
    assert [r.gravity_mgal for r in out] == [10.5, 11.5] and bad == 1


def _bumpy_map(seed=5, half=600.0, cell=5.0):
    return bumpy_map(seed, half, cell, 300, (15, 40))


def test_simulated_gravimeter_placement_and_determinism():
    lmap = _bumpy_map()
    pl = Placement((100.0, -50.0), rotation_deg=90.0)
    np.testing.assert_allclose(pl.to_map([10.0, 0.0]), [100.0, -40.0], atol=1e-9)  # north turns east
    np.testing.assert_allclose(pl.to_flight(pl.to_map([3.0, 4.0])), [3.0, 4.0], atol=1e-9)
    g0 = SimulatedGravimeter(lmap, pl, np.random.default_rng(1), sigma_mgal=0.0)
    r = g0.read(5.0, (10.0, 0.0))
    assert r.gravity_mgal == pytest.approx(float(lmap.interp_ne(100.0, -40.0)))
    assert g0.read(6.0, (1e6, 0.0)) is None  # off the map
    truth = [(float(t), 0.5 * t, 0.0) for t in np.arange(0, 20, 0.5)]
    a = SimulatedGravitySource(SimulatedGravimeter(lmap, pl, np.random.default_rng(3)), truth, period_s=1.0).readings()
    b = SimulatedGravitySource(SimulatedGravimeter(lmap, pl, np.random.default_rng(3)), truth, period_s=1.0).readings()
    assert len(a) == 20 and [x.gravity_mgal for x in a] == [x.gravity_mgal for x in b]
    assert all(isinstance(x, GravityReading) for x in a)


def test_chain_gravity_fixes_beat_unaided_ins_after_gnss_denial():
    flight = simulate_circle_flight(120.0, np.random.default_rng(1))
    lmap = _bumpy_map()
    errs = {}
    for aided in (False, True):
        grav = SimulatedGravimeter(lmap, Placement(), np.random.default_rng(2), sigma_mgal=0.5)
        m = ViterbiMatcher(lmap, ViterbiConfig(n=9, o=3, T=6, alpha=0.05, sigma_z_mgal=0.5, sigma_v_mps=1.5,
                                               subcell_values="interp", prior_sigma_m=15.0), cell_m=10.0) if aided else None
        sink = Collect()
        pipe = gravity_replay_pipeline(sink, lmap, GnssDenial(30.0), matcher=m, placement=Placement(), gravimeter=grav,
                                       period_s=1.0, sigma_floor_m=10.0, acceptance=FixAcceptance())
        for ev in flight.events:
            pipe.process(ev)
        pipe.finish()
        errors = next(s for s in pipe.stages if isinstance(s, DenialErrorStage)).errors
        fused = np.array([e.fused_error_m for e in errors])
        assert fused.size > 50 and np.all(np.isfinite(fused))
        n_fixes = sum(isinstance(o, PositionFix) for o in sink.items)
        if aided:
            assert n_fixes == next(s for s in pipe.stages if isinstance(s, GravityMatchStage)).n_fixes
        errs[aided] = (float(np.mean(fused)), n_fixes)
    assert errs[False][1] == 0 and errs[True][1] >= 10
    assert errs[True][0] < 0.8 * errs[False][0], errs
