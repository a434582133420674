"""The warm start's soft targets (a planner's action values at a temperature) and its learning-rate
decay: the targets, the config checks, the cached values, the schedule."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gym_gridloc_agents.training import pretrain
from gym_gridloc_agents.training.config import ConfigError, validate_config
from gym_gridloc_agents.training.train import train

from .test_train import tiny


def test_soft_targets_follow_the_action_values():
    data = {"targets": np.array([[0, 1, 0, 0], [0.5, 0, 0.5, 0]], np.float32),
            "values": np.array([[3.0, 2.0, 2.1, 4.0], [1.0, 1.5, 1.0, 9.0]])}
    assert np.array_equal(pretrain.soft_targets(data, 0.0), data["targets"])
    soft = pretrain.soft_targets(data, 0.1)
    assert soft.shape == (2, 4) and np.allclose(soft.sum(axis=1), 1.0)
    assert list(soft.argmax(axis=1)) == [1, 0] and soft[1, 0] == pytest.approx(soft[1, 2])
    # 0.1 step worse: e^-1 as likely; much worse: (almost) never
    assert soft[0, 2] / soft[0, 1] == pytest.approx(np.exp(-1.0), rel=1e-5) and soft[1, 3] < 1e-30
    sharper = pretrain.soft_targets(data, 0.02)
    assert sharper[0, 1] > soft[0, 1]
    with pytest.raises(ValueError, match="action values"):
        pretrain.soft_targets({"targets": data["targets"]}, 0.1)


def _cfg(tmp_path, **pre):
    return tiny(tmp_path, pretrain={"expert": "expectimax", "expert_kwargs": {"depth": 1}, "episodes": 4, "epochs": 2,
                                    "batch_size": 16, **pre})


def test_temperature_and_final_learning_rate_are_checked(tmp_path):
    ok = validate_config(_cfg(tmp_path, temperature=0.1, learning_rate=1e-3, learning_rate_final=1e-5))
    assert ok["pretrain"]["temperature"] == 0.1 and ok["pretrain"]["learning_rate_final"] == 1e-5
    assert validate_config(_cfg(tmp_path))["pretrain"]["temperature"] == 0.0
    with pytest.raises(ConfigError, match="temperature needs a planner's action values"):
        validate_config(_cfg(tmp_path, expert="greedy", temperature=0.1))
    with pytest.raises(ConfigError, match="pretrain.temperature must be >= 0"):
        validate_config(_cfg(tmp_path, temperature=-1.0))
    with pytest.raises(ConfigError, match="learning_rate_final must be <= 0.001"):
        validate_config(_cfg(tmp_path, learning_rate=1e-3, learning_rate_final=1e-2))


def test_warm_start_at_a_temperature_caches_the_planner_values(tmp_path):
    cfg = _cfg(tmp_path, temperature=0.1, dagger_rounds=1, dagger_episodes=2, dagger_epochs=1)
    info = train(cfg, progress_bar=False)
    assert info["pretrain"]["dagger_rounds"] == 1 and info["pretrain"]["dagger_samples"] > 0
    for name in ("expert.npz", "dagger.npz"):
        with np.load(tmp_path / "ckpt" / name) as data:
            assert '"values": true' in str(data["key"])
            values, targets = data["values"], data["targets"]
        assert values.shape == targets.shape and len(values) > 0
        best = values <= values.min(axis=1, keepdims=True) + 1e-6 * np.maximum(1.0, np.abs(values.min(axis=1, keepdims=True)))
        assert np.array_equal(targets > 0, best)  # the tied best actions are the values' minima
    # Without a temperature the same data keeps its former key (no values): caches are not mixed.
    plain = validate_config(_cfg(tmp_path))
    assert '"values"' not in pretrain._cache_key(plain, "expert")


def test_learning_rate_decays_to_its_final_value(tmp_path, monkeypatch):
    from stable_baselines3 import PPO

    from gym_gridloc_agents.envs import make_training_env

    cfg = validate_config(_cfg(tmp_path, learning_rate=1e-3, learning_rate_final=1e-5))
    model = PPO("MlpPolicy", make_training_env(cfg), policy_kwargs={"net_arch": [8]}, n_steps=16, batch_size=16, device="cpu")
    made, seen = [], []
    real_adam = torch.optim.Adam

    class Recording(real_adam):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append(self)

        def step(self, *a, **k):
            seen.append(self.param_groups[0]["lr"])
            return super().step(*a, **k)

    monkeypatch.setattr(torch.optim, "Adam", Recording)
    rng = np.random.default_rng(0)
    n = 40
    data = {"obs": rng.random((n, model.observation_space.shape[0]), dtype=np.float32),
            "targets": np.eye(4, dtype=np.float32)[rng.integers(0, 4, n)], "returns": rng.random(n).astype(np.float32)}
    pretrain._fit(model, data, cfg, epochs=range(3), progress=False, label="fit")
    assert len(made) == 1 and len(seen) == 3 * 3  # 3 epochs of 3 batches of 16
    assert seen[0] == pytest.approx(1e-3) and seen[-1] == pytest.approx(1e-5)
    assert all(a >= b for a, b in zip(seen, seen[1:]))
