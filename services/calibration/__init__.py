"""Odometry calibration, pure (no zenoh): UMBmark's formulas (``umbmark.py``) and the file of
return positions measured by hand (``measured.py``). ``invent calibrate umbmark`` drives the
square in the simulator with ``services/launch/calibrate.py``."""
