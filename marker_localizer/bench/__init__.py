"""Benchmarks: accuracy and speed of the detector against peers, on rendered and real frames."""
