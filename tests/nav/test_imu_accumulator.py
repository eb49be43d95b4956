"""IMU increments summed between strapdown steps (coning and sculling) against the truth of a coning, vibrating
vehicle at rest (companion.sim.coning): at 50 Hz the summed 400 Hz samples keep the attitude and velocity as well as
stepping each sample, where summing them without the corrections drifts; and the INS filter steps its strapdown at
ins_rate_hz, and brings it up to date before a measurement."""

from __future__ import annotations

import numpy as np

from companion.events import Attitude
from companion.nav.config import NavigatorConfig
from companion.nav.frame import LocalFrame
from companion.nav.gnss_lag import GnssLatency
from companion.nav.imu_accumulator import ImuAccumulator
from companion.nav.ins import StrapdownIns
from companion.nav.ins_filter import InsFilter
from companion.sim.coning import ConingMount

MOUNT = ConingMount()


def _new_ins() -> StrapdownIns:
    ins = StrapdownIns(0.0, 0.0, 0.0, 0.0, earth_rate=False)
    ins.q = MOUNT.attitude(0.0)
    return ins


def _errors(ins: StrapdownIns, t: float) -> tuple[float, float]:
    return MOUNT.errors(ins.q, ins.vel_ned, t)


def test_summed_increments_match_every_sample_and_beat_summing_without_corrections():
    samples = MOUNT.samples(400.0, 10.0, _new_ins().gravity())
    each = _new_ins()
    for t, a, w in samples:
        each.step(t, a, w)
    summed, plain = _new_ins(), _new_ins()
    acc = ImuAccumulator()
    for i, (t, a, w) in enumerate(samples):
        acc.add(t, 1 / 400.0, a, w)
        if (i + 1) % 8 == 0:
            _, rot, dv = acc.take()
            summed.step_increments(t, rot, dv)
            block = samples[i - 7:i + 1]  # the same 8 samples averaged into one 50 Hz sample, no corrections
            plain.step(t, tuple(np.mean([s[1] for s in block], axis=0)), tuple(np.mean([s[2] for s in block], axis=0)))
    e_each, e_sum, e_plain = (_errors(x, samples[-1][0]) for x in (each, summed, plain))
    # summing without coning drifts the attitude, without sculling the velocity; with them, as good as every sample
    assert e_plain[0] > 100 * e_sum[0] and e_plain[1] > 20 * e_sum[1], (e_each, e_sum, e_plain)
    assert e_sum[0] < 0.005 and e_sum[1] < 0.001, (e_each, e_sum, e_plain)


def _filter(rate_hz: float) -> InsFilter:
    c = NavigatorConfig(ins_rate_hz=rate_hz)
    latency = GnssLatency(c.gnss_delay_s, c.gnss_vel_delay_s, None)
    f = InsFilter(c, LocalFrame(0.0, 0.0, 0.0), latency, lambda e: None, 0.0, (0.0, 0.0, 0.0), None,
                  Attitude(0.0, 0.0, 0.0, 0.0), 1)
    f.strapdown.q = MOUNT.attitude(0.0)
    return f


def test_the_filter_steps_its_strapdown_at_its_rate_and_a_measurement_brings_it_up_to_date():
    g = _new_ins().gravity()
    f = _filter(50.0)
    steps = []
    orig = f.strapdown.step_increments
    f.strapdown.step_increments = lambda *a: steps.append(a[0]) or orig(*a)
    samples = MOUNT.samples(400.0, 2.0, g)
    for t, a, w in samples[:-3]:
        f.step_imu(t, a, w)
    assert 98 <= len(steps) <= 100  # 50 Hz, not 400
    assert np.allclose(np.diff(steps), 0.02)
    assert f.strapdown.t_s < samples[-4][0]  # the last samples are summed, not yet stepped
    f.predict(samples[-4][0])  # what a measurement or an output does first
    assert f.strapdown.t_s == samples[-4][0]
    # the same as stepping every sample (the filter's INS has the Earth's rate, the mount's truth not: compared with
    # each other, not with the truth)
    each = _filter(400.0)
    for t, a, w in samples[:-3]:
        each.step_imu(t, a, w)
    e_sum, e_each = _errors(f.strapdown, samples[-4][0]), _errors(each.strapdown, samples[-4][0])
    assert abs(e_sum[0] - e_each[0]) < 0.002 and abs(e_sum[1] - e_each[1]) < 0.002
    # a 50 Hz IMU steps it at every sample, as before
    f50 = _filter(50.0)
    f50.strapdown.step_increments = lambda *a: (_ for _ in ()).throw(AssertionError("summed a 50 Hz sample"))
    for t, a, w in MOUNT.samples(50.0, 1.0, g):
        f50.step_imu(t, a, w)
    assert f50.strapdown.t_s == 1.0
