"""Benchmarks (not tests): time the kernels against library equivalents on the same data."""
