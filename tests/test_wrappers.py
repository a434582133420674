"""HMMBeliefWrapper (gym_gridloc/wrappers.py) over every registered environment.

The wrapper's belief is the environment's referee posterior when both use the same model, it is
computed from actions and observations only, and the wrapped environments pass ``check_env``, are
deterministic, pickle and vectorise.  Under model mismatch an impossible observation raises, or
with ``on_impossible="reset"`` restarts the belief; long mismatched runs stay finite and memory
stays flat."""

from __future__ import annotations

import os

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

import pickle
import tracemalloc

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from gym_gridloc import (
    ForwardFilter,
    GridModel,
    HMMBeliefWrapper,
    ImpossibleObservationError,
    colour_grid_model,
    depth_maze_model,
    ring_sensor_model,
    windy_maze_model,
)
from gym_gridloc.generators import perfect_maze
from tests.helpers import (
    CONFIG_IDS,
    CONFIGS,
    ENV_IDS,
    assert_same_rollouts,
    rollout,
    run_check_env,
)

WRAPPER_OPTIONS = [{}, {"flatten": True}, {"full_state": True}]
OPTION_IDS = ["dict", "flatten", "full_state"]

#: The environment of the mismatch tests: the registered id on one fixed map (the depth maze
#: otherwise draws a new maze at every reset, which a wrapper with a given model cannot follow).
FIXED_MAP = {"DepthMaze-v0": {"map_seed": 0}}

#: A model per environment whose sensor and motion differ from the environment's defaults, but
#: which emits the same observation space (so it can filter the environment's observations).
MISMATCHED = {
    "ColourGrid-v0": lambda: colour_grid_model(slip=0.5, accuracy=0.7),
    "RingSensor8x8-v0": lambda: ring_sensor_model((8, 8), keep_heading=0.4, p_true=0.2, p_ring1=0.06, p_ring2=0.02),
    "WindyMaze-v0": lambda: windy_maze_model(drift=0.25, p_detect=0.7, p_false_alarm=0.2),
    "DepthMaze-v0": lambda: depth_maze_model(perfect_maze(7, seed=0), p_turn_fail=0.2, p_move_fail=0.2,
                                             p_depth_error=0.2, max_depth=5),
}
#: Filter models that call some of the environment's readings impossible.
SHARP_MISMATCH = {
    "ColourGrid-v0": lambda: colour_grid_model(accuracy=1.0, slip=0.0),
    "RingSensor8x8-v0": lambda: ring_sensor_model((8, 8), p_true=1.0, p_ring1=0.0, p_ring2=0.0),
    "WindyMaze-v0": lambda: windy_maze_model(p_detect=1.0, p_false_alarm=0.0, drift=0.0),
    # The depth maze's own robot is sharp; the environment's is made noisy below.
    "DepthMaze-v0": lambda: depth_maze_model(perfect_maze(7, seed=0), max_depth=5),
}
#: Keyword arguments of the environment in the sharp-mismatch tests.
SHARP_ENV = {"DepthMaze-v0": {"map_seed": 0, "p_turn_fail": 0.1, "p_move_fail": 0.1, "p_depth_error": 0.1}}


def test_the_mismatch_tables_cover_the_registry():
    assert set(MISMATCHED) == set(SHARP_MISMATCH) == set(ENV_IDS)


def belief_of(wrapper, obs) -> np.ndarray:
    """The (position or full) belief inside a wrapped observation."""
    if wrapper.flatten:
        return obs[-int(np.prod(wrapper.belief_array().shape)):].reshape(wrapper.belief_array().shape)
    return obs[wrapper.key]


# -- check_env ---------------------------------------------------------------------------------
@pytest.mark.parametrize("options", WRAPPER_OPTIONS, ids=OPTION_IDS)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env_wrapped(env_id, options):
    run_check_env(HMMBeliefWrapper(gym.make(env_id).unwrapped, **options))
    run_check_env(HMMBeliefWrapper(gym.make(env_id), **options))


@pytest.mark.parametrize("options", WRAPPER_OPTIONS, ids=OPTION_IDS)
def test_check_env_wrapped_ring_seed_dynamics(options):
    run_check_env(HMMBeliefWrapper(gym.make("RingSensor8x8-v0", dynamics="passive"), **options))


def test_observation_spaces():
    env = HMMBeliefWrapper(gym.make("WindyMaze-v0"))
    assert env.observation_space == spaces.Dict(
        {"observation": spaces.MultiBinary(4), "belief": spaces.Box(0.0, 1.0, (6, 7), np.float32)}
    )
    flat = HMMBeliefWrapper(gym.make("ColourGrid-v0"), flatten=True)
    assert flat.observation_space == spaces.Box(0.0, 1.0, (4 + 25,), np.float32)
    full = HMMBeliefWrapper(gym.make("RingSensor8x8-v0", dynamics="passive"), full_state=True)
    assert full.observation_space["belief"] == spaces.Box(0.0, 1.0, (4, 8, 8), np.float32)
    pos = HMMBeliefWrapper(gym.make("RingSensor8x8-v0", dynamics="passive"))
    assert pos.observation_space["belief"] == spaces.Box(0.0, 1.0, (8, 8), np.float32)


# -- determinism, pickling, vector envs ----------------------------------------------------------
@pytest.mark.parametrize("options", WRAPPER_OPTIONS, ids=OPTION_IDS)
@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_wrapped_same_seed_same_trajectory(env_id, kwargs, options):
    ra = rollout(HMMBeliefWrapper(gym.make(env_id, **kwargs), **options), seed=321, n_steps=120)
    rb = rollout(HMMBeliefWrapper(gym.make(env_id, **kwargs), **options), seed=321, n_steps=120)
    assert_same_rollouts(ra, rb)


@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_wrapped_env_yields_the_env_trajectory(env_id, kwargs):
    """The wrapper changes the observation, nothing else: same seed, same readings, rewards, info."""
    ra = rollout(gym.make(env_id, **kwargs), seed=8, n_steps=100)
    rb = rollout(HMMBeliefWrapper(gym.make(env_id, **kwargs)), seed=8, n_steps=100)
    stripped = [tuple(v["observation"] if isinstance(v, dict) and "belief" in v else v for v in rec) for rec in rb]
    assert_same_rollouts(ra, stripped)


@pytest.mark.parametrize("options", WRAPPER_OPTIONS, ids=OPTION_IDS)
@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_wrapped_pickle_continues_identically(env_id, kwargs, options):
    env = HMMBeliefWrapper(gym.make(env_id, **kwargs), **options)
    n = env.action_space.n
    env.reset(seed=4)
    for a in (1, 2, 3):
        env.step(a % n)
    clone = pickle.loads(pickle.dumps(env))
    np.testing.assert_array_equal(clone.belief_array(), env.belief_array())
    for a in (0, 0, 1, 2, 3, 3, 2):
        x, y = env.step(a % n), clone.step(a % n)
        for u, v in zip(x, y):
            if isinstance(u, dict):
                for k in u:
                    np.testing.assert_array_equal(u[k], v[k])
            else:
                np.testing.assert_array_equal(u, v)


@pytest.mark.parametrize("options", WRAPPER_OPTIONS, ids=OPTION_IDS)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_wrapped_sync_vector_env(env_id, options):
    venv = gym.vector.SyncVectorEnv([lambda: HMMBeliefWrapper(gym.make(env_id), **options) for _ in range(2)])
    single = HMMBeliefWrapper(gym.make(env_id), **options)
    vobs, _ = venv.reset(seed=[3, 4])
    sobs, _ = single.reset(seed=3)
    assert vobs in venv.observation_space
    first = (lambda o: o[0]) if options.get("flatten") else (lambda o: {k: v[0] for k, v in o.items()})
    rng = np.random.default_rng(0)
    for _ in range(40):
        actions = rng.integers(0, venv.single_action_space.n, size=2)
        vobs, _, vterm, vtrunc, _ = venv.step(actions)
        assert vobs in venv.observation_space
        sobs, _, term, trunc, _ = single.step(int(actions[0]))
        got = first(vobs)
        if isinstance(got, dict):
            for k in got:
                np.testing.assert_array_equal(got[k], np.asarray(sobs[k]))
        else:
            np.testing.assert_array_equal(got, sobs)
        if term or trunc:
            break
    venv.close()


# -- the belief --------------------------------------------------------------------------------
@pytest.mark.parametrize("options", WRAPPER_OPTIONS, ids=OPTION_IDS)
@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_belief_equals_referee_posterior_every_step(env_id, kwargs, options):
    env = HMMBeliefWrapper(gym.make(env_id, **kwargs), **options)
    inner = env.unwrapped
    rng = np.random.default_rng(5)
    n_steps = episode = 0
    while episode < 3 or n_steps < 60:  # several episodes, at least 60 steps
        obs, info = env.reset(seed=50 + episode)
        episode += 1
        while True:
            b = belief_of(env, obs)
            assert b.dtype == np.float32 and obs in env.observation_space
            position = b.sum(axis=0) if env.full_state else b
            np.testing.assert_allclose(position, inner.posterior, rtol=0, atol=1e-6)
            assert abs(float(b.sum(dtype=np.float64)) - 1.0) < 1e-5
            assert np.all(position[~inner.model.grid.free] == 0)
            if env.full_state:
                np.testing.assert_allclose(b, inner._referee.full_belief, rtol=0, atol=1e-6)
            obs, reward, terminated, truncated, info = env.step(int(rng.integers(env.action_space.n)))
            n_steps += 1
            if terminated or truncated:
                break


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_flattened_observation_layout(env_id):
    env = HMMBeliefWrapper(gym.make(env_id), flatten=True)
    obs, _ = env.reset(seed=0)
    for a in (0, 1, 2, 3):
        raw = env.unwrapped.model.sensor.to_observation(env.unwrapped.last_reading)
        space = env.env.observation_space
        head_len = space.n if isinstance(space, spaces.Discrete) else 4
        head = obs[:head_len]
        if isinstance(space, spaces.Discrete):
            assert head.sum() == 1.0 and int(np.argmax(head)) == int(raw)
        else:
            np.testing.assert_array_equal(head, np.asarray(raw, dtype=np.float32))
        np.testing.assert_allclose(obs[head_len:].reshape(env.unwrapped.model.shape), env.unwrapped.posterior, atol=1e-6)
        obs, *_ = env.step(a % env.action_space.n)


@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_belief_is_computed_from_actions_and_observations_only(env_id, kwargs):
    """A separate filter fed only the actions passed on and the observations emitted gives the
    same belief; a wrapper with another model, on the same environment run, gives another (see
    test_mismatched_model_gives_a_different_belief)."""
    env = HMMBeliefWrapper(gym.make(env_id, **kwargs))
    obs, _ = env.reset(seed=9)
    f = ForwardFilter(env.unwrapped.model)  # after reset: a redrawn map is the episode's model
    f.reset(obs["observation"])
    for t in range(30):
        a = t % env.action_space.n
        obs, _, terminated, truncated, _ = env.step(a)
        f.step(a, obs["observation"])
        np.testing.assert_array_equal(obs["belief"], f.position_belief.astype(np.float32))
        if terminated or truncated:
            break


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_mismatched_model_gives_a_different_belief(env_id):
    other = MISMATCHED[env_id]()
    kwargs = FIXED_MAP.get(env_id, {})
    matched = HMMBeliefWrapper(gym.make(env_id, **kwargs))
    mismatched = HMMBeliefWrapper(gym.make(env_id, **kwargs), model=other, on_impossible="reset")
    assert mismatched.model is other and mismatched.filter.model is other
    om, _ = matched.reset(seed=12)
    ox, _ = mismatched.reset(seed=12)
    np.testing.assert_array_equal(om["observation"], ox["observation"])  # the same environment run
    largest_gap = float(np.abs(om["belief"] - ox["belief"]).max())
    n = matched.action_space.n
    for t in range(20):
        om, _, tm, trm, im = matched.step(t % n)
        ox, _, tx, trx, ix = mismatched.step(t % n)
        np.testing.assert_array_equal(om["observation"], ox["observation"])
        assert im["position"] == ix["position"]
        # The referee (the env's own model) is the same in both; only the wrapper's belief differs.
        np.testing.assert_allclose(om["belief"], matched.unwrapped.posterior, atol=1e-6)
        assert abs(float(ox["belief"].sum(dtype=np.float64)) - 1.0) < 1e-5
        largest_gap = max(largest_gap, float(np.abs(om["belief"] - ox["belief"]).max()))
        if tm or trm:
            break
    assert largest_gap > 1e-3


def test_belief_options_and_their_deprecated_spellings():
    with pytest.warns(DeprecationWarning, match="belief=True is deprecated: use belief='exact'"):
        env = HMMBeliefWrapper(gym.make("WindyMaze-v0"), belief=True)
    assert env.belief == "exact" and isinstance(env.filter, ForwardFilter)
    with pytest.raises(ValueError, match=r"^belief must be one of 'exact', 'particles'; got 'histogram'"):
        HMMBeliefWrapper(gym.make("WindyMaze-v0"), belief="histogram")
    with pytest.raises(TypeError, match="flatten must be True or False, got 'yes'"):
        HMMBeliefWrapper(gym.make("WindyMaze-v0"), flatten="yes")


def test_map_channels_follow_the_episodes_map():
    colour = HMMBeliefWrapper(gym.make("ColourGrid-v0", size=(6, 7), new_map_each_reset=True), map=True)
    assert colour.observation_space["map"] == spaces.Box(0.0, 1.0, (5, 6, 7), np.float32)
    for seed in (0, 1):
        obs, _ = colour.reset(seed=seed)
        grid = colour.unwrapped.model.grid
        assert obs["map"].dtype == np.float32 and obs in colour.observation_space
        np.testing.assert_array_equal(obs["map"][0], grid.free)
        for k in range(4):
            np.testing.assert_array_equal(obs["map"][1 + k], grid.labels == k)
        obs, *_ = colour.step(0)
        np.testing.assert_array_equal(obs["map"][0], grid.free)
    maze = HMMBeliefWrapper(gym.make("DepthMaze-v0"), map=True, flatten=True)
    obs, _ = maze.reset(seed=2)
    free = maze.unwrapped.model.grid.free
    assert obs.shape == (6 + 49 + 49,) and maze.observation_space.contains(obs)
    np.testing.assert_array_equal(obs[-49:].reshape(7, 7), free)  # one channel: the free cells
    np.testing.assert_allclose(obs[6:55].reshape(7, 7), maze.unwrapped.posterior, atol=1e-6)


# -- the wrapper's own arguments ---------------------------------------------------------------
def test_unknown_on_impossible():
    with pytest.raises(ValueError, match=r"^on_impossible must be one of 'raise', 'reset'; got 'x'"):
        HMMBeliefWrapper(gym.make("WindyMaze-v0"), on_impossible="x")


def test_wrapper_model_of_the_wrong_kind():
    with pytest.raises(TypeError, match=r"model must be a GridModel, got str"):
        HMMBeliefWrapper(gym.make("WindyMaze-v0"), model="windy")


def test_wrapper_model_with_another_observation_space():
    with pytest.raises(ValueError, match=r"the model's sensor emits Discrete\(4\) but the environment's observation space is MultiBinary\(4\)"):
        HMMBeliefWrapper(gym.make("WindyMaze-v0"), model=colour_grid_model())


def test_wrapper_model_with_another_number_of_actions():
    ring = ring_sensor_model((8, 8))
    two_actions = GridModel(ring.grid, ring.transitions[:2], ring.sensor)
    with pytest.raises(ValueError, match=r"the model has 2 actions but the environment's action space is Discrete\(4\)"):
        HMMBeliefWrapper(gym.make("RingSensor8x8-v0"), model=two_actions)


def test_wrapper_on_an_env_without_a_model():
    with pytest.raises(TypeError, match=r"no GridModel at env\.unwrapped\.model, so pass model="):
        HMMBeliefWrapper(gym.make("CartPole-v1"))


def test_wrapper_key_clash():
    env = HMMBeliefWrapper(gym.make("WindyMaze-v0"))
    with pytest.raises(ValueError, match=r"already has the key\(s\) \['belief'\]; pass key=\.\.\. to choose another"):
        HMMBeliefWrapper(env)
    assert "belief2" in HMMBeliefWrapper(env, key="belief2").observation_space.spaces


# -- model mismatch --------------------------------------------------------------------------------
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_impossible_observation_raises_by_default(env_id):
    env = HMMBeliefWrapper(gym.make(env_id, **SHARP_ENV.get(env_id, {})).unwrapped, model=SHARP_MISMATCH[env_id]())
    pattern = (r"impossible under the filter's model .* \(model mismatch\?\); "
               r"pass on_impossible='reset' to HMMBeliefWrapper to restart the belief from the prior")
    n = env.action_space.n
    seed = 0
    while True:  # find a start whose first reading the sharp model allows
        try:
            env.reset(seed=seed)
            break
        except ImpossibleObservationError as exc:
            assert isinstance(exc, ValueError) and "impossible" in str(exc)
            seed += 1
    with pytest.raises(ImpossibleObservationError, match=pattern) as caught:
        for t in range(2000):
            before = env.belief_array().copy()
            env.step(t % n)
    assert isinstance(caught.value, ValueError)
    # The belief is left as it was before the failed step (not poisoned with NaN).
    np.testing.assert_array_equal(env.belief_array(), before)
    assert np.all(np.isfinite(env.belief_array()))


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_impossible_observation_resets_the_belief_when_asked(env_id):
    other = SHARP_MISMATCH[env_id]()
    env = HMMBeliefWrapper(gym.make(env_id, **SHARP_ENV.get(env_id, {})).unwrapped, model=other, on_impossible="reset")
    n = env.action_space.n
    obs, info = env.reset(seed=0)
    assert info["belief_reset"] in (True, False)
    for t in range(2000):
        obs, _, _, _, info = env.step(t % n)
        assert type(info["belief_reset"]) is bool
        if info["belief_reset"]:
            break
    else:
        pytest.fail("no impossible observation in 2000 mismatched steps")
    # The belief restarted from the prior, updated with the observation if that is possible.
    fresh = ForwardFilter(other)
    try:
        fresh.reset(obs["observation"])
    except ImpossibleObservationError:
        fresh.reset()
    np.testing.assert_allclose(obs["belief"], fresh.position_belief, atol=1e-7)
    # The next ordinary step says False again.
    for t in range(50):
        obs, _, _, _, info = env.step(t % n)
        if not info["belief_reset"]:
            break
    assert info["belief_reset"] is False


def test_on_impossible_reset_on_the_first_reading():
    """An impossible first reading (before any move) also restarts from the prior."""
    other = colour_grid_model(layout=["R,R", "R,R"], accuracy=1.0)
    env_model_map = ["G,G", "G,G"]
    env = HMMBeliefWrapper(gym.make("ColourGrid-v0", layout=env_model_map, accuracy=1.0), model=other,
                           on_impossible="reset")
    obs, info = env.reset(seed=0)
    assert info["belief_reset"] is True
    np.testing.assert_allclose(obs["belief"], np.full((2, 2), 0.25, dtype=np.float32))
    strict = HMMBeliefWrapper(gym.make("ColourGrid-v0", layout=env_model_map, accuracy=1.0), model=other)
    with pytest.raises(ImpossibleObservationError):
        strict.reset(seed=0)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_ten_thousand_mismatched_steps(env_id):
    env = HMMBeliefWrapper(gym.make(env_id, **SHARP_ENV.get(env_id, {})), model=SHARP_MISMATCH[env_id](), on_impossible="reset")
    rng = np.random.default_rng(3)
    obs, info = env.reset(seed=3)
    resets = episodes = 0
    for _ in range(10_000):
        obs, _, terminated, truncated, info = env.step(int(rng.integers(env.action_space.n)))
        b = obs["belief"]
        assert not np.isnan(b).any() and np.all(np.isfinite(b))
        assert abs(float(b.sum(dtype=np.float64)) - 1.0) < 1e-5
        resets += info["belief_reset"]
        if terminated or truncated:
            obs, info = env.reset()
            episodes += 1
    assert resets > 10 and episodes > 0


def test_mismatch_with_soft_model_never_resets():
    """A mismatched model with no zero probabilities can never call a reading impossible."""
    env = HMMBeliefWrapper(gym.make("ColourGrid-v0", accuracy=0.88), model=colour_grid_model(accuracy=0.999),
                           on_impossible="reset")
    env.reset(seed=0)
    for t in range(3000):
        obs, _, terminated, truncated, info = env.step(t % 4)
        assert info["belief_reset"] is False
        if terminated or truncated:
            env.reset()


@pytest.mark.parametrize("env_id,kwargs", [
    ("WindyMaze-v0", {"p_detect": 0.999, "p_false_alarm": 0.001}),
    ("ColourGrid-v0", {"accuracy": 0.999}),
])
def test_env_memory_does_not_grow(env_id, kwargs):
    """20,000 steps of a wrapped environment (never reset): the memory traced by tracemalloc at
    step 20,000 is not above that at step 5,000."""
    env = HMMBeliefWrapper(gym.make(env_id, localise_threshold=1.0, **kwargs).unwrapped)
    rng = np.random.default_rng(0)
    actions = rng.integers(0, 4, size=20_000)
    env.reset(seed=0)
    traced = {}
    for t, a in enumerate(actions, start=1):
        obs, _, _, _, info = env.step(int(a))
        if t == 4_000:
            tracemalloc.start()
        elif t in (5_000, 20_000):
            traced[t] = tracemalloc.get_traced_memory()[0]
            b = obs["belief"]
            assert np.all(np.isfinite(b)) and abs(float(b.sum(dtype=np.float64)) - 1.0) < 1e-5
    tracemalloc.stop()
    assert traced[20_000] - traced[5_000] < 16 * 1024, traced


# -- the lookahead observation -------------------------------------------------------------------
@pytest.mark.parametrize("env_id", ["ColourGrid-v0", "WindyMaze-v0", "DepthMaze-v0"])
def test_lookahead_rows_are_the_greedy_policies_expected_entropies(env_id):
    """Row 0 is what greedy minimises, row 1 what greedy2 minimises (the Lookahead's exact
    expectations), as a fraction of log2 of the grid's cells (states with full_state)."""
    from gym_gridloc.lookahead import Lookahead

    full_state = env_id == "DepthMaze-v0"
    env = HMMBeliefWrapper(gym.make(env_id), lookahead=2, full_state=full_state)
    assert env.observation_space["lookahead"] == spaces.Box(0.0, 1.0, (2, env.unwrapped.model.n_actions), np.float32)
    obs, _ = env.reset(seed=4)
    for t in range(6):
        model = env.unwrapped.model
        look = Lookahead(model, pose=full_state)
        cells = model.shape[0] * model.shape[1] * (model.n_layers if full_state else 1)
        b = env.filter.full_belief
        expected = np.stack([look.one_step(b), look.two_step(b)]) / np.log2(cells)
        np.testing.assert_allclose(obs["lookahead"], expected, rtol=1e-6, atol=1e-7)
        assert obs in env.observation_space
        obs, _, terminated, truncated, _ = env.step(t % model.n_actions)
        if terminated or truncated:
            break


def test_lookahead_follows_the_map_and_flattens():
    env = HMMBeliefWrapper(gym.make("ColourGrid-v0", size=(6, 7), new_map_each_reset=True), map=True, lookahead=1)
    seen = []
    for seed in (0, 1):
        obs, _ = env.reset(seed=seed)
        seen.append(obs["lookahead"])
        assert obs["lookahead"].shape == (1, 4) and obs in env.observation_space
    assert not np.array_equal(seen[0], seen[1])  # two maps, two priors' expectations
    flat = HMMBeliefWrapper(gym.make("WindyMaze-v0"), flatten=True, lookahead=2)
    plain = HMMBeliefWrapper(gym.make("WindyMaze-v0"), flatten=True)
    dict_env = HMMBeliefWrapper(gym.make("WindyMaze-v0"), lookahead=2)
    a, _ = flat.reset(seed=3)
    b, _ = plain.reset(seed=3)
    c, _ = dict_env.reset(seed=3)
    assert a.shape == (b.shape[0] + 8,) and flat.observation_space.contains(a)
    np.testing.assert_array_equal(a[: b.shape[0]], b)
    np.testing.assert_array_equal(a[b.shape[0]:], c["lookahead"].ravel())
    run_check_env(flat)
    run_check_env(dict_env)


@pytest.mark.parametrize("bad", [3, -1, True, 1.5, "2"])
def test_lookahead_must_be_0_1_or_2(bad):
    with pytest.raises(ValueError, match="lookahead must be 0, 1 or 2"):
        HMMBeliefWrapper(gym.make("WindyMaze-v0"), lookahead=bad)


# -- PreviousActionWrapper (raw readings with the previous action, for memory-based agents) ----------
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_previous_action_wrapper_check_env_and_encoding(env_id):
    from gym_gridloc import PreviousActionWrapper

    run_check_env(PreviousActionWrapper(gym.make(env_id).unwrapped))
    raw, env = gym.make(env_id), PreviousActionWrapper(gym.make(env_id))
    n_obs, n_act = spaces.flatdim(raw.observation_space), int(raw.action_space.n)
    assert env.observation_space == spaces.Box(0.0, 1.0, (n_obs + n_act + 1,), np.float32)
    o_raw, _ = raw.reset(seed=3)
    obs, _ = env.reset(seed=3)
    assert obs.dtype == np.float32 and env.observation_space.contains(obs)
    np.testing.assert_array_equal(obs[:n_obs], spaces.flatten(raw.observation_space, o_raw))
    np.testing.assert_array_equal(obs[n_obs:], np.eye(n_act + 1)[n_act])  # no action yet
    for action in (a % n_act for a in (2, 0, 3, 1)):
        o_raw, r_raw, t_raw, tr_raw, _ = raw.step(action)
        obs, r, t, tr, _ = env.step(action)
        np.testing.assert_array_equal(obs[:n_obs], spaces.flatten(raw.observation_space, o_raw))
        np.testing.assert_array_equal(obs[n_obs:], np.eye(n_act + 1)[action])
        assert (r, t, tr) == (r_raw, t_raw, tr_raw)
        if t or tr:
            break


def test_previous_action_encoding_refuses_bad_actions():
    from gym_gridloc.wrappers import PreviousActionWrapper, with_previous_action

    space = spaces.Discrete(3)
    with pytest.raises(ValueError, match="previous action must be in 0..3 or None, got 4"):
        with_previous_action(space, 4, 1, 4)
    with pytest.raises(ValueError, match="previous action"):
        with_previous_action(space, 4, 1, -1)
    with pytest.raises(TypeError, match="Discrete action space"):
        PreviousActionWrapper(gym.wrappers.TransformAction(
            gym.make("ColourGrid-v0"), lambda a: int(a[0]), spaces.Box(0, 3, (1,))))
