"""A fleet: several robots in one world (the fleet file, and ``invent up --fleet``)."""
