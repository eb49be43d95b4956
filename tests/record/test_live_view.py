"""Live Foxglove view: a real WebSocket client (``websockets``) gets LocationFix messages from a real
``companion run`` process flying against the vehicle simulator.

The client offers both subprotocol names of the Foxglove WebSocket protocol: ``foxglove.websocket.v1``
(the published spec) and ``foxglove.sdk.v1`` (what foxglove-sdk 0.30 servers accept); the server picks one.
"""

from __future__ import annotations

import asyncio
import json
import signal
import struct
import subprocess
import time

import pytest

from companion.record.live_view import parse_endpoint
from tests.runtime.test_hil import Sim, run_companion

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01  # server -> client binary opcode


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


async def _receive_fixes(port: int, topics: set[str], want_each: int, timeout_s: float) -> list[dict]:
    """LocationFix messages from the server until every topic in ``topics`` gave ``want_each``."""
    import websockets

    async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        assert ws.subprotocol in SUBPROTOCOLS
        subscribed: dict[int, str] = {}
        got: list[dict] = []
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout_s
        while any(sum(f["_topic"] == t for f in got) < want_each for t in topics):
            msg = await asyncio.wait_for(ws.recv(), timeout=max(0.1, end - loop.time()))
            if isinstance(msg, str):
                op = json.loads(msg)
                if op.get("op") == "advertise":
                    subs = []
                    for ch in op["channels"]:
                        if ch["topic"] in topics:
                            assert ch["schemaName"] == "foxglove.LocationFix" and ch["encoding"] == "json"
                            assert json.loads(ch["schema"])["title"] == "foxglove.LocationFix"
                            sub_id = len(subscribed) + 1
                            subscribed[sub_id] = ch["topic"]
                            subs.append({"id": sub_id, "channelId": ch["id"]})
                    if subs:
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            elif msg[0] == MESSAGE_DATA:
                sub_id, log_ns = struct.unpack_from("<IQ", msg, 1)
                fix = json.loads(msg[13:])
                fix["_topic"], fix["_log_ns"] = subscribed[sub_id], log_ns
                got.append(fix)
        return got


def test_foxglove_client_receives_live_location_fixes(tmp_path):
    sim = Sim(tmp_path, "--start", 20, "--end", 80)
    comp = run_companion(sim.port, tmp_path / "c.mcap", "--foxglove", "0", "--duration", 60)
    try:
        port, _ = _wait_for_port(comp, 60)
        topics = {"/map/fused", "/map/gnss", "/map/gps_input"}  # the fused, GNSS and GPS_INPUT tracks
        fixes = asyncio.run(_receive_fixes(port, topics, want_each=10, timeout_s=60))
    finally:
        if comp.poll() is None:
            comp.send_signal(signal.SIGTERM)
        out, err = comp.communicate(timeout=60)
        sim.finish()
    assert "Traceback" not in err, err
    assert {f["_topic"] for f in fixes} == topics, [f["_topic"] for f in fixes]
    for f in fixes:
        assert -90 <= f["latitude"] <= 90 and -180 <= f["longitude"] <= 180 and not (f["latitude"] == 0 == f["longitude"])
        assert len(f["position_covariance"]) == 9
        assert f["_log_ns"] > 1_600_000_000 * 10**9  # the record's log time: UTC (the simulator's SYSTEM_TIME or host)
