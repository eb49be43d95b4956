"""Benchmarks of the live companion: GPS_INPUT latency, replay throughput, the long GNSS denial run, SITL A/B."""

import socket


def free_port() -> int:
    """A TCP port nobody listens on at 127.0.0.1 right now (for a simulator / companion pair)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
