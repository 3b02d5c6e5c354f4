"""``invent localization``: the localization stub (docs/localization.md).

- :mod:`~services.localization.core`: the fix schedule and its noise (pure, no zenoh);
- :mod:`~services.localization.service`: the service around it.
"""
