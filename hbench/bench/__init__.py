"""Benchmark execution: one cell into tidy rows, the metrics, the worker processes, and the
conformance checks every method must pass."""
