"""Gravity-aided navigation scenarios and benchmarks (issue 5)."""
