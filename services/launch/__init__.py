"""How a run starts and ends: ``invent up``, for one robot or a fleet.

- :mod:`~services.launch.plan`: the run asked for, typed (:class:`~services.launch.plan.UpPlan`);
- :mod:`~services.launch.up`: ``invent up``'s one entry (:func:`~services.launch.up.run_up`), one robot's
  whole loop and its run report;
- :mod:`~services.launch.fleet`: ``invent up --fleet FILE``, every robot of a fleet in one world;
- :mod:`~services.launch.run`: what both share: the run's files, its sessions' access, launching
  the services and watching them, the live view, the exit status;
- :mod:`~services.launch.children`: the services as child processes (:class:`Supervisor`);
- :mod:`~services.launch.composition`: ``--composed``, the same services in one process;
- :mod:`~services.launch.recorder`: the run's ``run.mcap``, made of the services' journals.
"""
