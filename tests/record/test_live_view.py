"""Live Foxglove view: a real WebSocket client (``websockets``) gets the Map tracks and the autopilot's Log from a real
``companion run`` process flying against the vehicle simulator, and a close frame when it stops.

The client offers both subprotocol names of the Foxglove WebSocket protocol: ``foxglove.websocket.v1``
(the published spec) and ``foxglove.sdk.v1`` (what foxglove-sdk 0.30 servers accept); the server picks one.
"""

from __future__ import annotations

import asyncio
import json
import re
import signal
import struct
import subprocess
import threading
import time

import pytest

from companion.record.live_view import parse_endpoint
from tests.runtime.test_hil import Sim, run_companion

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01  # server -> client binary opcode
RESUBSCRIBE_S = 5.0


def test_parse_endpoint():
    assert parse_endpoint("8765") == ("127.0.0.1", 8765)
    assert parse_endpoint("0.0.0.0:9000") == ("0.0.0.0", 9000)
    assert parse_endpoint("[::1]:9000") == ("::1", 9000)
    for bad in ("x", "host:", "1:99999"):
        with pytest.raises(ValueError):
            parse_endpoint(bad)


def _wait_for_port(proc, deadline_s: float) -> tuple[int, list[str]]:
    seen = []
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        line = proc.stderr.readline()
        if not line:
            break
        seen.append(line)
        if "Foxglove live view on ws://" in line:
            return int(line.split("ws://", 1)[1].split()[0].rsplit(":", 1)[1]), seen
    raise AssertionError("no Foxglove server line from companion run: " + "".join(seen))


async def _view(port: int, want: dict[str, int], timeout_s: float, stop) -> tuple[list[dict], dict]:
    """Subscribe to the topics of ``want`` (topic -> messages wanted) and decode their messages until each topic gave
    its count; then ``stop()`` the companion and wait for the server to close the connection. Returns the decoded
    messages and how the connection closed.

    foxglove-sdk can advertise a channel made on its first message a moment before it takes subscriptions to it
    ("attempted to subscribe to unknown channel"): a channel silent for ``RESUBSCRIBE_S`` is subscribed again under a
    new subscription id, as a client seeing no data would."""
    import websockets

    async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        assert ws.subprotocol in SUBPROTOCOLS
        subscribed: dict[int, str] = {}  # subscription id -> topic
        schema_of: dict[str, str] = {}
        pending: dict[int, tuple[str, float]] = {}  # channel id -> (topic, when subscribed), until its first message
        got: list[dict] = []
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout_s

        async def subscribe(channels: list[tuple[int, str]]) -> None:
            subs = []
            for chan, topic in channels:
                sub_id = len(subscribed) + 1
                subscribed[sub_id] = topic
                pending[chan] = (topic, loop.time())
                subs.append({"id": sub_id, "channelId": chan})
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

        while any(sum(f["_topic"] == t for f in got) < n for t, n in want.items()):
            if loop.time() > end:
                raise TimeoutError(f"after {timeout_s} s: {[f['_topic'] for f in got][-20:]}")
            stale = [(c, t) for c, (t, since) in pending.items() if loop.time() - since > RESUBSCRIBE_S]
            if stale:
                await subscribe(stale)
            try:
                msg = await asyncio.wait_for(ws.recv(), timeout=1.0)
            except TimeoutError:
                continue
            if isinstance(msg, str):
                op = json.loads(msg)
                if op.get("op") == "advertise":
                    mine = []
                    for ch in op["channels"]:
                        if ch["topic"] in want:
                            assert ch["encoding"] == "json" and json.loads(ch["schema"])["title"] == ch["schemaName"]
                            schema_of[ch["topic"]] = ch["schemaName"]
                            mine.append((ch["id"], ch["topic"]))
                    if mine:
                        await subscribe(mine)
            elif msg[0] == MESSAGE_DATA:
                sub_id, log_ns = struct.unpack_from("<IQ", msg, 1)
                m = json.loads(msg[13:])
                m["_topic"], m["_log_ns"] = subscribed[sub_id], log_ns
                m["_schema"] = schema_of[m["_topic"]]
                pending = {c: v for c, v in pending.items() if v[0] != m["_topic"]}
                got.append(m)
        stop()  # the companion stops (SIGTERM): the server should close the connection with a close frame
        try:
            while True:
                await asyncio.wait_for(ws.recv(), timeout=60)
        except websockets.ConnectionClosed:
            pass
        frame = ws.protocol.close_rcvd if hasattr(ws, "protocol") else ws.close_rcvd  # (websockets' new and legacy API)
        return got, {"close_frame": frame is not None, "code": ws.close_code}


async def _refused(port: int) -> int:
    """A client offering only the published spec's subprotocol (Foxglove Studio 1.x, Lichtblick <= 1.22.0): the HTTP
    status the server answers."""
    import websockets

    try:
        async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.websocket.v1"]):
            return 101
    except websockets.InvalidStatus as err:
        return err.response.status_code


def test_foxglove_client_receives_the_live_view_and_a_close_frame(tmp_path):
    """A real WebSocket client subscribes to the Map tracks (ours, the receiver's, GPS_INPUT's and the autopilot's
    own) and the autopilot's Log and decodes them; a client the SDK refuses is logged with the reason in the
    companion's log format; stopping `run` closes the connection with a close frame."""
    # the simulated autopilot has the companion as GPS 2 and, as the companion only shadows, refuses to arm: its
    # STATUSTEXT "PreArm: GPS 2: Bad fix" comes at the arming attempt (8 s after the companion connected) and every
    # 30 s after, on the vehicle that waits on the ground
    sim = Sim(tmp_path, "--gps-mav-instance", 1)
    comp = run_companion(sim.port, tmp_path / "c.mcap", "--foxglove", "0")
    got, closed, failure, rest, refused, stopped = [], {}, None, [], None, []

    def stop():
        stopped.append(True)
        comp.send_signal(signal.SIGTERM)

    drain = threading.Thread(target=lambda: rest.extend(comp.stderr), daemon=True)  # a full stderr pipe would block it
    try:
        port, seen = _wait_for_port(comp, 120)
        rest.extend(seen)
        drain.start()
        refused = asyncio.run(_refused(port))
        tracks = {"/map/fused", "/map/gnss", "/map/gps_input", "/map/autopilot"}
        try:
            got, closed = asyncio.run(_view(port, {**dict.fromkeys(tracks, 10), "/log/autopilot": 1}, timeout_s=180,
                                            stop=stop))
        except Exception as exc:  # say what the companion said, not only that the socket closed
            failure = exc
    finally:
        if comp.poll() is None and not stopped:
            comp.send_signal(signal.SIGTERM)
        comp.wait(timeout=60)
        if drain.is_alive() or drain.ident is not None:
            drain.join(timeout=10)
        err = "".join(rest) if drain.ident is not None else comp.stderr.read()
        sim.finish()
    assert failure is None, f"{failure!r}; companion exit {comp.returncode}; stderr: {err[-3000:]}"
    assert "Traceback" not in err, err
    assert comp.returncode == 0, err[-2000:]  # SIGTERM: a clean stop
    # refused, and said so in the companion's own format (HH:MM:SS LEVEL logger: text), not a bare SDK line
    assert refused == 400
    said = [line for line in err.splitlines() if "refused" in line]
    assert len(said) == 1 and re.fullmatch(r"\d\d:\d\d:\d\d WARNING companion\.record\.live_view: Foxglove client "
                                           r"127\.0\.0\.1:\d+ refused: .*foxglove\.sdk\.v1.*", said[0]), said
    assert not [line for line in err.splitlines() if "handshake failed" in line and "companion." not in line]
    assert closed == {"close_frame": True, "code": closed["code"]} and closed["code"] != 1006, closed
    fixes = [m for m in got if m["_topic"].startswith("/map/")]
    assert {m["_topic"] for m in fixes} == tracks
    for f in fixes:
        assert f["_schema"] == "foxglove.LocationFix" and len(f["position_covariance"]) == 9
        assert -90 <= f["latitude"] <= 90 and -180 <= f["longitude"] <= 180 and not (f["latitude"] == 0 == f["longitude"])
        assert f["_log_ns"] > 1_600_000_000 * 10**9  # the record's log time: UTC (the simulator's SYSTEM_TIME or host)
        assert f["timestamp"]["sec"] * 10**9 + f["timestamp"]["nsec"] == f["_log_ns"]  # the same UTC in the payload
        assert f["frame_id"] == f["_topic"].rpartition("/")[2]  # each track its own frame
    logs = [m for m in got if m["_topic"] == "/log/autopilot"]
    assert logs and all(m["_schema"] == "foxglove.Log" for m in logs)
    assert {m["message"] for m in logs} == {"PreArm: GPS 2: Bad fix"} and {m["level"] for m in logs} == {5}  # CRITICAL
    assert {m["name"] for m in logs} == {"autopilot"}
    assert all(m["timestamp"]["sec"] * 10**9 + m["timestamp"]["nsec"] == m["_log_ns"] for m in logs)
