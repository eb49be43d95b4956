"""Benchmark and test harness: GNSS-denial runs, error against truth, the Monte Carlo executor, results files,
the naive baselines (hold last fix, constant velocity, withheld GNSS) and the recorder throughput bench."""
