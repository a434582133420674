"""The learned policies' history (gym_gridloc_agents/history.py): the last actions and the steps
left, encoded the same in training (one env, the native vector env) and when the policy acts."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from gym_gridloc_agents.envs import SB3VecEnv, make_env
from gym_gridloc_agents.evaluation.rollout import rollout
from gym_gridloc_agents.history import History, HistoryWrapper, episode_limit
from gym_gridloc_agents.policies import make_policy
from gym_gridloc_agents.training.config import ConfigError, validate_config
from gym_gridloc_agents.training.train import train

FLAT = {"belief": True, "flatten": True, "full_state": True, "map": True}


def test_features_are_the_last_actions_newest_first_and_the_steps_left():
    h = History(3, actions=2, horizon=10, limit=12, n=2)
    assert h.size == 7
    assert np.array_equal(h.features(), [[0, 0, 0, 0, 0, 0, 1]] * 2)  # no action yet; 12 left, seen as 10
    h.record(np.array([2, 0]))
    h.record(np.array([1, 1]))
    f = h.features()
    assert np.array_equal(f[0, :6], [0, 1, 0, 0, 0, 1]) and np.array_equal(f[1, :6], [0, 1, 0, 1, 0, 0])
    assert np.allclose(f[:, 6], 1.0)  # 10 left
    for _ in range(5):
        h.record(np.array([0, 0]))
    assert np.allclose(h.features()[:, 6], 0.5)  # 5 left of a horizon of 10
    h.reset(np.array([False, True]))
    assert np.array_equal(h.features()[1], [0, 0, 0, 0, 0, 0, 1]) and h.features()[0, 0] == 1
    for _ in range(20):
        h.record(np.array([0, 0]))
    assert h.features()[0, 6] == 0.0  # never below 0 past the end


@pytest.mark.filterwarnings("ignore:.*is different from the unwrapped version")
def test_the_wrapper_passes_check_env_and_counts_down():
    env = make_env("DepthMaze-v0", {"size": 7, "episode_length": 6}, {**FLAT, "past_actions": 2, "steps_left": 6})
    assert isinstance(env, HistoryWrapper) and episode_limit(env) == 6
    check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=1)
    assert obs.shape == env.observation_space.shape and obs[-1] == 1.0 and not obs[-7:-1].any()
    for t in range(1, 7):
        obs, *_ , truncated, _ = env.step(2)
        assert obs[-1] == pytest.approx((6 - t) / 6) and obs[-7 + 2] == 1.0  # the newest action: move (2)
    assert truncated
    dict_env = make_env("WindyMaze-v0", None, {"belief": True, "flatten": False, "past_actions": 3})
    assert dict_env.observation_space["history"].shape == (12,)
    check_env(dict_env, skip_render_check=True)
    assert episode_limit(gym.make("WindyMaze-v0")) == 100  # no episode_length: the step limit


def test_the_vector_env_keeps_a_history_per_episode():
    venv = SB3VecEnv.make("DepthMaze-v0", 3, belief="exact", flatten=True, full_state=True, map=True, size=7,
                          episode_length=4, history={"past_actions": 1, "steps_left": 4})
    assert venv.observation_space.shape[0] == venv.venv.single_observation_space.shape[0] + 4
    obs = venv.reset()
    assert np.allclose(obs[:, -1], 1.0) and not obs[:, -4:-1].any()
    for t in range(1, 5):
        venv.step_async(np.array([0, 1, 2]))
        obs, _, dones, infos = venv.step_wait()
        if t < 4:
            assert np.allclose(obs[:, -1], (4 - t) / 4) and np.array_equal(obs[:, -4:-1], np.eye(3))
    assert dones.all()  # every episode ended at 4 steps: a new one starts with a fresh history...
    assert np.allclose(obs[:, -1], 1.0) and not obs[:, -4:-1].any()
    for i in range(3):  # ...and the finished one's last observation keeps its own
        last = infos[i]["terminal_observation"]
        assert last[-1] == 0.0 and last[-4 + i] == 1.0


def test_the_time_step_counts_from_the_start_whatever_the_episode_length():
    for limit in (5, 15, 30, 60):  # the clock of an episode of any length is that of the first steps of one of 30
        h = History(3, horizon=30, limit=limit, time_step=True)
        seen = [h.features()[0, 0]]
        for _ in range(40):
            h.record(np.array([0]))
            seen.append(h.features()[0, 0])
        assert np.array_equal(seen, np.float32([max(30 - t, 0) / 30 for t in range(41)]))
    left, time = History(3, actions=2, horizon=30, limit=30, n=2), History(3, actions=2, horizon=30, n=2, time_step=True)
    for t in range(35):  # episodes of the horizon's length: the same features as the steps left
        assert np.array_equal(left.features(), time.features())
        left.record(np.array([t % 3, 2])), time.record(np.array([t % 3, 2]))
    short = History(3, horizon=30, limit=15)
    assert short.features()[0, 0] == 0.5  # the steps left of a shorter episode: what the first step shows differs


def test_time_step_and_steps_left_train_the_same_model_on_episodes_of_the_horizon(tmp_path):
    import torch

    weights = []
    for clock in ("steps_left", "time_step"):
        cfg = {"algo": "ppo", "env_id": "DepthMaze-v0", "env_kwargs": {"size": 7, "episode_length": 8, "reward": "belief"},
               "wrapper": {**FLAT, "past_actions": 2, clock: 8}, "vec_env": "native", "n_envs": 4, "seed": 3,
               "total_timesteps": 256, "policy_kwargs": {"net_arch": [16]},
               "hyperparams": {"n_steps": 32, "batch_size": 64, "n_epochs": 2}, "eval_freq": 0,
               "output": str(tmp_path / f"{clock}.zip"), "checkpoint_dir": str(tmp_path / clock)}
        train(cfg, progress_bar=False)
        policy = make_policy("ppo", make_env("DepthMaze-v0", {"size": 7, "episode_length": 8}).unwrapped.model,
                             env_id="DepthMaze-v0", env_kwargs={"size": 7, "episode_length": 8}, path=tmp_path / f"{clock}.zip")
        weights.append(policy.sb3.policy.state_dict())
        assert policy.history.time_step == (clock == "time_step")
    assert weights[0].keys() == weights[1].keys()
    assert all(torch.equal(weights[0][k], weights[1][k]) for k in weights[0])


def test_a_model_that_sees_the_time_step_plays_a_shorter_episode_as_the_start_of_a_longer_one(tmp_path):
    cfg = {"algo": "ppo", "env_id": "DepthMaze-v0", "env_kwargs": {"size": 7, "episode_length": 12, "reward": "belief"},
           "wrapper": {**FLAT, "past_actions": 2, "time_step": 12}, "vec_env": "native", "n_envs": 4, "seed": 1,
           "total_timesteps": 128, "policy_kwargs": {"net_arch": [16]},
           "hyperparams": {"n_steps": 32, "batch_size": 64, "n_epochs": 1}, "eval_freq": 0,
           "output": str(tmp_path / "m.zip"), "checkpoint_dir": str(tmp_path / "ckpt")}
    train(cfg, progress_bar=False)
    played = []
    for length in (6, 12):
        kw = {"size": 7, "episode_length": length}
        env = make_env("DepthMaze-v0", kw)
        policy = make_policy("ppo", env.unwrapped.model, env_id="DepthMaze-v0", env_kwargs=kw, path=tmp_path / "m.zip")
        played.append(rollout(env, policy, seed=4, keep=True).actions)
    assert len(played[0]) == 6 and played[0] == played[1][:6]


def test_history_options_are_checked_in_configs():
    base = {"algo": "ppo", "env_id": "WindyMaze-v0", "total_timesteps": 64, "output": "m.zip"}
    for key, value, message in (("past_actions", -1, "wrapper.past_actions must be an integer from 0 to 32"),
                                ("past_actions", 2.5, "wrapper.past_actions must be an integer from 0 to 32"),
                                ("steps_left", 10**6, "wrapper.steps_left must be an integer from 0 \\(none\\) to 10000"),
                                ("time_step", -3, "wrapper.time_step must be an integer from 0 \\(none\\) to 10000")):
        with pytest.raises(ConfigError, match=message):
            validate_config({**base, "wrapper": {"belief": True, "flatten": True, key: value}})
    with pytest.raises(ConfigError, match="wrapper.steps_left and time_step are two clocks: give one of them"):
        validate_config({**base, "wrapper": {"belief": True, "flatten": True, "steps_left": 10, "time_step": 10}})


def test_a_model_that_sees_its_history_acts_with_it(tmp_path):
    cfg = {"algo": "ppo", "env_id": "DepthMaze-v0", "env_kwargs": {"size": 7, "episode_length": 8, "reward": "belief"},
           "wrapper": {**FLAT, "past_actions": 3, "steps_left": 8}, "vec_env": "native", "n_envs": 4, "seed": 2,
           "total_timesteps": 256, "policy_kwargs": {"net_arch": [16]},
           "hyperparams": {"n_steps": 32, "batch_size": 64, "n_epochs": 1}, "eval_freq": 128, "eval_episodes": 3,
           "output": str(tmp_path / "m.zip"), "checkpoint_dir": str(tmp_path / "ckpt")}
    train(cfg, progress_bar=False)
    env = make_env("DepthMaze-v0", {"size": 7, "episode_length": 12})
    policy = make_policy("ppo", env.unwrapped.model, env_id="DepthMaze-v0", env_kwargs={"size": 7, "episode_length": 12},
                         path=tmp_path / "m.zip")
    assert policy.history is not None and policy.history.limit == 12  # counts down from the episode it acts in
    seen = []
    predict = policy.sb3.predict
    policy.sb3.predict = lambda obs, **kw: (seen.append(np.array(obs)), predict(obs, **kw))[1]
    ep = rollout(env, policy, seed=0, keep=True)
    assert ep.steps == 12 and len(seen) == 12
    for t, obs in enumerate(seen):
        assert obs[-1] == pytest.approx(min(12 - t, 8) / 8)
        past = obs[-10:-1].reshape(3, 3)
        for j in range(3):  # the newest first, zeros before the first step
            assert (past[j].argmax() == ep.actions[t - 1 - j] and past[j].sum() == 1) if t - 1 - j >= 0 else not past[j].any()
    policy.reset(seed=1)
    assert not policy.history.features()[0, :-1].any()
