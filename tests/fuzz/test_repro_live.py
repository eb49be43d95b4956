"""Reproducers: a real `companion run --inject inject` process against the fuzzing autopilot peer (replay/fuzz/link.py).

Every wait is for a condition (the TCP accept, the companion's UDP port bound, the first fresh GPS_INPUT, the
process exit) with a generous limit. The bursts are 40,000 RAW_IMU a second: on this machine the companion keeps up
with the issue's 14,000 when a core is free for it, 40,000 puts it seconds behind as 14,000 did on a loaded machine.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from replay.fuzz.link import MAX_LAG_S, Burst, Companion, Inject, Peer, Reboot, Sigterm, Silence, run_scenario

XFAIL = dict(strict=True, raises=AssertionError)
BURST_HZ = 40_000
pytestmark = pytest.mark.slow


def _run(name, faults, tmp_path, transport="tcp", **kw):
    kw.setdefault("quiet_s", 4.0)
    kw.setdefault("keep_going_s", 5.0)
    kw.setdefault("exit_timeout_s", 15.0)
    res, peer, comp = run_scenario(name, faults, transport=transport, workdir=tmp_path, **kw)
    assert res.started, f"no GPS_INPUT before the faults: {comp.stderr[-800:]}"
    return res, peer, comp


def _summary(res) -> str:
    return (f"violations {res.violations}; exit {res.exit_code}, SIGTERM -> exit {res.sigterm_to_exit_s} s, "
            f"died {res.died_s}, fresh after faults {res.fresh_after_faults}, stale {res.stale}/{res.gps_inputs}, "
            f"max lag {res.max_lag_s:.2f} s, traceback {res.traceback!r}, MCAP {res.mcap or 'ok'}; {res.notes}")


def test_live_forward_time_jump_keeps_consuming(tmp_path):
    res, _, _ = _run("imu_forward_1e5s", [Inject(1.0, {"RAW_IMU": [("time_usec", "+100000s")]})], tmp_path)
    assert res.died_s is None and res.fresh_after_faults > 0, _summary(res)
    assert res.exit_code == 0 and res.sigterm_to_exit_s <= 2.0 and not res.mcap, _summary(res)


def test_live_future_stamped_attitude_is_not_a_reboot(tmp_path):
    res, _, comp = _run("future_attitude_30s", [Inject(1.0, {"ATTITUDE": [("time_boot_ms", "+30s")]})], tmp_path)
    from companion.record import summarize

    assert "link reboot" not in comp.stderr, comp.stderr[-600:]
    topics = {t.topic: t.count for t in summarize(comp.out).topics}
    assert "/input/reboot" not in topics
    assert res.stale == 0, _summary(res)


def test_sigterm_honoured_within_2s_under_backlog_tcp(tmp_path):
    burst = Burst(1.0, 6.0, rate=BURST_HZ)
    res, _, _ = _run("sigterm_in_burst", [burst, Sigterm(3.5)], tmp_path, "tcp")
    assert burst.sent > 0.5 * BURST_HZ * 2.5, f"the peer sent only {burst.sent} burst messages"
    assert res.exit_code == 0 and res.sigterm_to_exit_s is not None and res.sigterm_to_exit_s <= 2.0, _summary(res)
    assert not res.mcap, _summary(res)


def test_sigterm_honoured_within_2s_under_backlog_udp(tmp_path):
    burst = Burst(1.0, 6.0, rate=BURST_HZ)
    res, _, _ = _run("sigterm_in_burst", [burst, Sigterm(3.5)], tmp_path, "udp")
    assert burst.sent > 0.5 * BURST_HZ * 2.5, f"the peer sent only {burst.sent} burst messages"
    assert res.exit_code == 0 and res.sigterm_to_exit_s is not None and res.sigterm_to_exit_s <= 2.0, _summary(res)
    assert not res.traceback and not res.mcap, _summary(res)


def test_no_stale_gps_input_under_burst(tmp_path):
    burst = Burst(1.0, 3.0, rate=BURST_HZ)
    res, peer, _ = _run("burst", [burst], tmp_path)
    assert burst.sent > 0.5 * BURST_HZ * 3.0, f"the peer sent only {burst.sent} burst messages"
    late = [g for g in peer.gps_inputs if g.lag_s is not None and g.lag_s > MAX_LAG_S]
    assert not late, (f"{len(late)} GPS_INPUT more than {MAX_LAG_S} s after their input arrived, the worst "
                      f"{max(g.lag_s for g in late):.1f} s (fix_type {max(late, key=lambda g: g.lag_s).fix_type})")
    assert res.fresh_after_faults > 0, _summary(res)


def _unsafe(peer):
    """GPS_INPUT the autopilot must not get: older than its stated lag by more than max_lag_s on the autopilot's
    clock, stamped later than anything of its current boot (an older boot's time), or a fix without a time."""
    return [g for g in peer.gps_inputs if (g.lag_s is not None and g.lag_s > MAX_LAG_S) or g.ahead
            or (g.fix_type >= 2 and (g.boot_s == 0 or g.time_week == 0))]


@pytest.mark.parametrize("transport", ["tcp", "udp"])
def test_silence_then_burst_sends_nothing_stale(tmp_path, transport):
    """4 s of silence (the companion declares the link lost and reconnects), then the held-back messages at once."""
    silence = Silence(1.0, 4.0)
    res, peer, comp = _run("silence_then_burst", [silence], tmp_path, transport)
    assert silence.held > 100 and silence.burst_mono is not None, silence.held
    assert "link lost" in comp.stderr, comp.stderr[-600:]
    bad = _unsafe(peer)
    assert not bad, f"{len(bad)} unsafe GPS_INPUT, the first {bad[0]}; {_summary(res)}"
    fresh = peer.fresh_since(silence.burst_mono)
    assert fresh and fresh[0].recv_mono - silence.burst_mono < 2.0, _summary(res)  # fresh fixes come back at once
    assert res.exit_code == 0 and not res.traceback and not res.mcap, _summary(res)


def test_reboot_mid_send_keeps_every_gps_input_on_the_current_boot(tmp_path):
    res, peer, comp = _run("reboot_mid_send", [Reboot(1.0, 1.5)], tmp_path)
    assert peer.reboot_mono and "link reboot" in comp.stderr, comp.stderr[-600:]
    bad = _unsafe(peer)
    assert not bad, f"{len(bad)} unsafe GPS_INPUT, the first {bad[0]}; {_summary(res)}"
    after = [g for g in peer.gps_inputs if g.recv_mono > peer.reboot_mono[0]]
    assert after and max(g.boot_s for g in after) < 30.0  # on the new boot's clock (it restarted at 1 s)
    assert res.fresh_after_faults > 0 and res.exit_code == 0 and not res.traceback, _summary(res)


def test_system_time_4e16_in_inject_mode(tmp_path):
    res, _, _ = _run("system_time_4e16", [Inject(1.0, {"SYSTEM_TIME": [("time_unix_usec", 40_000_000_000_000_000)]})],
                     tmp_path)
    assert res.died_s is None and not res.traceback, _summary(res)
    assert res.fresh_after_faults > 0 and res.exit_code == 0, _summary(res)


def test_live_bad_input_is_survived(tmp_path):
    """Garbage, bad CRCs, MAVLink 1 among MAVLink 2, extreme and NaN fields: survived today (and must stay so).
    The timing properties (SIGTERM within 2 s, no stale GPS_INPUT) are the reproducers' above: on a loaded
    machine they fail today whatever the input."""
    from replay.fuzz.link import BadCrc, Garbage, Mavlink1, scenarios

    ext = scenarios()["extreme_fields"]()[0]
    ext.at_s = 4.0
    for transport in ("tcp", "udp"):
        res, _, _ = _run("bad_input", [Garbage(1.0, 3.0), BadCrc(1.0, 3.0), Mavlink1(2.0, 3.0), ext],
                         tmp_path / transport, transport)
        broken = [v for v in res.violations if v not in ("slow_sigterm", "stale")]
        assert not broken, f"{transport}: {_summary(res)}"


# ----------------------------------------------------------------------------------------------- the disk
@pytest.fixture
def tiny_disk(tmp_path):
    """A 64 KiB tmpfs: the record fills it seconds after the start."""
    mnt = tmp_path / "tiny"
    mnt.mkdir()
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True, text=True)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs root): {res.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def _disk_full(path: Path) -> bool:
    st = os.statvfs(path)
    return st.f_bavail == 0


def test_full_disk_keeps_navigating_and_injecting(tmp_path, tiny_disk):
    peer = Peer("tcp")
    out = tiny_disk / "live.mcap"
    comp = Companion(peer.url, out, "--set", "streams.GPS_RAW_INT=5", workdir=tmp_path)
    peer.companion = comp
    try:
        peer.connect(60)
        t0 = time.monotonic()
        # full: no block left, or the recorder already refused a write that did not fit in what was left
        def full() -> bool:
            return _disk_full(tiny_disk) or "No space left" in comp.stderr

        peer.play(lambda now: full() or comp.proc.poll() is not None or time.monotonic() - t0 > 120)
        assert full(), f"the disk did not fill: {os.statvfs(tiny_disk).f_bavail} blocks free; {comp.stderr[-400:]}"
        full_at = time.monotonic()
        peer.play(lambda now: comp.proc.poll() is not None or time.monotonic() - full_at > 8)
        assert comp.proc.poll() is None, f"exit {comp.proc.returncode} once the disk was full: {comp.stderr[-400:]}"
        fresh = peer.fresh_since(full_at + 2)
        assert len(fresh) >= 20, f"{len(fresh)} fresh GPS_INPUT in the 6 s after the disk filled"
        peer.sigterm()
        peer.play(lambda now: comp.proc.poll() is not None or time.monotonic() - peer.sigterm_mono > 10)
        rc = comp.wait(10)
    finally:
        comp.close()
        peer.close()
    err = comp.stderr
    assert rc == 0 and "Traceback" not in err, err[-600:]
    assert any(str(out) in line and "No space left" in line for line in err.splitlines()), err[-600:]


# ----------------------------------------------------------------------------------------------- serial
def test_serial_device_missing_at_start_is_retried(tmp_path):
    dev = Path(f"/dev/ttyCOMPFUZZ{os.getpid()}")
    if dev.exists() or dev.is_symlink():
        dev.unlink()
    if not os.access("/dev", os.W_OK):
        pytest.skip("/dev not writable: cannot make the device appear")
    master, slave = os.openpty()
    comp = Companion(str(dev), tmp_path / "s.mcap", workdir=tmp_path, inject="shadow")
    try:
        t_end = time.monotonic() + 60
        while "open_failed" not in comp.stderr and comp.proc.poll() is None and time.monotonic() < t_end:
            time.sleep(0.05)
        assert comp.proc.poll() is None, f"exit {comp.proc.returncode} with the device missing: {comp.stderr.strip()}"
        assert "open_failed" in comp.stderr
        os.symlink(os.ttyname(slave), dev)  # the device appears (a USB adapter plugged in late)
        rx = mavlink2.MAVLink(None)
        rx.robust_parsing = True
        heard = False
        t_end = time.monotonic() + 60
        while not heard and time.monotonic() < t_end and comp.proc.poll() is None:
            r, _, _ = select.select([master], [], [], 0.2)
            if r:
                for m in rx.parse_buffer(os.read(master, 4096)) or []:
                    heard = heard or (m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 191)
        assert heard, f"no HEARTBEAT from the companion on the device: {comp.stderr[-400:]}"
        comp.proc.send_signal(signal.SIGTERM)
        assert comp.wait(15) == 0
    finally:
        comp.close()
        if dev.is_symlink():
            dev.unlink()
        os.close(master)
        os.close(slave)





# ----------------------------------------------------------------------------------------------- the record's clock
def test_live_record_is_on_one_clock(tmp_path):
    """The fake autopilot's flight is dated years before the host's clock (as SITL's, or a Raspberry Pi's without an
    RTC before NTP): what was recorded before its first SYSTEM_TIME must not carry the host's time."""
    from mcap.reader import make_reader

    res, _, comp = _run("quiet", [], tmp_path, quiet_s=2.0)
    assert res.exit_code == 0 and not res.mcap, _summary(res)
    with open(comp.out, "rb") as f:
        reader = make_reader(f)
        clock = next(m for m in reader.iter_metadata() if m.name == "clock").metadata
        stats = reader.get_summary().statistics
    span_s = (stats.message_end_time - stats.message_start_time) / 1e9
    assert span_s < 300, f"the record spans {span_s / 86400:.0f} days ({clock})"
    assert clock["log_time"].startswith("UTC") and "before_utc" not in clock, clock
