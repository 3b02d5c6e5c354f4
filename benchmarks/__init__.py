"""Benchmarks of invent-zenoh (``make bench``); never part of ``make test``."""
