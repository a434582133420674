"""gym_gridloc's agents: policies, planners, training and evaluation (installed as
``gym_gridloc_agents``; needs the ``rl`` extra).

- :mod:`~gym_gridloc_agents.policies`: ``random``, ``greedy``, ``greedy2``, ``ppo``, ``recurrent``
  behind one interface, ``policy.reset(seed, model)`` then ``policy.act(observation, belief)``;
- :mod:`~gym_gridloc_agents.rollout`: one episode of a policy (used by everything below);
- :mod:`~gym_gridloc_agents.envs`: environment factories and the SB3 adapter of the vector env;
- :mod:`~gym_gridloc_agents.files`: atomic writes, model metadata, safe model loading (model zips
  are pickles: trusted sources only);
- :mod:`~gym_gridloc_agents.config`, :mod:`~gym_gridloc_agents.train`,
  :mod:`~gym_gridloc_agents.pretrain`: YAML configs and training that never loses work;
- :mod:`~gym_gridloc_agents.bench`: the localisation-speed benchmark;
- :mod:`~gym_gridloc_agents.cli`: the ``gridloc`` command.
"""

from gym_gridloc_agents.policies import POLICY_NAMES, Policy, default_model_path, make_policy

__all__ = ["POLICY_NAMES", "Policy", "default_model_path", "make_policy"]
