"""Features extractors: shapes, used when a config names them, refused when misnamed or misplaced."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from gymnasium import spaces

import gym_gridloc
from gym_gridloc_agents.config import ConfigError, validate_config
from gym_gridloc_agents.features import EXTRACTORS, BeliefLogFeatures, BeliefMapCNN
from gym_gridloc_agents.files import load_model
from gym_gridloc_agents.policies import PPOPolicy
from gym_gridloc_agents.train import train

from .test_train import tiny


def test_belief_log_features_shape_and_values():
    space = spaces.Box(0.0, 1.0, (46,), np.float32)
    ext = BeliefLogFeatures(space, readings=4)
    assert ext.features_dim == 46 + 42
    obs = torch.zeros(3, 46)
    obs[:, 1] = 1.0  # a reading bit: passed on raw, no logarithm
    obs[0, 4] = 1.0  # certain
    obs[1, 4:6] = torch.tensor([1e-3, 1 - 1e-3])
    obs[2, 4:] = 1.0 / 42
    out = ext(obs)
    assert out.shape == (3, 88)
    assert torch.equal(out[:, :46], obs)  # the raw observation first
    logs = out[:, 46:]
    assert logs.shape == (3, 42) and float(logs.min()) >= 0.0 and float(logs.max()) <= 1.0 + 1e-6
    assert logs[0, 0] == pytest.approx(1.0, abs=1e-6) and logs[0, 1] == pytest.approx(0.0, abs=1e-6)
    # 1e-3 is resolved: half-way on the scale of 1e-6 .. 1
    assert logs[1, 0] == pytest.approx(1.0 + math.log(1e-3 + 1e-6) / math.log(1e6), abs=1e-5)
    assert logs[1, 0] == pytest.approx(0.5, abs=1e-3)
    assert torch.allclose(logs[2], torch.full((42,), 1.0 + math.log(1 / 42 + 1e-6) / math.log(1e6)))


def test_belief_log_features_refuses_bad_inputs():
    with pytest.raises(ValueError, match="flat Box"):
        BeliefLogFeatures(spaces.Dict({"belief": spaces.Box(0, 1, (3, 3))}))
    with pytest.raises(ValueError, match="readings must be in"):
        BeliefLogFeatures(spaces.Box(0.0, 1.0, (10,), np.float32), readings=10)
    with pytest.raises(ValueError, match="eps_exponent"):
        BeliefLogFeatures(spaces.Box(0.0, 1.0, (10,), np.float32), eps_exponent=0)


def test_extractors_say_which_observations_they_read():
    assert EXTRACTORS["belief_log"] is BeliefLogFeatures and not BeliefLogFeatures.dict_observations
    assert EXTRACTORS["belief_map_cnn"] is BeliefMapCNN and BeliefMapCNN.dict_observations


def test_named_belief_log_extractor_is_used(tmp_path):
    model = gym_gridloc.colour_grid_model()
    readings = model.sensor.encode(np.array([0])).shape[1]
    cfg = tiny(tmp_path, policy_kwargs={"net_arch": [16], "features_extractor": "belief_log",
                                        "features_extractor_kwargs": {"readings": readings}})
    train(cfg, progress_bar=False)
    sb3 = load_model(tmp_path / "model.zip", algo="ppo")[0]
    ext = sb3.policy.features_extractor
    assert isinstance(ext, BeliefLogFeatures) and ext.readings == readings
    n = sb3.observation_space.shape[0]
    assert ext.features_dim == 2 * n - readings
    assert sb3.policy.mlp_extractor.policy_net[0].in_features == 2 * n - readings
    policy = PPOPolicy(model, env_id="ColourGrid-v0", path=tmp_path / "model.zip")
    assert policy.act(0, model.prior()) in range(4)


def test_bad_extractor_names_and_placements_are_refused(tmp_path):
    with pytest.raises(ConfigError, match="features_extractor must be one of"):
        validate_config(tiny(tmp_path, policy_kwargs={"features_extractor": "belief_logs"}))
    # belief_log reads the flat vector; belief_map_cnn the Dict one
    with pytest.raises(ConfigError, match="belief_log reads flat observations"):
        validate_config(tiny(tmp_path, wrapper={"belief": True, "flatten": False},
                             policy_kwargs={"features_extractor": "belief_log"}))
    with pytest.raises(ConfigError, match="belief_map_cnn reads Dict observations"):
        validate_config(tiny(tmp_path, policy_kwargs={"features_extractor": "belief_map_cnn"}))
    with pytest.raises(ConfigError, match="takes readings, eps_exponent"):
        validate_config(tiny(tmp_path, policy_kwargs={"features_extractor": "belief_log",
                                                      "features_extractor_kwargs": {"channels": 4}}))
    ok = validate_config(tiny(tmp_path, policy_kwargs={"features_extractor": "belief_log",
                                                       "features_extractor_kwargs": {"readings": 4}}))
    assert ok["policy"] == "MlpPolicy"
