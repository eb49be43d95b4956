"""Gravity-aided navigation benchmarks, part II (issue 6): Li 2022 Viterbi design, Liu 2019 GF-PF design."""
