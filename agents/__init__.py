"""Policies, training and evaluation for gym_gridloc (see the README).

- :mod:`agents.policies`: ``random``, ``greedy``, ``greedy2``, ``ppo``, ``recurrent`` behind one
  interface, ``policy.reset(seed)`` then ``policy.act(observation, belief) -> action``;
- :mod:`agents.config` / :mod:`agents.train`: YAML configs, training that never loses work, safe
  model loading (model zips are pickles: trusted sources only);
- :mod:`agents.bench`: the localisation-speed benchmark;
- :mod:`agents.cli`: the ``gridloc`` command (``gridloc train CONFIG``, ``gridloc bench ...``).
"""

from agents.policies import POLICY_NAMES, Policy, default_model_path, make_policy

__all__ = ["POLICY_NAMES", "Policy", "default_model_path", "make_policy"]
