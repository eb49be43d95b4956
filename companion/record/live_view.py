"""Live view: the record's messages served over the Foxglove WebSocket protocol while flying.

``companion run --foxglove [HOST:]PORT`` starts a :class:`LiveView` (Foxglove's own server from the
maintained ``foxglove-sdk`` package) and gives it to the recorder, which hands it every message it
writes: same topic, same JSON schema, same payload bytes and the same log time as in the MCAP file.
So Foxglove's Map panel shows the fused, predicted, GNSS and GPS_INPUT tracks live, and a record
opened later shows the same thing. Off by default; it binds to the loopback interface unless a host
is given (the protocol has no authentication: expose it only on a trusted network).

The server runs in the SDK's own threads; publishing is a non-blocking hand-off (a slow client loses
its oldest messages, see ``message_backlog_size``), so a viewer never holds back the navigator.

Which viewers connect: foxglove-sdk's server speaks the WebSocket subprotocol ``foxglove.sdk.v1`` only (since the
SDK's first release, rust/foxglove/src/websocket/handshake.rs), and answers a client that does not offer it with HTTP
400. Foxglove's app offers it, Lichtblick from 1.22.1 on (the release that added it); Foxglove Studio 1.x and
Lichtblick up to 1.22.0 offer ``foxglove.websocket.v1`` alone and are refused. The SDK logs such a client as a bare "handshake failed"
through Python's logging (logger ``foxglove``): :class:`_SdkLog` says it in the companion's log with the reason.
``close()`` stops the server, which sends every client a close frame.
"""

from __future__ import annotations

import logging
import re

log = logging.getLogger(__name__)

DEFAULT_HOST = "127.0.0.1"
#: the only WebSocket subprotocol foxglove-sdk's server accepts
SUBPROTOCOL = "foxglove.sdk.v1"
_REFUSED = re.compile(r"Dropping client (?P<client>\S+): handshake failed")
_CLIENT = re.compile(r"(?P<what>Registered|Unregistered) client (?P<client>\S+)$")


class _SdkLog(logging.Handler):
    """The SDK's own log records (logger ``foxglove``, forwarded from its Rust core) in the companion's log: a refused
    client at WARNING with the reason, clients coming and going at INFO, the rest at DEBUG (errors as they are)."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
        except Exception:  # noqa: BLE001 - a malformed record must not stop the SDK's thread
            return
        refused = _REFUSED.search(text)
        if refused:
            log.warning("Foxglove client %s refused: WebSocket handshake failed; this server (foxglove-sdk) accepts "
                        "only clients offering the subprotocol %s (Foxglove, Lichtblick >= 1.22.1), not "
                        "foxglove.websocket.v1 alone (Foxglove Studio 1.x, Lichtblick <= 1.22.0), and no plain HTTP "
                        "request", refused["client"], SUBPROTOCOL)
            return
        client = _CLIENT.search(text)
        if client:
            log.info("Foxglove client %s %s", client["client"],
                     "connected" if client["what"] == "Registered" else "disconnected")
            return
        log.log(record.levelno if record.levelno >= logging.WARNING else logging.DEBUG, "foxglove-sdk: %s", text)


def _route_sdk_log() -> None:
    """Send the SDK's logger to :class:`_SdkLog` (once per process) instead of Python's bare last-resort output."""
    sdk = logging.getLogger("foxglove")
    if not any(isinstance(h, _SdkLog) for h in sdk.handlers):
        sdk.addHandler(_SdkLog())
        sdk.setLevel(logging.INFO)  # (clients coming and going are INFO; the root logger would drop them)
        sdk.propagate = False


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

        _route_sdk_log()
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
        """Stop the server: every client gets a close frame (the SDK's stop returns once it has shut down)."""
        if not self._closed:
            self._closed = True
            self._server.stop()
