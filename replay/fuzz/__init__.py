"""Fuzzing the companion: mutated real logs through ``companion replay`` and a hostile live link against
``companion run``, each checked against the fault-tolerance properties.

- :mod:`replay.fuzz.logs`: the clean inputs (prefixes and windows of the shared real logs) and a small parser
  of the two log formats (dataflash records and FMT formats; tlog records and MAVLink frames), enough to find
  and rewrite a record's time, a float, a type or length byte.
- :mod:`replay.fuzz.mutate`: the seeded mutator (``numpy.random.Generator``), one function per kind.
- :mod:`replay.fuzz.runner`: runs ``companion replay`` on a file (a subprocess, or a forked child of an
  already-importing process for CI speed) with a hard time-out and memory cap; measures wall/CPU/peak RSS.
- :mod:`replay.fuzz.properties`: what every run must satisfy and the outcome table.
- :mod:`replay.fuzz.link`: the live-link fuzzer: an autopilot peer on loopback UDP/TCP that feeds
  ``companion run`` garbage, bad CRCs, mixed MAVLink 1/2, extreme fields, time jumps, bursts and a SIGTERM.
- ``python -m replay.fuzz --mutants N --seed S``: the benchmark; prints the table and writes
  ``replay/results/fuzz.md``.
"""
