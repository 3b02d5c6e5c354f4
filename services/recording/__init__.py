"""Watch and record: MCAP recordings, run reports, replay and the live Foxglove view.

- :mod:`~services.recording.record`: ``invent record`` and the recording ``invent up`` makes of its journals;
- :mod:`~services.recording.mcap_files`: the MCAP file format, reading it back, a run's report from it;
- :mod:`~services.recording.report`: the metrics, the loop's health, the plots (no zenoh);
- :mod:`~services.recording.scene`: the robot's Foxglove scene (no zenoh);
- :mod:`~services.recording.replay`: ``invent replay``;
- :mod:`~services.recording.view`: ``invent view``, the live Foxglove WebSocket server.
"""
