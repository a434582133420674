"""Training: validated YAML configs (:mod:`~gym_gridloc_agents.training.config`), training that
never loses work (:mod:`~gym_gridloc_agents.training.train`) and the warm start
(:mod:`~gym_gridloc_agents.training.pretrain`). The environments (:mod:`gym_gridloc_agents.envs`)
and the features extractors the configs name (:mod:`gym_gridloc_agents.features`, which saved
models refer to by that name) are shared, at the package's top."""
