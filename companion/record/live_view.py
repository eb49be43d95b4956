"""Live view: the record's messages served over the Foxglove WebSocket protocol while flying.

``companion run --foxglove [HOST:]PORT`` starts a :class:`LiveView` (Foxglove's own server from the
maintained ``foxglove-sdk`` package) and gives it to the recorder, which hands it every message it
writes: same topic, same JSON schema, same payload bytes and the same log time as in the MCAP file.
So Foxglove's Map panel shows the fused, predicted, GNSS and GPS_INPUT tracks live, and a record
opened later shows the same thing. Off by default; it binds to the loopback interface unless a host
is given (the protocol has no authentication: expose it only on a trusted network).

The server runs in the SDK's own threads; publishing is a non-blocking hand-off (a slow client loses
its oldest messages, see ``message_backlog_size``), so a viewer never holds back the navigator.
"""

from __future__ import annotations

import logging

log = logging.getLogger(__name__)

DEFAULT_HOST = "127.0.0.1"


def parse_endpoint(text: str) -> tuple[str, int]:
    """``PORT``, ``HOST:PORT`` or ``[IPv6]:PORT`` -> (host, port); ValueError when malformed."""
    host, sep, port_text = text.rpartition(":")
    if not sep:
        host = DEFAULT_HOST
    host = host.strip("[]") or DEFAULT_HOST
    try:
        port = int(port_text)
    except ValueError:
        raise ValueError(f"--foxglove {text!r}: expected [HOST:]PORT") from None
    if not 0 <= port <= 65535:
        raise ValueError(f"--foxglove {text!r}: port must be 0..65535 (0: any free port)")
    return host, port


class LiveView:
    """A Foxglove WebSocket server publishing what the recorder writes (see the module doc)."""

    def __init__(self, host: str = DEFAULT_HOST, port: int = 8765, *, name: str = "companion"):
        from companion.extras import require

        foxglove = require("foxglove", "foxglove", "the live Foxglove view (--foxglove)")

        self._foxglove = foxglove
        self._context = foxglove.Context()
        try:
            self._server = foxglove.start_server(name=name, host=host, port=port, context=self._context)
        except Exception as err:  # noqa: BLE001 - the SDK raises its own error types for a busy port
            raise OSError(f"Foxglove live view on {host}:{port}: {err}") from None
        self.host = host
        self.port = self._server.port
        self._channels: dict[str, object] = {}
        self._closed = False
        log.info("Foxglove live view on ws://%s:%d", host, self.port)

    def publish(self, topic: str, schema_name: str, schema_data: bytes, log_ns: int, data: bytes) -> None:
        if self._closed:
            return
        channel = self._channels.get(topic)
        if channel is None:
            schema = self._foxglove.Schema(name=schema_name, encoding="jsonschema", data=schema_data)
            channel = self._foxglove.Channel(topic, schema=schema, message_encoding="json", context=self._context)
            self._channels[topic] = channel
        channel.log(data, log_time=log_ns)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._server.stop()
