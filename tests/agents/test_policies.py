"""Policies: valid actions everywhere, greedy / greedy2 equal to brute force, safe model loading."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc
from gym_gridloc_agents.loading import model_method
from gym_gridloc_agents.policies import (
    POLICY_NAMES,
    DistilledPolicy,
    Greedy2Policy,
    GreedyPolicy,
    PPOPolicy,
    RandomPolicy,
    RecurrentPolicy,
    default_model_path,
    make_policy,
)
from gym_gridloc.filter import ForwardFilter
from gym_gridloc_agents.evaluation.bench import BENCH_ENV_IDS


def _entropy_bits(p: np.ndarray) -> float:
    p = p[p > 0]
    return float(-(p * np.log2(p)).sum())


def _after(model, belief, action):
    """``(P(z), posterior hidden-state belief)`` for every reading z possible after ``action``,
    by the filter itself."""
    f = ForwardFilter(model)
    f.reset()
    f.set_belief(belief)
    f.predict(action)
    pred = f.full_belief
    for z in range(model.sensor.n_readings):
        joint = pred * model.likelihood(z)[None]
        pz = joint.sum()
        if pz > 0:
            yield pz, joint / pz


def brute_expected_entropy(model, belief, action) -> float:
    """E_z[H(position | b, a, z)] by an explicit loop over readings."""
    return sum(pz * _entropy_bits(post.sum(axis=0).ravel()) for pz, post in _after(model, belief, action))


def brute_two_step(model, belief, a1) -> float:
    """E_z1[min_a2 E_z2[H]] by explicit loops."""
    return sum(
        pz * min(brute_expected_entropy(model, post, a2) for a2 in range(model.n_actions))
        for pz, post in _after(model, belief, a1)
    )


def _beliefs(env_id, n_steps, seed=0, **kwargs):
    env = gym_gridloc.HMMBeliefWrapper(gym.make(env_id, **kwargs))
    obs, _ = env.reset(seed=seed)
    out = [env.filter.full_belief]
    rng = np.random.default_rng(seed)
    for _ in range(n_steps):
        obs, _, term, trunc, _ = env.step(int(rng.integers(env.action_space.n)))
        out.append(env.filter.full_belief)
        if term or trunc:
            break
    return env.unwrapped.model, out


@pytest.mark.parametrize(
    "env_id,kwargs",
    [
        ("WindyMaze-v0", {}),
        ("ColourGrid-v0", {}),
        ("RingSensor8x8-v0", {"size": (4, 5)}),
        ("RingSensor8x8-v0", {"size": (4, 4), "dynamics": "passive"}),
        ("ColourGrid-v0", {"slip": 0.5}),
    ],
)
def test_greedy_equals_brute_force(env_id, kwargs):
    model, beliefs = _beliefs(env_id, 3, **kwargs)
    g = GreedyPolicy(model)
    for b in beliefs:
        got = g.expected_entropies(b)
        want = [brute_expected_entropy(model, b, a) for a in range(model.n_actions)]
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)
        best = np.flatnonzero(np.isclose(want, min(want), rtol=1e-9, atol=1e-9))
        assert g.act(None, b) in best


def test_greedy_with_kidnapping_equals_brute_force():
    model = gym_gridloc.windy_maze_model().with_kidnapping(0.05)
    _, beliefs = _beliefs("WindyMaze-v0", 3)
    for b in beliefs:
        want = [brute_expected_entropy(model, b, a) for a in range(model.n_actions)]
        np.testing.assert_allclose(GreedyPolicy(model).expected_entropies(b), want, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("env_id,kwargs", [("WindyMaze-v0", {}), ("RingSensor8x8-v0", {"size": (3, 4)}),
                                          ("RingSensor8x8-v0", {"size": (3, 3), "dynamics": "passive"})])
def test_greedy2_equals_brute_force(env_id, kwargs):
    model, beliefs = _beliefs(env_id, 2, **kwargs)
    g2 = Greedy2Policy(model)
    for b in beliefs[:2]:
        got = g2.expected_entropies(b)
        want = [brute_two_step(model, b, a) for a in range(model.n_actions)]
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)


def test_greedy_accepts_position_belief_and_rejects_wrong_shape():
    model = gym_gridloc.windy_maze_model()
    g = GreedyPolicy(model)
    b = model.prior()
    np.testing.assert_allclose(g.expected_entropies(b[0]), g.expected_entropies(b))
    with pytest.raises(ValueError, match="belief must be"):
        g.act(None, np.ones((3, 3)))
    seed_model = gym_gridloc.ring_sensor_model((4, 4), dynamics="passive")
    with pytest.raises(ValueError, match=r"\(4, 4, 4\)"):
        GreedyPolicy(seed_model).act(None, np.ones((4, 4)) / 16)


def test_random_policy_is_seeded_and_uniform():
    model = gym_gridloc.colour_grid_model()
    p = RandomPolicy(model)
    p.reset(seed=3)
    a = [p.act(None, None) for _ in range(400)]
    p.reset(seed=3)
    assert a == [p.act(None, None) for _ in range(400)]
    counts = np.bincount(a, minlength=4)
    assert counts.min() > 60


@pytest.mark.parametrize("env_id", BENCH_ENV_IDS)
@pytest.mark.parametrize("name", POLICY_NAMES)
def test_every_policy_returns_valid_actions(env_id, name):
    if name == "pomcp":
        pytest.importorskip("pomdp_py", reason="pomcp needs the planning extra (pip install 'gym_gridloc[planning]')")
    env = gym_gridloc.HMMBeliefWrapper(gym.make(env_id))
    if name == "optimal":  # the exact search needs a noiseless model
        from gym_gridloc_agents.planners.optimal import NotDeterministic

        with pytest.raises(NotDeterministic, match="is not deterministic|has a noisy sensor"):
            make_policy(name, env.unwrapped.model, env_id=env_id)
        return
    if name == "central" and getattr(env.unwrapped.model.sensor, "nothing", None) is None:
        with pytest.raises(ValueError, match="needs a sensor with a 'nothing' reading"):
            make_policy(name, env.unwrapped.model, env_id=env_id)
        return
    policy = make_policy(name, env.unwrapped.model, env_id=env_id)
    for ep in range(2):
        obs, _ = env.reset(seed=ep)
        policy.reset(seed=ep)
        for _ in range(6):
            a = policy.act(obs["observation"], env.filter.full_belief)
            assert isinstance(a, int) and env.action_space.contains(a)
            obs, _, term, trunc, _ = env.step(a)
            if term or trunc:
                break


def test_shipped_models_have_metadata():
    for env_id in BENCH_ENV_IDS:
        for method, algo in (("distilled", "ppo"), ("recurrent", "recurrent_ppo")):
            path = default_model_path(env_id, method)
            assert path.is_file(), path
            assert path.name == f"{env_id}-{method}.zip"
            meta = path.with_suffix(".json")
            import json

            m = json.loads(meta.read_text())
            assert m["env_id"] == env_id and m["algo"] == algo and model_method(m) == method
            assert m["num_timesteps"] >= m["total_timesteps"]
            assert {"config", "seed", "versions", "wall_time_seconds"} <= set(m)
            assert path.stat().st_size < 3_000_000  # small enough for git


#: The shipped models trained on random maps of one size: (env_id, size, HMMBeliefWrapper options).
SIZED_MODELS = [("DepthMaze-v0", 7, {"full_state": True}), ("DepthMaze-v0", 15, {"full_state": True}),
                ("DepthMaze-v0", 21, {"full_state": True}), ("WindyMaze-v0", 9, {}), ("WindyMaze-v0", 15, {})]


@pytest.mark.parametrize("env_id,size,options", SIZED_MODELS)
def test_shipped_random_map_models_are_found_by_size_and_act(env_id, size, options):
    import json

    from gym_gridloc.maps import test_set

    path = default_model_path(env_id, "distilled", {"size": size})
    assert path.name == f"{env_id}-size{size}-distilled.zip" and path.stat().st_size < 3_000_000
    m = json.loads(path.with_suffix(".json").read_text())
    assert m["env_id"] == env_id and m["algo"] == "ppo" and m["env_kwargs"]["size"] == size
    assert m["num_timesteps"] >= m["total_timesteps"]
    assert {"config", "seed", "versions", "wall_time_seconds", "evaluations"} <= set(m)
    assert m["wall_time_seconds"] <= 2 * 3600  # the training budget
    held = test_set(env_id, size, 1)[0]
    kwargs = {"episode_length": 4} if env_id == "DepthMaze-v0" else {}
    env = gym_gridloc.HMMBeliefWrapper(gym.make(env_id, size=size, **kwargs), **options)
    obs, _ = env.reset(seed=0, options={"map": held.grid, "state": held.state})
    policy = make_policy("distilled", env.unwrapped.model, env_id=env_id, env_kwargs={"size": size})
    policy.reset(seed=0, model=env.unwrapped.model)
    for _ in range(4):
        action = policy.act(obs["observation"], env.filter.full_belief)
        assert env.action_space.contains(action)
        obs, *_ = env.step(action)


#: The shipped pure-RL models of random maps: (env_id, size, protocol keywords).
SIZED_PPO = [("DepthMaze-v0", 7, {"episode_length": 15}), ("DepthMaze-v0", 15, {"episode_length": 20}),
             ("WindyMaze-v0", 9, {})]


@pytest.mark.parametrize("env_id,size,protocol", SIZED_PPO)
def test_shipped_pure_rl_models_of_random_maps_are_found_and_act(env_id, size, protocol):
    """`ppo` on random maps: found by size, learned from the reward alone (no pretraining, no
    warm start), small, evaluated on validation maps (during training, or, where the training
    kept its last model, every seed afterwards: ``seeds``), and it acts on a held-out map."""
    import json

    from gym_gridloc.maps import test_set

    path = default_model_path(env_id, "ppo", {"size": size, **protocol})
    assert path.name == f"{env_id}-size{size}-ppo.zip" and path.stat().st_size < 3_000_000
    m = json.loads(path.with_suffix(".json").read_text())
    assert m["env_id"] == env_id and m["algo"] == "ppo" and model_method(m) == "ppo"
    assert m["env_kwargs"]["size"] == size and m["pretrain"] is None and not m["config"].get("pretrain")
    assert m["num_timesteps"] >= m["total_timesteps"] and (m["evaluations"] or m["config"]["eval_freq"] == 0 and m["seeds"])
    held = test_set(env_id, size, 1)[0]
    env = gym_gridloc.HMMBeliefWrapper(gym.make(env_id, size=size, **protocol))
    obs, _ = env.reset(seed=0, options={"map": held.grid, "state": held.state})
    policy = make_policy("ppo", env.unwrapped.model, env_id=env_id, env_kwargs={"size": size, **protocol})
    assert policy.path == path
    policy.reset(seed=0, model=env.unwrapped.model)
    for _ in range(4):
        action = policy.act(obs["observation"], env.filter.full_belief)
        assert env.action_space.contains(action)
        obs, *_ = env.step(action)


def test_ppo_for_another_environment_fails_clearly(tmp_path):
    colour = gym_gridloc.colour_grid_model()
    # By metadata: the shipped WindyMaze model named for ColourGrid.
    with pytest.raises(ValueError, match="trained for WindyMaze-v0, not ColourGrid-v0"):
        PPOPolicy(colour, env_id="ColourGrid-v0", path=default_model_path("WindyMaze-v0", "distilled"))
    # Without metadata: the observation space decides.
    import shutil

    bare = tmp_path / "model.zip"
    shutil.copy(default_model_path("WindyMaze-v0", "distilled"), bare)
    with pytest.raises(ValueError, match="another environment or observation space"):
        PPOPolicy(colour, path=bare)
    with pytest.raises(ValueError, match="holds a ppo model, not recurrent_ppo"):
        RecurrentPolicy(colour, path=default_model_path("ColourGrid-v0", "distilled"))
    with pytest.raises(FileNotFoundError, match="does not exist"):
        PPOPolicy(colour, path=tmp_path / "missing.zip")
    junk = tmp_path / "junk.zip"
    junk.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a loadable ppo model"):
        PPOPolicy(colour, path=junk)


def test_a_model_numpy_1_cannot_read_says_to_install_numpy_2(monkeypatch):
    """The shipped zips are pickled with numpy 2; under numpy 1 unpickling them fails on
    ``numpy._core`` (seen with numpy 1.26): the error says what to install."""
    from stable_baselines3 import PPO

    def numpy_1_load(*args, **kwargs):
        raise ModuleNotFoundError("No module named 'numpy._core.numeric'")

    monkeypatch.setattr(PPO, "load", numpy_1_load)
    with pytest.raises(ValueError, match=r"saved with numpy 2.*pip install 'numpy>=2'"):
        PPOPolicy(gym_gridloc.colour_grid_model(), env_id="ColourGrid-v0",
                  path=default_model_path("ColourGrid-v0", "ppo"))


def test_models_are_matched_by_the_environment_their_keywords_build():
    # DepthMaze-v0 without keywords is the 7x7 maze: the model trained with size=7 is its default;
    # episode keywords (episode_length, reward) may differ
    assert default_model_path("DepthMaze-v0", "distilled").name == "DepthMaze-v0-size7-distilled.zip"
    assert (default_model_path("DepthMaze-v0", "distilled", env_kwargs={"size": 7, "episode_length": 30}).name
            == "DepthMaze-v0-size7-distilled.zip")
    with pytest.raises(FileNotFoundError, match=r"no shipped distilled model for DepthMaze-v0 with \{'size': 11\}"):
        default_model_path("DepthMaze-v0", "distilled", env_kwargs={"size": 11})
    assert (default_model_path("WindyMaze-v0", "distilled", env_kwargs={"drift": 0.1}).name
            == "WindyMaze-v0-distilled.zip")  # the default drift
    # a model for other keywords is refused, naming them
    model = gym_gridloc.windy_maze_model(drift=0.2)
    with pytest.raises(ValueError, match=r"trained for WindyMaze-v0 with env_kwargs \{\}, not \{'drift': 0.2\}"):
        PPOPolicy(model, env_id="WindyMaze-v0", env_kwargs={"drift": 0.2}, path=default_model_path("WindyMaze-v0", "distilled"))
    DistilledPolicy(gym_gridloc.windy_maze_model(), env_id="WindyMaze-v0", env_kwargs={"drift": 0.1})


def test_distilled_loads_the_previously_shipped_models_and_old_names_still_work():
    """The planner-distilled models shipped before 0.2 as ``<env>.zip`` / ``<env>-size<N>.zip``
    are the ``distilled`` policy's; their old file names still load, with a FutureWarning."""
    from gym_gridloc_agents.policies import POLICY_DIR

    for env_id, kwargs in [("WindyMaze-v0", {}), ("ColourGrid-v0", {}), ("RingSensor8x8-v0", {}),
                           ("DepthMaze-v0", {"size": 7}), ("WindyMaze-v0", {"size": 9})]:
        model = gym.make(env_id, **kwargs).unwrapped.model
        policy = make_policy("distilled", model, env_id=env_id, env_kwargs=kwargs)
        assert isinstance(policy, DistilledPolicy) and policy.path.stem.endswith("-distilled")
        assert policy.meta["pretrain"] and model_method(policy.meta) == "distilled"
        old = POLICY_DIR / policy.path.name.replace("-distilled", "")
        assert not old.exists()
        with pytest.warns(FutureWarning, match="is now .*-distilled.zip"):
            legacy = DistilledPolicy(model, env_id=env_id, env_kwargs=kwargs, path=old)
        assert legacy.path == policy.path


def test_ppo_encoding_matches_the_wrapper():
    env = gym_gridloc.HMMBeliefWrapper(gym.make("ColourGrid-v0"), flatten=True)
    inner = env.env
    p = PPOPolicy(env.unwrapped.model, env_id="ColourGrid-v0")
    obs, _ = env.reset(seed=1)
    raw = inner.unwrapped.last_reading
    np.testing.assert_array_equal(p.encode(raw, env.filter.full_belief), obs)
    assert p.sb3.observation_space.contains(obs)


def test_ppo_encoding_with_the_lookahead_matches_the_wrapper():
    """With ``lookahead`` (and a map redrawn at each reset) the policy's observation is the
    wrapper's, map after map: the expected entropies follow the episode's map."""
    options = {"flatten": False, "full_state": False, "map": True, "lookahead": 2}
    env = gym_gridloc.HMMBeliefWrapper(gym.make("ColourGrid-v0", size=6, new_map_each_reset=True), **options)
    p = PPOPolicy(env.unwrapped.model, sb3_model=object(), wrapper=options)
    assert p.expected_space(env.unwrapped.model) == env.observation_space
    for seed in (0, 1):
        obs, _ = env.reset(seed=seed)
        p.reset(seed=seed, model=env.unwrapped.model)
        for t in range(3):
            mine = p.encode(env.unwrapped.last_reading, env.filter.full_belief)
            assert set(mine) == set(obs)
            for key in obs:
                np.testing.assert_array_equal(mine[key], obs[key])
            obs, *_ = env.step(t)


def test_unknown_policy_name():
    with pytest.raises(ValueError, match="unknown policy 'smart'"):
        make_policy("smart", gym_gridloc.colour_grid_model())


def test_greedy_plans_on_large_maps_without_a_readings_table_and_greedy2_refuses_clearly():
    # One step predicts 4 beliefs and correlates them with the ring kernel: no (readings x states)
    # table (10001 x 10000 here) and no dense transition, also with kidnapping.
    model = gym_gridloc.ring_sensor_model((100, 100)).with_kidnapping(0.01)
    belief = model.prior()
    belief[:, :50] *= 3.0
    belief /= belief.sum()
    p = GreedyPolicy(model, seed=0)
    assert p.act(None, belief) in range(4)
    with pytest.raises(ValueError, match=r"would predict \d+ beliefs .* use a one-step policy \(greedy\) or a smaller map"):
        Greedy2Policy(model, seed=0).act(None, belief)


@pytest.mark.parametrize("method", ["ppo", "distilled"])
def test_a_namespaced_id_finds_the_shipped_models(method):
    from gym_gridloc_agents.loading import plain_id
    from gym_gridloc_agents.policies import default_model_path

    assert plain_id("gym_gridloc/DepthMaze-v0") == "DepthMaze-v0" and plain_id("CartPole-v1") == "CartPole-v1"
    for env_id in ("WindyMaze-v0", "DepthMaze-v0"):
        env = gym.make(f"gym_gridloc/{env_id}")
        policy = make_policy(method, env.unwrapped.model, env_id=f"gym_gridloc/{env_id}")
        assert policy.path == default_model_path(env_id, method)
