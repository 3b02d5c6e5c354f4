"""How a run starts and ends: ``invent up``, for one robot or a fleet, and the other launchers.

- :mod:`~services.launch.plan`: the run asked for, typed (:class:`~services.launch.plan.UpPlan`);
- :mod:`~services.launch.up`: ``invent up``'s one entry and its one sequence
  (:func:`~services.launch.up.run_up`), of one robot or of a fleet;
- :mod:`~services.launch.robots`: what a run of one robot and of a fleet differ in, given to that
  sequence: each robot as its services start (:class:`Robot`), :class:`Robots`, :class:`Watch`;
- :mod:`~services.launch.one_robot`: one robot's own ways: its checks, ``--secure`` profile,
  watch and flat report;
- :mod:`~services.launch.fleet`: ``invent up --fleet FILE``'s own ways: every robot of a fleet in
  one world, each degrading alone, and the fleet's report;
- :mod:`~services.launch.run`: what both share: the run's files, its sessions' access, launching
  the services and watching them, the live view, the exit status;
- :mod:`~services.launch.children`: the services as child processes (:class:`Supervisor`);
- :mod:`~services.launch.composition`: ``--composed``, the same services in one process;
- :mod:`~services.launch.recorder`: the run's ``run.mcap``, made of the services' journals;
- :mod:`~services.launch.worker`: a composed fleet over several processes (``invent worker``);
- :mod:`~services.launch.ros2_run`: what ``--ros2`` adds, and ``invent ros2 --fleet``'s bridges;
- :mod:`~services.launch.calibrate` and :mod:`~services.launch.umbmark_runs`: ``invent calibrate
  umbmark``, its passes and its runs of the square.
"""
