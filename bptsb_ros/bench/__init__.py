"""Benchmarks: ``bptsb bench`` (suite), its gang, MNIST and live rows, and the real-time and soak measurements.

Speeds are reported as ratios to an anchor measured in the same run (see docs/speed.md).
"""
