"""Hardware-in-the-loop: the real ``companion run`` process against ``companion sim`` over loopback TCP.

The simulated vehicle plays a generated flight (10 Hz GNSS, 50 Hz IMU, truth known) or a tlog and records
every GPS_INPUT it receives with the truth at the message's time. Each test waits for conditions (the\nsimulator's record, the companion's log), each with a generous bound.
"""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from companion.record import iter_payloads, summarize
from tests.conftest import REPO, free_port

SAMPLE_TLOG = REPO / "logs" / "sample_flight.tlog"
CLI = [sys.executable, "-m", "companion.cli"]


class Sim:
    def __init__(self, tmp_path, *args):
        self.port = free_port()
        self.record = tmp_path / "sim.jsonl"
        self.proc = subprocess.Popen(
            [*CLI, "sim", "--listen", f"tcpin:127.0.0.1:{self.port}", "--record", str(self.record), *map(str, args)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        first = self.proc.stdout.readline()  # printed once it is about to listen
        assert first.startswith("sim:"), self.proc.stderr.read()

    def finish(self, timeout=30):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        out, err = self.proc.communicate(timeout=timeout)
        assert "Traceback" not in err, err
        return [json.loads(line) for line in self.record.read_text().splitlines()]


def run_companion(port, out, *args, timeout=90):
    return subprocess.Popen(
        [*CLI, "run", "--connect", f"tcp:127.0.0.1:{port}", "--out", str(out), *map(str, args)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )


class StderrWatch:
    """Reads a running companion's stderr in a thread (lines kept) so a test can wait for what it logs."""

    def __init__(self, proc):
        import threading

        self.proc, self.lines = proc, []
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self):
        for line in self.proc.stderr:
            self.lines.append(line)

    def count(self, text: str) -> int:
        return sum(text in line for line in list(self.lines))

    def caught_up_after_link_loss(self, timeout_s: float = 180.0) -> bool:
        """The peer has closed the link and the loop has worked off what was queued before (every 'behind the
        link' episode ended with 'caught up'); False at the time-out or when the process ended."""
        import time

        end = time.monotonic() + timeout_s
        while time.monotonic() < end and self.proc.poll() is None:
            if self.count("link lost") and self.count("behind the link: coalescing") == self.count("caught up with the link"):
                return True
            time.sleep(0.1)
        return False

    def text(self) -> str:
        self._thread.join(30)
        return "".join(self.lines)


def wait_for_records(sim, pred, timeout_s: float = 180.0) -> list[dict]:
    """Poll the simulator's record (one JSON line per event, flushed) until ``pred(records)`` or the time-out
    or the simulator's end; returns the records read last."""
    import time

    end = time.monotonic() + timeout_s
    recs: list[dict] = []
    while time.monotonic() < end:
        text = sim.record.read_text() if sim.record.exists() else ""
        recs = [json.loads(line) for line in text.splitlines() if line.endswith("}")]
        if pred(recs) or sim.proc.poll() is not None:
            break
        time.sleep(0.1)
    return recs


def gps_inputs(recs):
    return [r for r in recs if r["event"] == "gps_input"]


def event_time(recs, name):
    return next(r["play_s"] for r in recs if r["event"] == name)


def check_fields(g):
    assert g["gps_id"] == 1 and g["ignore_flags"] & 2 == 0  # HDOP present (EKF3 needs it)
    assert not (g["lat_deg"] == 0 and g["lon_deg"] == 0)
    assert g["fix_type"] < 2 or g["satellites"] >= 6
    assert g["h_acc_m"] > 0 and g["v_acc_m"] > 0 and math.isfinite(g["hdop"])


def test_gnss_cut_injection_starts_and_stays_within_reported_accuracy(tmp_path):
    sim = Sim(tmp_path, "--start", 20, "--end", 56, "--gnss-off", 32, 42)
    comp = run_companion(
        sim.port, tmp_path / "c.mcap", "--inject", "inject", "--set", 'inject.activate="gnss_loss"', "--duration", 32
    )
    out, err = comp.communicate(timeout=90)
    recs = sim.finish()
    assert comp.returncode == 0 and "Traceback" not in err, err
    gi = gps_inputs(recs)
    cut = event_time(recs, "gnss_off")
    assert gi, out
    assert all(g["play_s"] >= cut for g in gi)  # nothing injected while the receiver was healthy
    first = gi[0]["play_s"]
    assert first - cut <= 1.0  # injection starts within 1 s of the cut
    during = [g for g in gi if cut + 1.0 <= g["play_s"] < 42.0]
    rate = len(during) / (42.0 - cut - 1.0)
    assert rate >= 5.0  # >= 5 Hz while injecting
    for g in gi:
        check_fields(g)
    assert all(g["time_week"] > 2000 for g in gi)  # GPS time from SYSTEM_TIME
    # honest accuracy: the horizontal error is within the reported accuracy most of the time
    err_h = np.array([g["err_h_m"] for g in gi if "err_h_m" in g])
    acc_h = np.array([g["h_acc_m"] for g in gi if "err_h_m" in g])
    assert len(err_h) >= 0.9 * len(gi)
    assert np.mean(err_h <= acc_h) >= 0.68 and np.all(err_h <= 4.0 * acc_h)
    assert np.max(err_h[acc_h < 10.0]) < 10.0
    # receiver back at 42 s: injection stops after recover_s (3 s) of healthy fixes
    assert gi[-1]["play_s"] < 42.0 + 3.0 + 1.0
    assert "latency      " in out
    s = summarize(tmp_path / "c.mcap")
    counts = {t.topic: t.count for t in s.topics}
    assert s.finalised and counts["/inject/gps_input"] >= len(gi) and counts["/inject/state"] >= 2


def test_link_drop_and_reboot_recovery_then_sigterm(tmp_path):
    sim = Sim(tmp_path, "--start", 20, "--end", 70, "--link-drop", 26, 29, "--reboot-at", 35, "--reboot-downtime", 2)
    comp = run_companion(sim.port, tmp_path / "c.mcap", "--inject", "inject", "--set", "link.link_timeout_s=1.5")

    def recovered(recs):  # 10 GPS_INPUT after the reboot, or the reboot plus the 8 s the test allows have passed
        booted = [r["play_s"] for r in recs if r["event"] == "booted"]
        later = [r for r in recs if booted and r["event"] == "gps_input" and r["play_s"] > booted[0]]
        return len(later) >= 10 or any(r["play_s"] > booted[0] + 9.0 for r in recs if booted and "play_s" in r)

    wait_for_records(sim, recovered)  # instead of a fixed time: start-up takes seconds on a loaded machine
    if comp.poll() is None:
        comp.send_signal(signal.SIGTERM)
    out, err = comp.communicate(timeout=60)
    recs = sim.finish()
    assert comp.returncode == 0 and "Traceback" not in err, err
    assert "stopped by   SIGTERM" in out
    gi = gps_inputs(recs)
    end = next(r for r in recs if r["event"] == "end")
    assert end["connections"] >= 2  # reconnected after the drop
    back, booted = event_time(recs, "link_back"), event_time(recs, "booted")
    assert any(back < g["play_s"] < 35.0 for g in gi)  # injecting again after the link came back
    after_boot = [g for g in gi if g["play_s"] > booted]
    assert after_boot, "no injection after the reboot"
    assert after_boot[0]["play_s"] - booted < 8.0
    assert after_boot[-1]["time_boot_us"] < 20e6  # time_usec follows the autopilot's new boot time
    for g in gi:
        check_fields(g)
    ok = [g for g in after_boot if "err_h_m" in g]
    assert ok and np.median([g["err_h_m"] for g in ok]) < 3.0
    s = summarize(tmp_path / "c.mcap")
    assert s.finalised
    counts = {t.topic: t.count for t in s.topics}
    assert counts["/link/status"] >= 6 and counts["/input/reboot"] == 1
    assert "link.lost" in out and "link.reboot" in out


def test_bad_input_imu_stop_never_an_unsupported_fix(tmp_path):
    sim = Sim(tmp_path, "--start", 20, "--end", 48, "--noise", "--imu-off", 27, 31, "--gnss-off", 33, 38)
    comp = run_companion(sim.port, tmp_path / "c.mcap", "--inject", "inject", "--duration", 22)
    out, err = comp.communicate(timeout=90)
    recs = sim.finish()
    assert comp.returncode == 0 and "Traceback" not in err, err
    for why in ("bad frame", "other system 2/1", "ATTITUDE non-finite", "GPS position out of range"):
        assert why in out, out  # dropped and said why
    gi = gps_inputs(recs)
    assert len(gi) > 100
    for g in gi:
        check_fields(g)
    fixes = [g for g in gi if g["fix_type"] >= 3 and "err_h_m" in g]
    err_h = np.array([g["err_h_m"] for g in fixes])
    acc_h = np.array([g["h_acc_m"] for g in fixes])
    assert np.mean(err_h <= acc_h) >= 0.68 and np.all(err_h <= 4.0 * acc_h)
    # the other vehicle's receiver (lat 10, lon 20) never leaks into what is injected
    assert all(abs(g["lat_deg"] + 35.36) < 0.1 for g in gi)


def test_live_path_gives_the_replay_payloads(tmp_path):
    """The sample tlog streamed by the simulated vehicle through `companion run` records the same
    payloads as `companion replay` of that log (events without a boot time -- HEARTBEAT, STATUSTEXT --
    are stamped by arrival and left out; link and injector topics exist only live)."""
    # live equals replay only while the companion keeps up: behind the link it sheds IMU frames and coalesces IMU
    # samples, and says so in its metadata. x2 first; a run that had to shed (a loaded machine) is flown again at x1
    for speed in (2, 1):
        run_dir = tmp_path / f"x{speed}"
        run_dir.mkdir()
        sim = Sim(run_dir, "--log", SAMPLE_TLOG, "--streams", "all", "--speed", speed, "--end", 64)
        live_mcap = run_dir / "live.mcap"
        comp = run_companion(sim.port, live_mcap, "--inject", "shadow", "--duration", 68 / speed)
        out, err = comp.communicate(timeout=180)
        sim.finish()
        assert comp.returncode == 0, err
        runtime = summarize(live_mcap).metadata_dict("runtime")
        shed = {k: v for k, v in runtime.items() if (k.startswith("shed.") or k == "link.imu_frames_shed") and v != "0"}
        if not shed:
            break
    assert not shed, f"the companion fell behind the link even at x1 and shed load: {shed}"
    rep = subprocess.run(
        [*CLI, "replay", str(SAMPLE_TLOG), "--out", str(tmp_path / "replay.mcap"), "--quiet"],
        capture_output=True, text=True, timeout=120,
    )
    assert rep.returncode == 0, rep.stderr
    skip = ("/input/heartbeat", "/input/statustext", "/log/autopilot", "/link/", "/inject/", "/map/gps_input")

    clocks = [summarize(f).metadata_dict("clock") for f in (live_mcap, tmp_path / "replay.mcap")]
    assert all(c["log_time"] == "UTC, Unix epoch ns" for c in clocks), clocks
    assert clocks[0]["utc_offset_ns"] == clocks[1]["utc_offset_ns"]  # live and replay on the same UTC
    offset_ns = int(clocks[0]["utc_offset_ns"])

    def payloads(path):
        d: dict[str, list] = {}
        # compared on the vehicle clock in the payloads: log times are UTC, and a live run stamps what comes before
        # the vehicle's first SYSTEM_TIME with the host's UTC clock (a replay looks ahead); a LocationFix carries its
        # log time, so the vehicle time is that less the UTC offset (its payload compared without it)
        for topic, _log_ns, data in iter_payloads(path):
            if not topic.startswith(skip):
                p = json.loads(data)
                if "t_s" in p:
                    t_ns = round(p["t_s"] * 1e9)
                else:
                    stamp = p.pop("timestamp")
                    t_ns, data = stamp["sec"] * 10**9 + stamp["nsec"] - offset_ns, json.dumps(p).encode()
                d.setdefault(topic, []).append((t_ns, data))
        return d

    live, replay = payloads(live_mcap), payloads(tmp_path / "replay.mcap")
    last_ns = max(t for v in live.values() for t, _ in v)
    cut_ns = last_ns - 3_000_000_000  # the live run stops mid-flight: leave out the navigator's final flush
    assert set(live) == set(replay)
    assert "/input/imu" in live and "/input/gnss" in live
    compared = 0
    for topic in live:
        a = [p for p in live[topic] if p[0] <= cut_ns]
        b = [p for p in replay[topic] if p[0] <= cut_ns]
        assert a == b, topic
        compared += len(a)
    assert compared > 3000 and cut_ns > 50e9


def test_simulator_ends_once_the_companion_is_gone(tmp_path):
    """The README's background `companion sim ... &` ends on its own once `companion run` has exited."""
    sim = Sim(tmp_path, "--idle-exit", 3)  # the sample flight is 174 s long
    comp = run_companion(sim.port, tmp_path / "c.mcap", "--duration", 5)
    _out, err = comp.communicate(timeout=90)
    assert comp.returncode == 0, err
    t0 = time.monotonic()
    sim.proc.wait(timeout=60)  # long before the flight's end
    waited_s = time.monotonic() - t0
    recs = sim.finish()
    idle = [r for r in recs if r["event"] == "idle_exit"]
    assert idle and idle[0]["play_s"] < 60.0 and waited_s < 60.0


def _heartbeats_and_texts(mcap):
    hb, texts = [], []
    for topic, _log_ns, data in iter_payloads(mcap):
        if topic == "/input/heartbeat":
            hb.append(json.loads(data)["armed"])
        elif topic == "/input/statustext":
            texts.append(json.loads(data)["text"])
    return hb, texts


def test_mav_gps_instance_arms_on_the_companions_3d_fix(tmp_path):
    """`companion sim --gps-mav-instance 1` arms like an ArduPilot with GPS2_TYPE=14: only with a 3D GPS_INPUT for
    instance 1 at most 1 s old. `companion run --inject inject` (activate backup: a fix while disarmed) gives it one;
    the flight then flies, and the record marks exactly the GPS_INPUT below 3D as ignored by EKF3."""
    sim = Sim(tmp_path, "--gps-mav-instance", 1, "--end", 60)
    comp = run_companion(sim.port, tmp_path / "c.mcap", "--inject", "inject")

    def climbing(recs):  # armed, and fixes for 5 s of flight after it (the sample flight takes off at 10 s)
        armed = [r for r in recs if r["event"] == "armed"]
        return bool(armed) and any(g["state_play_s"] > armed[0]["play_s"] + 5.0 for g in gps_inputs(recs))

    wait_for_records(sim, climbing, timeout_s=120.0)
    if comp.poll() is None:
        comp.send_signal(signal.SIGTERM)
    _out, err = comp.communicate(timeout=60)
    recs = sim.finish()
    assert comp.returncode == 0 and "Traceback" not in err, err
    armed = [r for r in recs if r["event"] == "armed"]
    assert len(armed) == 1, [r for r in recs if r["event"] != "gps_input"]
    a = armed[0]
    assert a["scripted_s"] == pytest.approx(8.1) and a["play_s"] - a["scripted_s"] == pytest.approx(a["delay_s"], abs=0.2)
    fix_t, fix_type = a["last_fix"]
    assert fix_type >= 3 and 0.0 <= a["play_s"] - fix_t <= 1.0
    gi = gps_inputs(recs)
    assert all(g["gps_id"] == 1 for g in gi)
    assert all(("ignored" in g) == (g["fix_type"] < 3) for g in gi)
    assert all(g["ignored"] == "by EKF3: fix_type < 3" for g in gi if g["fix_type"] < 3)
    flying = [g["err_h_m"] for g in gi if g["state_play_s"] > a["play_s"] and g["fix_type"] >= 3 and "err_h_m" in g]
    assert len(flying) >= 20 and np.median(flying) < 3.0  # the truth follows the flight as it was delayed
    hb, texts = _heartbeats_and_texts(tmp_path / "c.mcap")
    assert True in hb and hb[0] is False  # the companion saw the vehicle arm
    assert not any("Bad fix" in t for t in texts) or a["delay_s"] > 0


def test_mav_gps_instance_refuses_to_arm_without_the_companions_fix(tmp_path):
    """In shadow mode the companion sends nothing: the vehicle with a MAVLink GPS2 never arms, says
    "PreArm: GPS 2: Bad fix" (the companion records it) and holds on the ground; the record says so."""
    sim = Sim(tmp_path, "--gps-mav-instance", 1)
    comp = run_companion(sim.port, tmp_path / "c.mcap", "--inject", "shadow", "--duration", 16)
    recs = wait_for_records(sim, lambda rs: any(r["event"] == "arming_refused" for r in rs), timeout_s=120.0)
    _out, err = comp.communicate(timeout=90)  # then the rest of its 16 s: the sim keeps retrying meanwhile
    recs = sim.finish()
    assert comp.returncode == 0 and "Traceback" not in err, err
    refused = [r for r in recs if r["event"] == "arming_refused"]
    assert refused and refused[0]["text"] == "PreArm: GPS 2: Bad fix" and refused[0]["last_fix"] is None
    assert refused[0]["play_s"] == pytest.approx(8.1, abs=0.5)
    assert not any(r["event"] == "armed" for r in recs) and not gps_inputs(recs)
    end = recs[-1]
    assert end["event"] == "end" and end["armed_at_s"] is None
    assert end["arm_delay_s"] >= 3.0 and end["arm_delay_s"] == pytest.approx(end["play_s"] - 8.1, abs=1.5)
    hb, texts = _heartbeats_and_texts(tmp_path / "c.mcap")
    assert len(hb) >= 12 and not any(hb)  # held disarmed all along
    assert "PreArm: GPS 2: Bad fix" in texts
    s = summarize(tmp_path / "c.mcap")
    assert {t.topic: t.count for t in s.topics}["/inject/gps_input"] > 50  # computed, recorded, never sent
