"""Mapping: an occupancy grid built from a robot's scans and odometry, the odometry's drift corrected
by matching each scan against the map built so far (scan-to-map). Pure cores: the log-odds grid
(``occupancy.py``), the scan matcher (``matcher.py``), the builder fed poses and scans in time order,
recorded or live (``builder.py``: ``MapBuilder``), and a recording's messages made into a map
(``from_recording.py``; ``invent map --from run.mcap`` reads the file)."""
