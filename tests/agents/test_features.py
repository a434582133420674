"""Features extractors: the depths they compute are the sensor's, pooling over poses turns with the
maze, a batch of mixed mazes gives what each sample gives alone; the belief_log extractor's shapes and
values; configs name them, and misnamed or misplaced ones are refused."""

from __future__ import annotations

import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces

import gym_gridloc
from gym_gridloc import engine
from gym_gridloc.wrappers import previous_action_space, with_previous_action
from gym_gridloc_agents.training.config import ConfigError, validate_config
from gym_gridloc_agents.features import (EXTRACTORS, BeliefLogFeatures, BeliefMapCNN, CellPoolCNN, PosePoolCNN,
                                         ReadingCellFeatures, depth_channels)
from gym_gridloc_agents.loading import load_model
from gym_gridloc_agents.policies import PPOPolicy
from gym_gridloc_agents.training.train import train

from .test_train import tiny

ROOT = Path(__file__).resolve().parents[2]


def _maze(size: int, seed: int):
    env = gym.make("DepthMaze-v0", size=size, map_seed=seed)
    return env.unwrapped.model


def _space(n: int, belief=(4,), reading: int = 14) -> spaces.Dict:
    return spaces.Dict({"observation": spaces.Box(0, 1, (reading,)), "belief": spaces.Box(0, 1, (*belief, n, n)),
                        "map": spaces.Box(0, 1, (1, n, n))})


@pytest.mark.parametrize("size,seed", [(7, 0), (9, 3), (15, 5)])
def test_depth_channels_are_the_readings_of_every_pose(size, seed):
    model = _maze(size, seed)
    free = torch.tensor(model.grid.free, dtype=torch.float32)[None, None]
    depth = depth_channels(free)[0].numpy()
    states = engine.states_of(model, np.arange(model.n_states))
    for i, (h, r, c) in enumerate(states):
        assert depth[h, r, c] == model.likelihood_vector(int(depth[h, r, c]))[i] * depth[h, r, c] > 0
    assert np.all(depth[:, ~model.grid.free] == 0)


def _observation(model, belief):
    free = torch.tensor(model.grid.free, dtype=torch.float32)[None, None]
    return {"observation": torch.zeros(1, 14), "belief": belief, "map": free}


def _random_belief(model, seed):
    g = torch.Generator().manual_seed(seed)
    free = torch.tensor(model.grid.free, dtype=torch.float32)
    b = torch.rand(1, 4, *free.shape, generator=g) * free
    b[b < 0.6] = 0
    return b / b.sum()


def test_pose_pooling_turns_with_the_maze_and_batches_mixed_mazes():
    torch.manual_seed(0)
    net = PosePoolCNN(_space(9), channels=8, layers=3, features=16)
    model = _maze(9, 1)
    obs = _observation(model, _random_belief(model, 1))
    # The maze turned a quarter counterclockwise: heading h becomes h - 1 (east points north).
    turned = {"observation": obs["observation"], "map": torch.rot90(obs["map"], 1, dims=(2, 3)),
              "belief": torch.stack([torch.rot90(obs["belief"][0, (h + 1) % 4], 1, dims=(0, 1)) for h in range(4)])[None]}
    with torch.no_grad():
        a, b = net(obs), net(turned)
        torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-5)
        other = _maze(9, 2)
        third = _observation(other, _random_belief(other, 3))
        batch = {k: torch.cat([obs[k], third[k], turned[k], obs[k]]) for k in obs}
        out = net(batch)
        for row, alone in zip(out, [a, net(third), b, a]):
            torch.testing.assert_close(row, alone[0], atol=1e-5, rtol=1e-5)
    assert out.shape == (4, net.features_dim) and net.features_dim == 16 + 14
    # The belief weighs the poses: another belief on the same maze gives other features.
    assert not torch.allclose(net(_observation(model, _random_belief(model, 7))), a)


def test_pose_pooling_refuses_what_it_cannot_read():
    with pytest.raises(ValueError, match="'observation', 'belief' and 'map'"):
        PosePoolCNN(spaces.Dict({"observation": spaces.Box(0, 1, (3,)), "belief": spaces.Box(0, 1, (4, 5, 5))}))
    with pytest.raises(ValueError, match="square pose belief"):
        PosePoolCNN(_space(5, belief=(1,)))


def _colour_observation(model, belief) -> dict[str, torch.Tensor]:
    from gym_gridloc.wrappers import map_channels

    return {"observation": torch.zeros(1, 4), "belief": torch.as_tensor(belief, dtype=torch.float32)[None],
            "map": torch.as_tensor(map_channels(model))[None]}


def test_cell_pooling_moves_with_the_map_and_reads_colour_maps():
    """Nothing is tied to a place: a map and belief moved together (obstacles all round, farther
    from the hypotheses than the convolutions see) give the same features; a batch gives what each sample gives alone;
    the belief and the colours both matter."""
    from gym_gridloc.generators import colour_map

    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    rows = np.array(list("RGBY"))[rng.integers(0, 4, (5, 5))]
    rows[1, 3] = "."  # an obstacle

    def placed(r0: int, c0: int):
        layout = np.full((15, 15), ".")
        layout[r0 : r0 + 5, c0 : c0 + 5] = rows
        model = gym_gridloc.colour_grid_model(layout)
        belief = np.zeros((15, 15))
        belief[r0 + 2, c0 + 1], belief[r0 + 4, c0 + 4], belief[r0, c0] = 0.5, 0.3, 0.2
        return model, belief

    (m1, b1), (m2, b2) = placed(4, 4), placed(6, 5)
    space = spaces.Dict({"observation": spaces.Box(0, 1, (4,)), "belief": spaces.Box(0, 1, (15, 15)),
                         "map": spaces.Box(0, 1, (5, 15, 15))})
    net = CellPoolCNN(space, channels=8, layers=3, features=16, max_dilation=2)  # sees 4 cells away
    with torch.no_grad():
        a, b = net(_colour_observation(m1, b1)), net(_colour_observation(m2, b2))
        torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-5)
        other = gym_gridloc.colour_grid_model(colour_map((15, 15), obstacle_density=0.2, seed=4))
        b3 = other.prior()[0]
        first, second = _colour_observation(m1, b1), _colour_observation(other, b3)
        out = net({k: torch.cat([first[k], second[k]]) for k in first})
        torch.testing.assert_close(out[0], a[0], atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(out[1], net(second)[0], atol=1e-5, rtol=1e-5)
        # A full-state belief (L, H, W) is summed over its layers.
        layered = torch.as_tensor(np.stack([b1 / 2, b1 / 2]), dtype=torch.float32)[None]
        torch.testing.assert_close(net({**first, "belief": layered}), a)
        moved = b1.copy()
        moved[4, 4], moved[5, 4] = 0.0, 0.2  # one hypothesis on another cell
        assert not torch.allclose(net(_colour_observation(m1, moved)), a)
        recoloured = m1.grid.labels.copy()
        layout = np.where(m1.grid.free, np.array(list("RGBY"))[np.clip(recoloured, 0, 3)], ".")
        layout[6, 6] = "R" if layout[6, 6] != "R" else "G"  # a cell next to a hypothesis
        m3 = gym_gridloc.colour_grid_model(layout)
        assert not torch.allclose(net(_colour_observation(m3, b1)), a)
    assert out.shape == (2, 16 + 4)
    with pytest.raises(ValueError, match="'observation', 'belief' and 'map'"):
        CellPoolCNN(spaces.Dict({"observation": spaces.Box(0, 1, (4,)), "belief": spaces.Box(0, 1, (9, 9))}))
    with pytest.raises(ValueError, match="must cover the same grid"):
        CellPoolCNN(spaces.Dict({"observation": spaces.Box(0, 1, (4,)), "belief": spaces.Box(0, 1, (9, 9)),
                                 "map": spaces.Box(0, 1, (5, 7, 7))}))


def test_cell_pooling_reads_the_lookahead_beside_its_features():
    """The expected entropies enter the head and pass on raw and less their row's minimum."""
    torch.manual_seed(0)
    space = spaces.Dict({"observation": spaces.Box(0, 1, (4,)), "belief": spaces.Box(0, 1, (6, 6)),
                         "map": spaces.Box(0, 1, (5, 6, 6)), "lookahead": spaces.Box(0, 1, (2, 4))})
    net = CellPoolCNN(space, channels=4, layers=2, features=8, max_dilation=1)
    assert net.features_dim == 8 + 16 + 4
    model = gym_gridloc.colour_grid_model(np.array(list("RGBY"))[np.random.default_rng(1).integers(0, 4, (6, 6))])
    obs = _colour_observation(model, model.prior()[0])
    look = torch.tensor([[[0.5, 0.4, 0.6, 0.45], [0.3, 0.2, 0.35, 0.25]]])
    with torch.no_grad():
        out = net({**obs, "lookahead": look})
        torch.testing.assert_close(out[0, 8:16], look.flatten())
        torch.testing.assert_close(out[0, 16:24], (look - look.amin(dim=2, keepdim=True)).flatten())
        other = net({**obs, "lookahead": look.flip(2)})
        assert not torch.allclose(other[0, :8], out[0, :8])  # the head reads them too


def test_belief_map_cnn_shapes():
    net = BeliefMapCNN(_space(7), channels=4, layers=2, features=8)
    model = _maze(7, 0)
    assert net(_observation(model, _random_belief(model, 0))).shape == (1, 8 + 14)


@pytest.mark.parametrize("cls", [BeliefMapCNN, PosePoolCNN, CellPoolCNN])
def test_dict_extractors_pass_the_history_on(cls):
    """A Dict observation's "history" (the last actions, the steps left) reaches the policy as it is."""
    space = _space(7)
    history = spaces.Box(0, 1, (11,))
    plain = cls(space, channels=4, layers=2, features=8)
    net = cls(spaces.Dict({**space.spaces, "history": history}), channels=4, layers=2, features=8)
    assert net.features_dim == plain.features_dim + 11
    model = _maze(7, 0)
    obs = _observation(model, _random_belief(model, 0))
    h = torch.zeros(1, 11)
    h[0, 2], h[0, 10] = 1.0, 0.4
    with torch.no_grad():
        out = net({**obs, "history": h})
    assert out.shape == (1, net.features_dim)
    torch.testing.assert_close(out[0, -11:], h[0])


def _cfg(**policy_kwargs):
    return {"algo": "ppo", "env_id": "DepthMaze-v0", "env_kwargs": {"size": 7, "episode_length": 5},
            "wrapper": {"belief": True, "flatten": False, "full_state": True, "map": True}, "total_timesteps": 64,
            "policy_kwargs": policy_kwargs, "output": "x.zip",
            "pretrain": {"expert": "optimal", "episodes": 2, "episode_batches": True}}


def test_configs_name_the_extractors():
    assert set(EXTRACTORS) == {"belief_map_cnn", "pose_pool_cnn", "cell_pool_cnn", "belief_log", "reading_cell", "candidate_views"}
    cfg = validate_config(_cfg(features_extractor="pose_pool_cnn", features_extractor_kwargs={"channels": 8, "max_dilation": 4}))
    assert cfg["pretrain"]["episode_batches"] is True
    with pytest.raises(ConfigError, match="features_extractor must be one of belief_map_cnn, pose_pool_cnn"):
        validate_config(_cfg(features_extractor="pose_pool"))
    bad = _cfg(features_extractor="pose_pool_cnn")
    bad["pretrain"]["episode_batches"] = "yes"
    with pytest.raises(ConfigError, match="pretrain.episode_batches must be true or false"):
        validate_config(bad)


def test_episode_batches_shuffle_whole_episodes():
    from gym_gridloc_agents.training.pretrain import _epoch_order

    sizes = np.array([3, 1, 4, 2])
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    order = _epoch_order(int(sizes.sum()), sizes, torch.Generator().manual_seed(0)).numpy()
    assert sorted(order.tolist()) == list(range(10))
    pieces, k = [], 0
    while k < len(order):  # the order is a sequence of whole episodes, each in its own order
        e = int(np.searchsorted(starts, order[k], side="right") - 1)
        assert order[k : k + sizes[e]].tolist() == list(range(starts[e], starts[e] + sizes[e]))
        pieces.append(e)
        k += sizes[e]
    assert sorted(pieces) == [0, 1, 2, 3]
    assert len(_epoch_order(10, None, torch.Generator().manual_seed(0))) == 10


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


def test_reading_cell_features_give_the_reported_cell():
    # RingSensor8x8's reading (65 one-hot: cell r * 8 + c, or 64 for nothing) with
    # PreviousActionWrapper's 5 slots after it, as the recurrent config reads it
    env = gym.make("RingSensor8x8-v0")
    space = previous_action_space(env.observation_space, env.action_space)
    ext = ReadingCellFeatures(space, height=8, width=8)
    assert ext.features_dim == 70 + 3 and EXTRACTORS["reading_cell"] is ReadingCellFeatures
    assert not ReadingCellFeatures.dict_observations
    obs = torch.zeros(3, 70)
    for i, reading in enumerate((0, 2 * 8 + 7, 64)):  # top-left, row 2 column 7, nothing
        obs[i] = torch.as_tensor(with_previous_action(env.observation_space, 4, reading, 1))
    out = ext(obs)
    assert torch.equal(out[:, :70], obs)  # the raw observation first
    assert torch.allclose(out[:, 70:], torch.tensor([[0.0, 0.0, 0.0], [2 / 7, 1.0, 0.0], [0.0, 0.0, 1.0]]))
    with pytest.raises(ValueError, match="needs 65 leading entries"):
        ReadingCellFeatures(spaces.Box(0.0, 1.0, (40,), np.float32), height=8, width=8)
    with pytest.raises(ValueError, match="width"):
        ReadingCellFeatures(space, height=8, width=0)


def test_a_reading_cell_config_must_match_the_sensor(tmp_path):
    from gym_gridloc_agents.training.config import load_config

    cfg = load_config(ROOT / "configs" / "recurrent_ringsensor.yml")  # the shipped recipe validates
    assert cfg["policy_kwargs"]["features_extractor"] == "reading_cell"
    raw = {"algo": "recurrent_ppo", "env_id": "RingSensor8x8-v0", "wrapper": {"belief": False}, "total_timesteps": 64,
           "output": str(tmp_path / "m.zip"), "policy_kwargs": {"features_extractor": "reading_cell"}}
    validate_config(raw)
    for env_kwargs, fek in (({"size": (6, 6)}, {}), ({}, {"height": 6}), ({}, {})):
        bad = {**raw, "env_kwargs": env_kwargs, "policy_kwargs": {**raw["policy_kwargs"], "features_extractor_kwargs": fek}}
        if not env_kwargs and not fek:
            bad["env_id"] = "WindyMaze-v0"  # wall bits, not a cell
        with pytest.raises(ConfigError, match="reading_cell .* reads raw readings"):
            validate_config(bad)


def test_extractors_say_which_observations_they_read():
    assert EXTRACTORS["belief_log"] is BeliefLogFeatures and not BeliefLogFeatures.dict_observations
    assert EXTRACTORS["belief_map_cnn"] is BeliefMapCNN and BeliefMapCNN.dict_observations
    assert EXTRACTORS["pose_pool_cnn"] is PosePoolCNN and PosePoolCNN.dict_observations


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
