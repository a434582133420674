"""``gridloc sweep``: the checked specification (:mod:`~gym_gridloc_agents.sweeps.sweep_spec`), the
Ray Tune run (:mod:`~gym_gridloc_agents.sweeps.sweep`, the only module here importing Ray) and the
tables across seeds (:mod:`~gym_gridloc_agents.sweeps.sweep_results`)."""
