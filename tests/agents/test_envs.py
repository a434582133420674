"""Environment factories and the stable-baselines3 adapter of the native vector env."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from gym_gridloc_agents.envs import SB3VecEnv, check_environment, make_env


def test_stable_baselines3_trains_on_the_adapter():
    """The native vector env behind SB3."""
    import stable_baselines3 as sb3
    from stable_baselines3.common.vec_env import VecMonitor

    venv = SB3VecEnv.make("WindyMaze-v0", 8)
    venv.seed(4)
    obs = venv.reset()
    assert obs["belief"].shape == (8, 6, 7)
    # SB3's same-step autoreset: the finished episode's last observation is in the info.
    seen = False
    for _ in range(300):
        obs, rewards, dones, infos = venv.step(np.zeros(8, dtype=np.int64))
        assert rewards.dtype == np.float32
        for i in np.flatnonzero(dones):
            seen = True
            assert set(infos[i]["terminal_observation"]) == {"observation", "belief"}
            assert "TimeLimit.truncated" in infos[i]
    assert seen
    model = sb3.PPO("MultiInputPolicy", VecMonitor(SB3VecEnv.make("ColourGrid-v0", 4)), n_steps=64,
                    batch_size=64, n_epochs=1, seed=0, device="cpu")
    model.learn(512)
    assert model.num_timesteps >= 512


def test_the_adapter_refuses_fractional_actions_and_takes_whole_floats():
    venv = SB3VecEnv.make("ColourGrid-v0", 2)
    venv.reset()
    with pytest.raises(ValueError, match="actions must be integers"):
        venv.step(np.array([0.7, 1.2]))
    venv.step(np.array([1.0, 3.0]))  # whole numbers as floats are the same actions


def test_the_adapter_needs_a_gym_gridloc_vector_env():
    with pytest.raises(TypeError, match="needs a gym_gridloc native vector env"):
        SB3VecEnv(gym.make_vec("CartPole-v1", num_envs=2, vectorization_mode="sync"))


def test_make_env_and_check_environment():
    env = make_env("WindyMaze-v0")
    assert set(env.observation_space.spaces) == {"observation", "belief"}
    assert make_env("WindyMaze-v0", wrapper={"belief": False}).observation_space == gym.spaces.MultiBinary(4)
    with pytest.raises(ValueError, match="is not a gym_gridloc environment"):
        check_environment("CartPole-v1", {}, what="env", error=ValueError)
    with pytest.raises(ValueError, match=r"env: WindyMaze-v0 has no keyword 'slip' \(its keywords: drift, kidnap_prob, layout,"):
        check_environment("WindyMaze-v0", {"slip": 0.1}, what="env", error=ValueError)
    with pytest.raises(ValueError, match=r"does not build with \{'drift': 0.7\}: drift"):
        check_environment("WindyMaze-v0", {"drift": 0.7}, what="env", error=ValueError)


def test_bench_vector_script_runs_its_ppo_comparison():
    """scripts/bench_vector.py end to end on tiny settings: its PPO part builds the SB3 adapter."""
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[2] / "scripts" / "bench_vector.py"
    out = subprocess.run([sys.executable, str(script), "--num-envs", "2", "--seconds", "0.05", "--ppo-envs", "2", "3",
                          "--ppo-steps", "128"], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "native / sync" in out.stdout and "native / Dummy" in out.stdout
    ppo_rows = [line.split("|")[0].strip() for line in out.stdout.split("PPO")[-1].splitlines() if line.count("|") == 2]
    assert ppo_rows[1:] == ["2", "3"]  # one row per N (after the header)
