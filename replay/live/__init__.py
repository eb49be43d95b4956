"""Benchmarks against live autopilots (ArduPilot SITL): the process driver and its pure analysis."""
