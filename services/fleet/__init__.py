"""A fleet: several robots in one world, pure: the fleet file (:mod:`~services.fleet.description`)
and what a fleet run says of its robots together (:mod:`~services.fleet.summary`). ``invent up
--fleet`` is ``services/launch/fleet.py``."""
