"""``break_cycles``: a policy of the belief that acts with its most probable action samples one
where the belief comes back within an episode (and only there); the option is read from the
model's metadata unless given, refused where the belief does not decide, seeded per episode, and
a config says it."""

from __future__ import annotations

import json
import shutil

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc
from gym_gridloc_agents.learned import PPOPolicy, default_model_path
from gym_gridloc_agents.policies import make_policy
from gym_gridloc_agents.training.config import ConfigError, validate_config


_NO_WALLS = np.zeros(4, dtype=np.int8)  # a WindyMaze reading


class _Recording:
    """An sb3 stand-in: records how it was asked to act, and acts 0."""

    def __init__(self) -> None:
        self.asked: list[bool] = []

    def predict(self, observation, deterministic=True):
        self.asked.append(bool(deterministic))
        return np.array(0), None


def _policy(**kw):
    model = gym.make("WindyMaze-v0").unwrapped.model
    sb3 = _Recording()
    return PPOPolicy(model, sb3_model=sb3, wrapper={"belief": True, "flatten": True}, **kw), sb3, model


def _beliefs(model):
    rng = np.random.default_rng(0)
    out = []
    for _ in range(2):
        b = rng.random(model.belief_shape) * model.state_mask
        out.append(b / b.sum())
    return out


def test_it_samples_where_a_belief_comes_back_and_only_there():
    policy, sb3, model = _policy(break_cycles=True)
    b1, b2 = _beliefs(model)
    policy.reset(seed=0)
    for b in (b1, b2, b1, b2, b1 + 1e-15 * b2):  # the last: b1 but for its last bits
        policy.act(_NO_WALLS, b)
    assert sb3.asked == [True, True, False, False, False]
    policy.reset(seed=1)  # a new episode remembers nothing
    policy.act(_NO_WALLS, b2)
    assert sb3.asked[-1] is True


@pytest.mark.parametrize("kw, asked", [({}, [True, True, True]), ({"deterministic": False, "break_cycles": True}, [False] * 3)])
def test_without_it_or_when_sampling_anyway_nothing_changes(kw, asked):
    policy, sb3, model = _policy(**kw)
    b1, _ = _beliefs(model)
    policy.reset(seed=0)
    for _ in range(3):
        policy.act(_NO_WALLS, b1)
    assert sb3.asked == asked


def test_the_metadata_decides_unless_told_and_other_values_are_refused(tmp_path):
    model = gym.make("WindyMaze-v0").unwrapped.model
    shipped = default_model_path("WindyMaze-v0", "ppo")
    path = tmp_path / "m.zip"
    shutil.copy(shipped, path)
    meta = json.loads(shipped.with_suffix(".json").read_text())
    path.with_suffix(".json").write_text(json.dumps({**meta, "break_cycles": True}))
    assert make_policy("ppo", model, env_id="WindyMaze-v0", path=path).break_cycles is True
    assert make_policy("ppo", model, env_id="WindyMaze-v0", path=path, break_cycles=False).break_cycles is False
    assert make_policy("ppo", model, env_id="WindyMaze-v0").break_cycles is bool(meta.get("break_cycles", False))
    with pytest.raises(ValueError, match="break_cycles must be true, false or None, got 'yes'"):
        make_policy("ppo", model, env_id="WindyMaze-v0", break_cycles="yes")
    ring = gym.make("RingSensor8x8-v0").unwrapped.model
    with pytest.raises(ValueError, match="takes no option 'break_cycles'"):
        make_policy("recurrent", ring, env_id="RingSensor8x8-v0", break_cycles=True)


def test_a_seeded_episode_is_the_same_every_time():
    env = gym_gridloc.HMMBeliefWrapper(gym.make("DepthMaze-v0", size=15, episode_length=40, reward="belief"))
    policy = make_policy("ppo", env.unwrapped.model, env_id="DepthMaze-v0", env_kwargs={"size": 15, "episode_length": 40},
                         break_cycles=True)
    from gym_gridloc_agents.evaluation.rollout import rollout

    runs = [rollout(env, policy, 7, keep=True).actions for _ in range(2)]
    assert runs[0] == runs[1] and len(runs[0]) == 40


def test_a_config_says_it_for_policies_of_the_belief(tmp_path):
    raw = {"algo": "ppo", "env_id": "WindyMaze-v0", "wrapper": {"belief": True, "flatten": True}, "policy": "MlpPolicy",
           "total_timesteps": 64, "output": str(tmp_path / "m.zip")}
    assert validate_config(dict(raw))["break_cycles"] is False
    assert validate_config({**raw, "break_cycles": True})["break_cycles"] is True
    with pytest.raises(ConfigError, match="break_cycles must be true or false"):
        validate_config({**raw, "break_cycles": "yes"})
    recurrent = {"algo": "recurrent_ppo", "env_id": "WindyMaze-v0", "wrapper": {"belief": False}, "total_timesteps": 64,
                 "output": str(tmp_path / "r.zip"), "break_cycles": True}
    with pytest.raises(ConfigError, match="break_cycles needs a policy of the belief"):
        validate_config(recurrent)
