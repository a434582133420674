"""Training: validated YAML configs (:mod:`~gym_gridloc_agents.training.config`), the environment
factories and the SB3 adapter of the vector env (:mod:`~gym_gridloc_agents.training.envs`),
training that never loses work (:mod:`~gym_gridloc_agents.training.train`) and the warm start
(:mod:`~gym_gridloc_agents.training.pretrain`). The features extractors the configs name are
:mod:`gym_gridloc_agents.features` (saved models refer to them by that name)."""
