"""Navigation: how the drive finds its way to a goal (docs/navigation.md). Pure cores: the grids
(``grid.py``), map files (``map_file.py``), worlds rasterised into maps (``rasterize.py``), the costmap
(``costmap.py``), the planner (``planner.py``), the path tracker (``tracker.py``) and the navigator that
runs a goal with its recoveries (``navigator.py``)."""
