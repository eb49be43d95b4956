"""Benchmarks of the live companion: GPS_INPUT latency, replay throughput and the long GNSS denial run."""
