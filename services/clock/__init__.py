"""Simulation time, as every service follows the simulator's clock.

- :mod:`~services.clock.sim_time`: stamps, their checks, periodic schedules, the restart rule (pure);
- :mod:`~services.clock.lockstep`: the lockstep protocol's pure logic: tick barrier, holds, owed stamps;
- :mod:`~services.clock.sim_watch`: the simulator's liveliness token, and inputs that wait for its clock.
"""
