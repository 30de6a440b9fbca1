"""Benchmarks: the engine's speed against peer libraries, and the paper's experiments."""
