"""Nothing lost, the values that reach a library: every option, keyword and config value is
checked first (one error naming it), model metadata is read defensively, and learning curves
count seeds and baselines only where they are what they say."""

from __future__ import annotations

import importlib.util
import json

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc  # noqa: F401 - registers the environments
from gym_gridloc_agents.cli import main
from gym_gridloc_agents.policies import POLICY_NAMES, make_policy


def fails(capsys, argv, says, status=2):
    assert main(argv) == status
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "error:" in err and says in err, err
    return err


@pytest.mark.parametrize("name", POLICY_NAMES)
def test_every_policy_refuses_an_unknown_option(name):
    model = gym.make("ColourGrid-v0").unwrapped.model
    with pytest.raises(ValueError, match="takes no option 'bogus'"):
        make_policy(name, model, env_id="ColourGrid-v0", bogus=1)


@pytest.mark.skipif(importlib.util.find_spec("pomdp_py") is None, reason="needs pomdp_py (the planning extra)")
def test_a_fractional_particle_count_is_refused():
    from gym_gridloc.interop import to_pomdp_py

    env = gym.make("ColourGrid-v0")
    env.reset(seed=0)
    pp = to_pomdp_py(env.unwrapped.model, seed=0)
    belief = env.unwrapped.exact_filter.full_belief
    for n in (1.5, 0, -2, "3", True):
        with pytest.raises(ValueError, match="n must be a whole number >= 1"):
            pp.particles(belief, n)
    assert len(pp.particles(belief, 3).particles) == 3 and len(pp.particles(belief, 2.0).particles) == 2
