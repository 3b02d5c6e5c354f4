"""Odometry calibration, pure (no zenoh): UMBmark's formulas (``umbmark.py``), a benchmark's runs
and what the benchmarks conclude (``benchmark.py``), ``invent calibrate umbmark``'s settings as
typed values (``settings.py``) and the file of return positions measured by hand
(``measured.py``). ``invent calibrate umbmark`` drives the square in the simulator with
``services/launch/calibrate.py`` and ``umbmark_runs.py``."""
