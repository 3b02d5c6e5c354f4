"""``invent goto``'s logic, pure (no zenoh): :mod:`~services.goto.core` says what the tool prints of
a goal and when, and which exit status its outcome gives. The command and its zenoh session are
``services/cli/goto.py``; the drive that runs the goal, ``services/drive/`` (docs/protocol.md
section 7.3)."""
