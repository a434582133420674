"""gym_gridloc's agents: policies, planners, training and evaluation (installed as
``gym_gridloc_agents``; needs the ``rl`` extra). Grouped as they are used; at the top, what every
group shares:

- :mod:`~gym_gridloc_agents.policies`: the one table of policies (``random``, ``greedy``,
  ``greedy2``, the planners, ``ppo``, ``distilled``, ``recurrent``) behind one interface,
  ``policy.reset(seed, model)`` then ``policy.act(observation, belief)``; the shipped models are in
  ``models/`` beside it;
- :mod:`~gym_gridloc_agents.base`, :mod:`~gym_gridloc_agents.values`,
  :mod:`~gym_gridloc_agents.envs`, :mod:`~gym_gridloc_agents.features`,
  :mod:`~gym_gridloc_agents.files`: the ``Policy`` base, the ``KEY=VALUE`` reader, the environment
  factories and the SB3 adapter of the vector env, the SB3 features extractors (saved models name
  them), atomic writes, model metadata and safe model loading (model zips are pickles: trusted
  sources only);
- :mod:`~gym_gridloc_agents.planners`: the planners (with ``optimal`` and ``pomcp``);
- :mod:`~gym_gridloc_agents.training`: configs, training, the warm start;
- :mod:`~gym_gridloc_agents.evaluation`: one episode (``rollout``), the benchmark, statistics,
  tables and plots;
- :mod:`~gym_gridloc_agents.sweeps`: ``gridloc sweep`` on Ray Tune;
- :mod:`~gym_gridloc_agents.viewer`: ``gridloc play``/``view``;
- :mod:`~gym_gridloc_agents.cli`: the ``gridloc`` command.
"""

from gym_gridloc_agents.policies import POLICY_NAMES, Policy, default_model_path, make_policy

__all__ = ["POLICY_NAMES", "Policy", "default_model_path", "make_policy"]
