"""``invent drive``: the velocity source (docs/drive.md, docs/protocol.md section 7).

- :mod:`~services.drive.scenarios`: scenarios, built-in and from files, played tick by tick (pure);
- :mod:`~services.drive.path_following`: pure pursuit with turn-in-place (pure);
- :mod:`~services.drive.service`: the service around them.
"""
