"""Link management against the simulated vehicle in-process: targeting, stream requests, re-requests,
reboot, link loss and reconnection, signing, bad frames; and the runtime loop's recording and shutdown."""

from __future__ import annotations

import asyncio
import threading

import pytest

from tests.conftest import free_port
from companion.config import LinkConfig, StreamConfig, load_config
from companion.events import GnssFix, ImuSample, Reboot
from companion.mavlink.link import Batch, LinkStatus, MavlinkLink, message_id
from companion.sim.playback import playback_from_flight
from companion.sim.vehicle import Faults, VehicleSim


@pytest.fixture(scope="module")
def playback():
    return playback_from_flight()


class Harness:
    """A VehicleSim in a thread and a MavlinkLink in an asyncio loop, for ``seconds`` of wall time."""

    def __init__(self, playback, *, faults=None, key=None, link_key_file="", start_s=20.0, streams=None, **link_kw):
        self.port = free_port()
        self.sim = VehicleSim(playback, f"tcpin:127.0.0.1:{self.port}", faults=faults, start_s=start_s, key=key)
        self.link_cfg = LinkConfig(connect=f"tcp:127.0.0.1:{self.port}", signing_key_file=link_key_file, **link_kw)
        self.stream_cfg = streams or StreamConfig()
        self.items: list = []

    def run(self, seconds: float):
        th = threading.Thread(target=self.sim.run, daemon=True)
        th.start()

        async def main():
            link = MavlinkLink(self.link_cfg, self.stream_cfg)
            link.start(asyncio.get_running_loop(), self.items.append)
            await asyncio.sleep(seconds)
            await asyncio.to_thread(link.stop)
            return link

        self.link = asyncio.run(main())
        self.sim.stop()
        th.join(5)
        return self

    @property
    def statuses(self) -> list[LinkStatus]:
        return [i for i in self.items if isinstance(i, LinkStatus)]

    def states(self) -> list[str]:
        return [s.state for s in self.statuses]

    def events(self, cls=None):
        evs = [e for i in self.items if isinstance(i, Batch) for e in i.events]
        return [e for e in evs if cls is None or isinstance(e, cls)]


def test_targets_autopilot_and_requests_streams(playback):
    h = Harness(playback).run(4.0)
    assert h.states()[:3] == ["opened", "autopilot", "streams"]
    assert h.link.target == (1, 1)
    req = {msg_id: interval for _, msg_id, interval in h.sim.stats.requests}
    assert req == {message_id("GPS_RAW_INT"): 1e5, message_id("RAW_IMU"): 2e4, message_id("ATTITUDE"): 1e5, message_id("SYSTEM_TIME"): 1e6,
                   message_id("GLOBAL_POSITION_INT"): 2e5}  # (the autopilot's own position: its Map track)
    assert h.sim.stats.received["HEARTBEAT"] >= 3  # ours, 1 Hz
    imu, gnss = h.events(ImuSample), h.events(GnssFix)
    assert len(imu) > 100 and len(gnss) > 10  # streams flow once requested (the sim sends none before)
    assert h.link.decoder.dropped["other system 255/190"] >= 2  # the ground station's heartbeats
    assert "COMMAND_ACK" not in h.link.decoder.dropped


def test_rate_drop_is_rerequested(playback):
    h = Harness(playback, faults=Faults(forget_streams_at=22.0), streams=StreamConfig(check_period_s=1.0)).run(6.0)
    assert "rate_low" in h.states()
    later = [r for r in h.sim.stats.requests if r[0] > 22.0]
    assert {m for _, m, _ in later} >= {message_id("RAW_IMU"), message_id("GPS_RAW_INT")}
    late_imu = [e for e in h.events(ImuSample) if e.t_s > 24.0]
    assert len(late_imu) > 50  # streams back after the re-request


def test_reboot_detected_and_streams_rerequested(playback):
    h = Harness(playback, faults=Faults(reboot_at=24.0, reboot_downtime_s=1.0), link_timeout_s=3.0).run(9.0)
    assert "reboot" in h.states()
    reboots = h.events(Reboot)
    # detected from the first boot-time message after it (the rebooted vehicle streams only once asked again)
    assert len(reboots) == 1 and reboots[0].previous_boot_s > 23.0 and reboots[0].new_boot_s < 5.0
    after = [r for r in h.sim.stats.requests if r[0] > 25.0]
    assert len(after) >= 4  # everything requested again (the autopilot forgot at reboot)
    t = [e.t_s for e in h.events(ImuSample)]
    assert t == sorted(t) or sum(b < a for a, b in zip(t, t[1:])) <= 2  # vehicle time continues through the reboot
    assert max(t) > reboots[0].t_s + 2.0


def test_link_drop_reconnects_with_backoff(playback):
    h = Harness(playback, faults=Faults(link_drop=(22.0, 25.0)), link_timeout_s=1.0, reconnect_min_s=0.25).run(9.0)
    st = h.states()
    assert "lost" in st and "reconnecting" in st
    i = st.index("lost")
    assert "autopilot" in st[i:] and st.count("opened") >= 2
    assert st.count("open_failed") >= 1  # the server is gone during the drop: refused, retried
    assert h.sim.stats.connections == 2
    assert any(e.t_s > 26.0 for e in h.events(ImuSample))


def test_signing_both_ways(playback, tmp_path):
    key = bytes(range(1, 33))
    (tmp_path / "key").write_text(key.hex())
    h = Harness(playback, key=key, link_key_file=str(tmp_path / "key")).run(3.0)
    assert h.link.target == (1, 1) and len(h.events(ImuSample)) > 50
    assert h.sim.stats.received["HEARTBEAT"] >= 2 and h.sim.stats.received.get("BAD_DATA", 0) == 0


def test_signing_vehicle_refuses_an_unsigned_companion(playback):
    h = Harness(playback, key=bytes(range(32))).run(2.5)
    # the companion hears the signed HEARTBEATs (a receiver without a key accepts signed frames) but the
    # vehicle refuses everything unsigned: no stream request gets through, so no data flows
    assert h.sim.stats.received["HEARTBEAT"] == 0 and h.sim.stats.received["BAD_DATA"] >= 2
    assert not h.sim.stats.requests and not h.events(ImuSample)


def test_bad_input_is_dropped_and_counted(playback):
    h = Harness(playback, faults=Faults(noise=True)).run(5.0)
    d = h.link.decoder.dropped
    assert d["bad frame"] >= 3 and d["other system 2/1"] >= 2 and d["ATTITUDE non-finite"] >= 2
    gnss = h.events(GnssFix)
    # the vehicle's fix_type 0 reports arrive as fixes without a position, never as a position at 0,0
    assert any(g.fix_type == 0 for g in gnss) and all(g.lat_deg != 0.0 for g in gnss if g.has_position)
    assert len(h.events(ImuSample)) > 150  # the link keeps going


def test_runtime_records_link_events_and_stops_cleanly(playback, tmp_path):
    from companion.record import Recorder, summarize
    from companion.runtime import Runtime

    port = free_port()
    sim = VehicleSim(playback, f"tcpin:127.0.0.1:{port}", start_s=20.0)
    th = threading.Thread(target=sim.run, daemon=True)
    th.start()
    cfg = load_config(None, {"link.connect": f"tcp:127.0.0.1:{port}", "inject.mode": "shadow"})
    rec = Recorder(tmp_path / "r.mcap")
    logs: list[str] = []
    rt = Runtime(cfg, rec, log=logs.append)
    reason = asyncio.run(rt.run(duration_s=3.0))
    sim.stop()
    th.join(5)
    rec.add_metadata("runtime", rt.metadata())
    rec.close()
    assert reason == "--duration 3 s"
    s = summarize(tmp_path / "r.mcap")
    counts = {t.topic: t.count for t in s.topics}
    assert s.finalised and counts["/link/status"] >= 3 and counts["/input/imu"] > 50
    assert any("link autopilot" in line for line in logs)
    assert not rt.link.thread_alive


def test_serial_transport_on_a_pty():
    """The termios serial transport, on a pseudo-terminal standing in for the autopilot's UART."""
    import os

    from pymavlink.dialects.v20 import ardupilotmega as mav

    from companion.mavlink.transport import open_transport
    from companion.mavlink.address import parse_url

    master, slave = os.openpty()
    try:
        tr = open_transport(parse_url(f"{os.ttyname(slave)},921600"))
        frame = bytes(mav.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(mav.MAVLink(None, 1, 1)))
        os.write(master, frame)
        got = b""
        for _ in range(20):
            got += tr.recv(0.1)
            if len(got) >= len(frame):
                break
        assert got == frame
        assert tr.write(b"\xfd\x00") and os.read(master, 16) == b"\xfd\x00"
        tr.close()
    finally:
        os.close(master)
        os.close(slave)


def test_udp_link_learns_the_peer_and_requests_streams(playback):
    """udpin: the companion answers whoever sends (the vehicle on udpout), as with a telemetry radio bridge."""
    port = free_port()
    sim = VehicleSim(playback, f"udpout:127.0.0.1:{port}", start_s=20.0)
    th = threading.Thread(target=sim.run, daemon=True)
    items: list = []

    async def main():
        link = MavlinkLink(LinkConfig(connect=f"udpin:127.0.0.1:{port}"), StreamConfig())
        link.start(asyncio.get_running_loop(), items.append)
        th.start()
        await asyncio.sleep(4.0)
        await asyncio.to_thread(link.stop)
        return link

    link = asyncio.run(main())
    sim.stop()
    th.join(5)
    assert link.target == (1, 1) and len(sim.stats.requests) == 5
    imu = [e for i in items if isinstance(i, Batch) for e in i.events if isinstance(e, ImuSample)]
    assert len(imu) > 50


def test_deferred_imports_are_warmed_off_the_loop():
    """The runtime starts without scipy.spatial (READY sooner) and imports it in a thread once the loop runs: at its
    first use in the loop (the KNN predictor's tree) it stalled the loop 0.5 s behind the link."""
    import subprocess
    import sys

    code = ("import sys; import companion.runtime.runner as r; assert 'scipy.spatial' not in sys.modules; "
            "r.warm_deferred_imports(); assert all(m in sys.modules for m in r.DEFERRED_IMPORTS)")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr


def test_inbox_is_a_fifo_queue_for_one_task():
    from companion.runtime.runner import Inbox

    async def main():
        box = Inbox(asyncio.get_running_loop())
        assert box.empty()
        with pytest.raises(asyncio.QueueEmpty):
            box.get_nowait()
        box.put_nowait(1)
        box.put_nowait(2)
        assert await box.get() == 1 and box.get_nowait() == 2 and box.empty()
        waiting = asyncio.ensure_future(box.get())
        await asyncio.sleep(0)
        asyncio.get_running_loop().call_later(0.01, box.put_nowait, 3)
        assert await asyncio.wait_for(waiting, 60) == 3
        cancelled = asyncio.ensure_future(box.get())  # a get cancelled while waiting loses nothing
        await asyncio.sleep(0)
        cancelled.cancel()
        box.put_nowait(4)
        assert await box.get() == 4 and box.empty()
        await asyncio.gather(cancelled, return_exceptions=True)
        return cancelled.cancelled()

    assert asyncio.run(main())


def test_run_loop_runs_on_uvloop_when_installed():
    from companion.runtime.runner import run_loop

    async def main():
        await asyncio.sleep(0)
        return type(asyncio.get_running_loop()).__module__

    try:
        import uvloop  # noqa: F401
    except ImportError:
        assert run_loop(main()).startswith("asyncio")
    else:
        assert run_loop(main()).startswith("uvloop")
