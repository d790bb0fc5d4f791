"""Benchmarks (``make bench``): fit speed, loop latency, scale, precision, leader-follower baseline."""
