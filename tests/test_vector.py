"""The native vector environment (gym_gridloc/vector.py).

One generator serves the whole batch (Gymnasium's CartPoleVectorEnv style), so:

* a vector env of ONE equals the single (wrapped) env exactly: same seed, same actions, the same
  observations, beliefs within 1e-12, rewards, terminations and infos, for every registered env
  and the options that change the numbers (kidnapping, passive dynamics, generated and redrawn
  maps, pose referee, fixed episode length, truncation, observation layouts);
* N envs are the same process as N single envs, not their random streams: the distributions of
  episode lengths, first readings, start states and the readings of the first steps agree
  (chi-square and two-sample tests, fixed seeds);
* each env's belief equals a ForwardFilter run on that env's own actions and observations.
"""

from __future__ import annotations

import re
import warnings
from collections import Counter

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from scipy import stats

import gym_gridloc
from gym_gridloc import (
    ForwardFilter,
    GridLocEnv,
    GridLocVectorEnv,
    HMMBeliefWrapper,
    referee,
    ring_sensor_model,
)
from tests.helpers import ENV_IDS

#: (env id, env keyword arguments, observation options of both the vector env and the wrapper).
ONE_CASES = [(env_id, {}, {}) for env_id in ENV_IDS] + [
    ("ColourGrid-v0", {"size": (7, 8), "n_colours": 5, "kidnap_prob": 0.05}, {}),
    ("ColourGrid-v0", {"size": (6, 6), "new_map_each_reset": True}, {"map": True}),
    ("WindyMaze-v0", {"size": (9, 8), "map_seed": 2}, {"flatten": True}),
    ("WindyMaze-v0", {"kidnap_prob": 0.1, "new_map_each_reset": True}, {}),
    ("RingSensor8x8-v0", {"size": (5, 6), "localise_threshold": 0.6}, {"flatten": True}),
    ("RingSensor8x8-v0", {"size": (5, 5), "dynamics": "passive", "localise_threshold": 0.5}, {"full_state": True}),
    ("RingSensor8x8-v0", {"layout": ["OOOOO", "O#O#O", "OOOOO", "O#OOO"], "localise_threshold": 0.6}, {}),
    ("RingSensor8x8-v0", {"max_episode_steps": 7}, {}),
    ("DepthMaze-v0", {"p_turn_fail": 0.1, "p_move_fail": 0.1, "p_depth_error": 0.1, "kidnap_prob": 0.02}, {"map": True}),
    ("DepthMaze-v0", {"episode_length": 12, "reward": "belief"}, {}),
    ("DepthMaze-v0", {"size": 5}, {"map": True}),  # (the mazes drawn in the step's call; each env's map observed)
    ("DepthMaze-v0", {"size": 9}, {}),  # (too many walls for the step's table: the map factory's codes)
    ("ColourGrid-v0", {"size": (6, 6), "new_map_each_reset": True}, {"map": True, "lookahead": 2}),
    ("WindyMaze-v0", {"kidnap_prob": 0.1}, {"flatten": True, "lookahead": 1}),
]
ONE_IDS = [f"{e}-{k}-{o}" for e, k, o in ONE_CASES]


def make_pair(env_id, kwargs, options, n=1):
    """The native vector env of ``n`` and one single wrapped env, built alike."""
    native = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kwargs, **options)
    single = HMMBeliefWrapper(gym.make(env_id, **kwargs), **options)
    return native, single


def assert_same_observation(vobs, i, sobs):
    """Env ``i`` of a batched observation against a single one: readings and maps exactly, the
    float32 beliefs and expected entropies within 1e-7 (float64 beliefs within 1e-12 may round
    either way)."""
    if isinstance(sobs, dict):
        assert set(vobs) == set(sobs)
        for key, value in sobs.items():
            if key in ("belief", "lookahead"):
                np.testing.assert_allclose(vobs[key][i], value, rtol=0, atol=1e-7)
            else:
                np.testing.assert_array_equal(vobs[key][i], np.asarray(value))
    else:
        np.testing.assert_allclose(vobs[i], sobs, rtol=0, atol=1e-7)


def assert_same_info(vinfo, i, info, belief):
    """Env ``i`` of batched infos against a single env's info.  The estimate is an argmax: where
    two cells tie exactly in exact arithmetic, rounding (1e-16) may pick either; both must be most
    probable within 1e-12."""
    assert {k for k in vinfo if not k.startswith("_")} == set(info)
    assert tuple(vinfo["position"][i]) == info["position"]
    if "heading" in info:
        assert int(vinfo["heading"][i]) == info["heading"]
    tested = belief.reshape(-1) if "estimate_heading" in info else belief.sum(axis=0).reshape(-1)
    r, c = vinfo["estimate"][i]
    k = (int(vinfo["estimate_heading"][i]) * belief[0].size if "estimate_heading" in info else 0) + r * belief.shape[2] + c
    assert tested[k] >= tested.max() - 1e-12
    if (r, c) == tuple(info["estimate"]) and vinfo.get("estimate_heading", [None] * (i + 1))[i] == info.get("estimate_heading"):
        assert vinfo["success"][i] == info["success"] and vinfo["error"][i] == info["error"]
    assert vinfo["confidence"][i] == pytest.approx(info["confidence"], abs=1e-12)
    assert vinfo["entropy"][i] == pytest.approx(info["entropy"], abs=1e-9)
    assert bool(vinfo["localised"][i]) == info["localised"]


@pytest.mark.parametrize("env_id,kwargs,options", ONE_CASES, ids=ONE_IDS)
def test_a_vector_env_of_one_equals_the_single_env(env_id, kwargs, options):
    native, single = make_pair(env_id, kwargs, options)
    u = native.unwrapped
    assert native.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert native.single_observation_space == single.observation_space
    vobs, vinfo = native.reset(seed=3)
    sobs, info = single.reset(seed=3)
    rng = np.random.default_rng(0)
    ended = resets = 0
    pending = False  # NEXT_STEP autoreset: the step after an episode's end resets the env
    limit = kwargs.get("max_episode_steps", gym.spec(env_id).max_episode_steps)
    for t in range(max(250, limit + 30)):  # past the time limit: every case ends an episode
        assert native.observation_space.contains(vobs)
        assert_same_observation(vobs, 0, sobs)
        assert u.states[0].tolist() == list(single.unwrapped.state)
        assert u.models[0] is not None and u.models[0].grid.labels.tolist() == single.unwrapped.model.grid.labels.tolist()
        np.testing.assert_allclose(u.full_beliefs[0], single.filter.full_belief, rtol=0, atol=1e-12)
        np.testing.assert_allclose(u.full_beliefs[0], single.unwrapped._referee.full_belief, rtol=0, atol=1e-12)
        assert_same_info(vinfo, 0, info, single.filter.full_belief)
        a = int(rng.integers(native.single_action_space.n))
        vobs, vrew, vterm, vtrunc, vinfo = native.step(np.array([a]))
        if pending:
            sobs, info = single.reset()
            rew, term, trunc = 0.0, False, False
            resets += 1
        else:
            sobs, rew, term, trunc, info = single.step(a)
        assert vrew.dtype == np.float64 and vrew[0] == pytest.approx(rew, abs=1e-12)
        if kwargs.get("reward", "step") == "step":
            assert vrew[0] == rew
        assert bool(vterm[0]) == term and bool(vtrunc[0]) == trunc
        pending = term or trunc
        ended += pending
    assert ended > 0 and resets > 0  # autoresets were exercised


def test_seeds_of_the_one_generator():
    env = gym.make_vec("WindyMaze-v0", num_envs=3, vectorization_mode="vector_entry_point")
    first = [env.reset(seed=5), env.reset(seed=[5]), env.reset(seed=[5, 6, 7]), env.reset(seed=[5, 6, 7]), env.reset(seed=[5, 6, 8])]
    (o5, i5), (o5l, i5l), (a, ia), (b, ib), (c, ic) = first
    np.testing.assert_array_equal(o5["observation"], o5l["observation"])  # [s] seeds as s
    np.testing.assert_array_equal(i5["position"], i5l["position"])
    np.testing.assert_array_equal(a["observation"], b["observation"])
    np.testing.assert_array_equal(ia["position"], ib["position"])
    assert not (np.array_equal(ia["position"], ic["position"]) and np.array_equal(a["observation"], c["observation"]))
    # The first env of a batch of one seeded with s equals the single env seeded with s.
    one = gym.make_vec("WindyMaze-v0", num_envs=1, vectorization_mode="vector_entry_point")
    single = HMMBeliefWrapper(gym.make("WindyMaze-v0"))
    (vobs, vinfo), (sobs, sinfo) = one.reset(seed=6), single.reset(seed=6)
    assert tuple(vinfo["position"][0]) == sinfo["position"]
    np.testing.assert_array_equal(vobs["observation"][0], sobs["observation"])
    np.testing.assert_array_equal(vobs["belief"][0], sobs["belief"])
    with pytest.raises(ValueError, match=r"seed must be a non-negative integer"):
        env.reset(seed=-1)
    with pytest.raises(ValueError, match=r"seed must be a non-negative integer, a list of them, or None; got 'x'"):
        env.reset(seed="x")


def test_the_referee_options_through_a_generic_vector_env():
    """A GridLocVectorEnv over the generic GridLocEnv class (pose referee, fixed episode length,
    belief reward) equals the single GridLocEnv."""
    model = ring_sensor_model((4, 5), dynamics="passive", p_true=0.5, p_ring1=0.04, p_ring2=0.01)
    kwargs = {"model": model, "referee_pose": True, "episode_length": 9, "reward": "belief", "localise_threshold": 0.4}
    native = GridLocVectorEnv(1, env_class=GridLocEnv, **kwargs)
    single = HMMBeliefWrapper(GridLocEnv(**kwargs))
    vobs, vinfo = native.reset(seed=1)
    sobs, info = single.reset(seed=1)
    rng = np.random.default_rng(2)
    pending, ended = False, 0
    for _ in range(40):
        assert_same_observation(vobs, 0, sobs)
        assert_same_info(vinfo, 0, info, single.filter.full_belief)
        a = int(rng.integers(4))
        vobs, vrew, vterm, vtrunc, vinfo = native.step(np.array([a]))
        if pending:
            sobs, info = single.reset()
            rew, term, trunc = 0.0, False, False
        else:
            sobs, rew, term, trunc, info = single.step(a)
            assert not term and vrew[0] == pytest.approx(info["confidence"], abs=1e-12)
        assert vrew[0] == pytest.approx(rew, abs=1e-12) and bool(vterm[0]) == term and bool(vtrunc[0]) == trunc
        pending = term or trunc
        ended += trunc
    assert ended >= 3  # truncated at 9 steps every time


# -- N envs: each belief is its env's own filter --------------------------------------------------------
EACH_CASES = [
    ("ColourGrid-v0", {"kidnap_prob": 0.05}),
    ("WindyMaze-v0", {"size": (7, 9), "new_map_each_reset": True}),
    ("RingSensor8x8-v0", {"size": (4, 5), "dynamics": "passive", "localise_threshold": 0.5, "max_episode_steps": 40}),
    ("DepthMaze-v0", {"p_depth_error": 0.1, "max_episode_steps": 20}),
]


@pytest.mark.parametrize("env_id,kwargs", EACH_CASES, ids=[f"{e}-{k}" for e, k in EACH_CASES])
def test_each_env_of_a_vector_env_equals_a_filter_on_its_own_run(env_id, kwargs):
    n = 5
    native = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)
    u = native.unwrapped
    obs, info = native.reset(seed=11)
    filters = [ForwardFilter(u.models[i]).reset(obs["observation"][i]) for i in range(n)]
    rng = np.random.default_rng(4)
    pending = np.zeros(n, dtype=bool)
    ended = 0
    for _ in range(120):
        beliefs = u.full_beliefs
        ref = np.stack([f.full_belief for f in filters])
        np.testing.assert_allclose(beliefs, ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(obs["belief"], ref.sum(axis=1), rtol=0, atol=1e-7)
        mine = referee.summarise(ref, u.states, u.template.localise_threshold, pose=u.template.referee_pose)
        np.testing.assert_allclose(info["confidence"], mine["confidence"], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(info["position"], mine["position"])
        actions = rng.integers(native.single_action_space.n, size=n)
        obs, rew, term, trunc, info = native.step(actions)
        for i in range(n):
            if pending[i]:  # reset by this step: a new episode (and, maybe, a new map)
                filters[i] = ForwardFilter(u.models[i]).reset(obs["observation"][i])
                assert rew[i] == 0.0 and not term[i] and not trunc[i]
            else:
                filters[i].step(int(actions[i]), obs["observation"][i])
        pending = term | trunc
        ended += int(pending.sum())
    assert ended >= n


# -- N envs against N single envs, statistically -------------------------------------------------------
#: Chi-square / two-sample tests reject at p < ALPHA (fixed seeds: the outcome is the same on every run).
ALPHA = 1e-3
N_EPISODES = 2000
STAT_CASES = [
    ("ColourGrid-v0", {}),
    ("WindyMaze-v0", {}),
    ("RingSensor8x8-v0", {"size": (4, 4), "dynamics": "passive", "p_true": 0.5, "p_ring1": 0.03, "p_ring2": 0.01}),
    ("DepthMaze-v0", {"map_seed": 0, "p_depth_error": 0.1, "max_episode_steps": 15}),
]
FIRST_STEPS = 3  # the readings of steps 1..3 are compared step by step


def _start(info, i=None):
    """The start state of an episode from its first info: (heading, row, col) or (row, col)."""
    pick = (lambda v: v) if i is None else (lambda v: v[i])
    pos = tuple(int(x) for x in pick(info["position"]))
    return (int(pick(info["heading"])), *pos) if "heading" in info else pos


def vector_episodes(env_id, kwargs, n_envs: int, n_episodes: int, seed: int) -> list[dict]:
    """Finished episodes of a native vector env under uniformly random actions."""
    venv = gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point", belief=None, **kwargs)
    sensor = venv.unwrapped.template.model.sensor
    rng = np.random.default_rng(seed + 1)
    obs, info = venv.reset(seed=seed)
    readings = sensor.readings(obs, n_envs)
    current = [{"start": _start(info, i), "first": int(readings[i]), "readings": [], "length": 0} for i in range(n_envs)]
    pending = np.zeros(n_envs, dtype=bool)
    out = []
    while len(out) < n_episodes:
        obs, _, term, trunc, info = venv.step(rng.integers(venv.single_action_space.n, size=n_envs))
        readings = sensor.readings(obs, n_envs)
        for i in range(n_envs):
            if pending[i]:
                current[i] = {"start": _start(info, i), "first": int(readings[i]), "readings": [], "length": 0}
            else:
                current[i]["length"] += 1
                current[i]["readings"].append(int(readings[i]))
                if term[i] or trunc[i]:
                    out.append(current[i])
        pending = term | trunc
    venv.close()
    return out[:n_episodes]


def single_episodes(env_id, kwargs, n_envs: int, n_episodes: int, seed: int) -> list[dict]:
    """Finished episodes of ``n_envs`` single envs (seeded apart) under uniformly random actions."""
    envs = [gym.make(env_id, **kwargs) for _ in range(n_envs)]
    sensor = envs[0].unwrapped.model.sensor
    rng = np.random.default_rng(seed + 1)
    out = []
    for k in range(n_episodes):
        env = envs[k % n_envs]
        obs, info = env.reset(seed=seed + k) if k < n_envs else env.reset()
        episode = {"start": _start(info), "first": sensor.to_reading(obs), "readings": [], "length": 0}
        while True:
            obs, _, term, trunc, info = env.step(int(rng.integers(env.action_space.n)))
            episode["length"] += 1
            episode["readings"].append(sensor.to_reading(obs))
            if term or trunc:
                break
        out.append(episode)
    return out


def assert_same_distribution(a: list, b: list, what: str) -> None:
    """Two samples of a discrete variable come from the same distribution: a chi-square test of
    the 2 x K table (categories seen fewer than 10 times in both samples together are pooled),
    and the same support: a category seen 20 times or more in both samples together is seen in
    each (under the null hypothesis, and samples of about equal size, all 20 fall in one sample
    with probability 2 * 2**-20)."""
    ca, cb = Counter(a), Counter(b)
    assert 0.9 < len(a) / len(b) < 1.1
    missing = [cat for cat in set(ca) | set(cb) if ca[cat] + cb[cat] >= 20 and min(ca[cat], cb[cat]) == 0]
    assert not missing, f"{what}: seen in one sample only: {sorted(missing)[:5]} (counts {[(ca[c], cb[c]) for c in sorted(missing)[:5]]})"
    table, rare = [], [0, 0]
    for cat in sorted(set(ca) | set(cb)):
        if ca[cat] + cb[cat] < 10:
            rare[0] += ca[cat]
            rare[1] += cb[cat]
        else:
            table.append([ca[cat], cb[cat]])
    if sum(rare):
        table.append(rare)
    assert len(table) >= 2, f"{what}: a single category; nothing to compare"
    _, p, dof, _ = stats.chi2_contingency(np.array(table).T)
    assert p > ALPHA, f"{what}: the vector env and the single envs differ (chi-square p = {p:.2e}, {dof} dof)"


@pytest.mark.parametrize("env_id,kwargs", STAT_CASES, ids=[f"{e}-{k}" for e, k in STAT_CASES])
def test_n_envs_are_n_single_envs_statistically(env_id, kwargs):
    vec = vector_episodes(env_id, kwargs, 16, N_EPISODES, seed=100)
    one = single_episodes(env_id, kwargs, 16, N_EPISODES, seed=100)
    lengths_v, lengths_s = [e["length"] for e in vec], [e["length"] for e in one]
    assert_same_distribution(lengths_v, lengths_s, "episode lengths")
    ks = stats.ks_2samp(lengths_v, lengths_s)
    assert ks.pvalue > ALPHA, f"episode lengths: two-sample KS p = {ks.pvalue:.2e}"
    assert_same_distribution([e["first"] for e in vec], [e["first"] for e in one], "first readings")
    assert_same_distribution([e["start"] for e in vec], [e["start"] for e in one], "start states")
    for k in range(FIRST_STEPS):
        assert_same_distribution([e["readings"][k] for e in vec if len(e["readings"]) > k],
                                 [e["readings"][k] for e in one if len(e["readings"]) > k], f"readings of step {k + 1}")


# -- autoreset, arguments, observation layouts ----------------------------------------------------------
def test_same_step_autoreset_gives_final_observations():
    env = gym.make_vec("ColourGrid-v0", num_envs=4, vectorization_mode="vector_entry_point",
                       autoreset_mode=AutoresetMode.SAME_STEP, max_episode_steps=5)
    env.reset(seed=0)
    ever = np.zeros(4, dtype=bool)
    for _ in range(5):
        obs, rew, term, trunc, info = env.step(np.zeros(4, dtype=np.int64))
        done = term | trunc
        if not done.any():  # the final observations are there when an episode ended
            assert "final_obs" not in info and "_final_obs" not in info
            continue
        assert np.array_equal(info["_final_obs"], done) and np.array_equal(info["_final_info"], done)
        for i in np.flatnonzero(done):
            assert set(info["final_obs"][i]) == {"observation", "belief"}
            assert set(info["final_info"][i]) >= {"position", "confidence", "localised"}
        assert np.all(env.unwrapped.batch.rows.elapsed[done] == 0)  # already reset
        assert np.all(rew == -1.0)  # every env stepped: no reset step in between
        ever |= done
    assert ever.all()  # every episode ends by the 5th step at the latest
    env.unwrapped.set_autoreset_mode(AutoresetMode.NEXT_STEP)
    assert env.unwrapped.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP


def test_vector_env_arguments_are_checked():
    env = gym.make_vec("ColourGrid-v0", num_envs=2, vectorization_mode="vector_entry_point")
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.array([0, 0]))
    with pytest.raises(ValueError, match=r"the first reset must reset every environment: .* environment\(s\) \[1\] without a state"):
        env.reset(seed=0, options={"reset_mask": np.array([True, False])})
    env.reset(seed=0)
    env.reset(options={"reset_mask": np.array([True, False])})  # later, a partial reset is fine
    with pytest.raises(ValueError, match=r"options\['reset_mask'\] must be 2 booleans"):
        env.reset(options={"reset_mask": [1, 0]})
    with pytest.raises(ValueError, match=r"unknown reset option\(s\) \['state'\]; allowed: 'reset_mask'"):
        env.reset(options={"state": (0, 0)})
    with pytest.raises(ValueError, match=r"action 7 of env 1 is not in the action space Discrete\(4\) \(0=N, 1=E, 2=S, 3=W\)"):
        env.step(np.array([0, 7]))
    with pytest.raises(ValueError, match="actions must be 2 integers"):
        env.step(np.array([0, 1, 2]))
    with pytest.raises(ValueError, match=r"^belief must be one of 'exact', None; got 'yes'"):
        gym.make_vec("ColourGrid-v0", num_envs=2, vectorization_mode="vector_entry_point", belief="yes")
    with pytest.raises(ValueError, match="num_envs must be a positive integer"):
        GridLocVectorEnv(0, env_class=gym_gridloc.ColourGridEnv)
    with pytest.raises(ValueError, match="does not render"):
        GridLocVectorEnv(2, env_class=gym_gridloc.ColourGridEnv, render_mode="rgb_array")
    with pytest.raises(TypeError, match="flatten must be True or False"):
        GridLocVectorEnv(2, env_class=gym_gridloc.ColourGridEnv, flatten=1)
    with pytest.raises(ValueError, match="lookahead must be 0, 1 or 2"):
        GridLocVectorEnv(2, env_class=gym_gridloc.ColourGridEnv, lookahead=3)
    with pytest.raises(ValueError, match="lookahead needs a belief"):
        GridLocVectorEnv(2, env_class=gym_gridloc.ColourGridEnv, belief=None, lookahead=1)
    with pytest.raises(ValueError, match="max_episode_steps must be a positive integer or None"):
        GridLocVectorEnv(2, env_class=gym_gridloc.ColourGridEnv, max_episode_steps=0)
    with pytest.raises(ValueError, match="autoreset_mode must be"):
        GridLocVectorEnv(2, env_class=gym_gridloc.ColourGridEnv, autoreset_mode=AutoresetMode.DISABLED)
    # A map redrawn at every reset is supported (each env its own model).
    redrawn = gym.make_vec("ColourGrid-v0", num_envs=3, vectorization_mode="vector_entry_point", new_map_each_reset=True)
    redrawn.reset(seed=1)
    assert len({id(m) for m in redrawn.unwrapped.models}) == 3


def test_deprecated_belief_spellings():
    with pytest.warns(DeprecationWarning, match="belief=True is deprecated: use belief='exact'"):
        on = gym.make_vec("WindyMaze-v0", num_envs=2, vectorization_mode="vector_entry_point", belief=True)
    with pytest.warns(DeprecationWarning, match="belief=False is deprecated: use belief=None"):
        off = gym.make_vec("WindyMaze-v0", num_envs=2, vectorization_mode="vector_entry_point", belief=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        exact = gym.make_vec("WindyMaze-v0", num_envs=2, vectorization_mode="vector_entry_point", belief="exact")
        bare = gym.make_vec("WindyMaze-v0", num_envs=2, vectorization_mode="vector_entry_point", belief=None)
    assert on.unwrapped.belief == "exact" and off.unwrapped.belief is None
    assert on.single_observation_space == exact.single_observation_space
    assert off.single_observation_space == bare.single_observation_space == gym.spaces.MultiBinary(4)
    for a, b in ((on, exact), (off, bare)):
        oa, _ = a.reset(seed=2)
        ob, _ = b.reset(seed=2)
        for _ in range(10):
            if isinstance(oa, dict):
                for k in oa:
                    np.testing.assert_array_equal(oa[k], ob[k])
            else:
                np.testing.assert_array_equal(oa, ob)
            oa, *_ = a.step(np.array([0, 1]))
            ob, *_ = b.step(np.array([0, 1]))
    with pytest.warns(DeprecationWarning, match="GridLocVectorEnv.beliefs is deprecated: use full_beliefs"):
        np.testing.assert_array_equal(exact.unwrapped.beliefs, exact.unwrapped.full_beliefs)


def test_readings_only_and_flat_observations():
    native = gym.make_vec("WindyMaze-v0", num_envs=1, vectorization_mode="vector_entry_point", belief=None)
    single = gym.make("WindyMaze-v0")
    assert native.single_observation_space == single.observation_space
    o1, _ = native.reset(seed=1)
    o2, _ = single.reset(seed=1)
    for t in range(40):
        np.testing.assert_array_equal(o1[0], o2)
        o1, _, te, tr, _ = native.step(np.array([t % 4]))
        o2, _, te2, tr2, _ = single.step(t % 4)
        assert bool(te[0]) == te2 and bool(tr[0]) == tr2
        if te2 or tr2:
            break
    flat = gym.make_vec("ColourGrid-v0", num_envs=3, vectorization_mode="vector_entry_point", flatten=True)
    o1, _ = flat.reset(seed=2)
    assert o1.shape == (3, 4 + 25) and o1.dtype == np.float32
    for _ in range(20):
        assert flat.observation_space.contains(o1)
        np.testing.assert_allclose(o1[:, 4:].reshape(3, 5, 5), flat.unwrapped.position_beliefs, rtol=0, atol=1e-7)
        np.testing.assert_array_equal(o1[:, :4], np.eye(4, dtype=np.float32)[flat.unwrapped.batch.rows.readings])
        o1, *_ = flat.step(np.array([1, 2, 3]))


def test_native_vector_env_on_a_256x256_ring_grid():
    env = gym.make_vec("RingSensor8x8-v0", num_envs=4, vectorization_mode="vector_entry_point", size=(256, 256))
    obs, info = env.reset(seed=1)
    for _ in range(3):
        obs, rewards, terminated, truncated, info = env.step(np.array([0, 1, 2, 3]))
    assert obs["belief"].shape == (4, 256, 256)
    np.testing.assert_allclose(obs["belief"].sum(axis=(1, 2)), 1.0, atol=1e-4)


def test_bench_step_script_compares_and_bounds(capsys):
    """scripts/bench_step.py on tiny settings: the wrapped and vector comparisons print a ratio
    and a verdict for each environment, and DepthMaze (a new map per reset) its map-building bound."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "scripts" / "bench_step.py"
    spec = importlib.util.spec_from_file_location("bench_step", path)
    bench_step = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench_step)
    bench_step.main(["--envs", "WindyMaze-v0", "DepthMaze-v0", "--steps", "40", "--rounds", "2",
                     "--num-envs", "4", "--vector-steps", "20"])
    out = capsys.readouterr().out
    for env_id in ("WindyMaze-v0", "DepthMaze-v0"):
        assert re.search(rf"{env_id}\s+\|\s+[\d.]+us\s+[\d.]+us \|\s+[\d.]+x <= [\d.]+x: (met|NOT met)", out), out
        assert re.search(rf"{env_id}\s+\|\s+\d+/s\s+\d+/s \|\s+[\d.]+x >= 40x: (met|NOT met)", out), out
    bound = re.findall(r"([\d.]+) new maps per vector step at ([\d.]+) ms each .*native / sync <= ([\d.]+)x", out)
    assert len(bound) == 1 and float(bound[0][1]) > 0  # DepthMaze only: WindyMaze keeps its map


def test_a_rejected_step_changes_nothing_and_actions_are_never_written():
    """A bad action (also a negative one, on the fast path of int64 arrays) raises before any
    draw: the states, beliefs and the generator are as before; the caller's actions array is
    never written; each ``_key`` mask of the info is an array of its own."""
    env = gym.make_vec("WindyMaze-v0", num_envs=4, vectorization_mode="vector_entry_point")
    twin = gym.make_vec("WindyMaze-v0", num_envs=4, vectorization_mode="vector_entry_point")
    env.reset(seed=5)
    twin.reset(seed=5)
    for bad in (np.array([0, 1, -1, 2]), np.array([0, 1, 2, 4]), np.array([0, 1, 2, 3], dtype=np.int32)[[0, 1, 2, 2]] + [0, 0, 0, 9]):
        with pytest.raises(ValueError, match="is not in the action space"):
            env.step(bad)
    actions = np.array([3, 2, 1, 0])
    for _ in range(30):
        a, b = env.step(actions), twin.step(actions.copy())
        assert np.array_equal(a[0]["belief"], b[0]["belief"]) and np.array_equal(a[1], b[1])
        assert np.array_equal(env.unwrapped.states, twin.unwrapped.states)
    assert actions.tolist() == [3, 2, 1, 0]
    info = a[4]
    info["_entropy"][0] = False
    assert info["_confidence"].all() and info["_localised"].all()


def test_the_steps_entry_point_and_the_dispatcher_give_the_same_steps():
    """The bank calls the compiled step's entry point for the usual argument types (writable
    C-contiguous int64 actions, int8 modes) and numba's dispatcher otherwise: read-only actions
    (the vector env passes them on as they are) step the rows exactly as writable ones."""
    env = gym.make_vec("DepthMaze-v0", num_envs=6, vectorization_mode="vector_entry_point")
    twin = gym.make_vec("DepthMaze-v0", num_envs=6, vectorization_mode="vector_entry_point")
    env.reset(seed=11)
    twin.reset(seed=11)
    rng = np.random.default_rng(0)
    bank = env.unwrapped.batch.bank
    for t in range(60):
        actions = rng.integers(0, 3, size=6)
        frozen = actions.copy()
        frozen.flags.writeable = False
        a, b = env.step(actions), twin.step(frozen if t % 2 else actions)
        assert np.array_equal(a[0]["belief"], b[0]["belief"]) and np.array_equal(a[1], b[1]) and np.array_equal(a[3], b[3])
        assert a[4]["entropy"].tolist() == b[4]["entropy"].tolist()
        assert np.array_equal(env.unwrapped.states, twin.unwrapped.states)
    assert bank._entry is not None and bank._entry[0] is bank._fast.vector_advance.overloads[
        tuple(bank._fast.vector_advance.typeof_pyval(x) for x in (bank._tables, env.unwrapped.batch.rows.compiled, actions,
                                                                  np.zeros(6, dtype=np.int8), env.unwrapped.batch.blocks.compiled,
                                                                  bank._functions))].entry_point


@pytest.mark.parametrize("env_id", ["RingSensor8x8-v0", "DepthMaze-v0"])
def test_a_vector_env_pickles_and_goes_on_as_the_original(env_id):
    """(DepthMaze: a maze per reset, each environment on its own slot of the engine's bank.)"""
    import pickle

    env = gym.make_vec(env_id, num_envs=5, vectorization_mode="vector_entry_point").unwrapped
    k = env.single_action_space.n
    env.reset(seed=2)
    env.step(np.array([0, 1, 2, 3, 0]) % k)
    twin = pickle.loads(pickle.dumps(env))
    for t in range(60):
        a = (np.arange(5) + t) % k
        (oa, ra, *_), (ob, rb, *_) = env.step(a), twin.step(a)
        assert np.array_equal(oa["belief"], ob["belief"]) and np.array_equal(ra, rb)
    assert np.array_equal(env.states, twin.states)


@pytest.mark.parametrize("env_id, kwargs", [("WindyMaze-v0", {"kidnap_prob": 0.1}), ("DepthMaze-v0", {}),
                                             ("ColourGrid-v0", {"size": (6, 6), "new_map_each_reset": True}),
                                             ("RingSensor8x8-v0", {"size": (130, 130)})])
def test_the_single_env_is_the_steps_n_1_view_to_the_bit(env_id, kwargs):
    """The single env and the vector env of one are views of the same step (batch.Batch): the same
    beliefs, infos, rewards and ends to the bit (compiled step, numpy reference, redrawn maps)."""
    native = gym.make_vec(env_id, num_envs=1, vectorization_mode="vector_entry_point", **kwargs).unwrapped
    single = gym.make(env_id, **kwargs)
    assert single.unwrapped._batch.n == 1
    _, vinfo = native.reset(seed=11)
    _, info = single.reset(seed=11)
    rng = np.random.default_rng(0)
    pending = False
    for _ in range(25 if kwargs.get("size") == (130, 130) else 150):
        assert native.full_beliefs[0].tobytes() == single.unwrapped.exact_filter.full_belief.tobytes()
        assert referee.scalars(vinfo, 0) == info
        a = int(rng.integers(native.single_action_space.n))
        _, vr, vt, vtr, vinfo = native.step(np.array([a]))
        if pending:
            _, info = single.reset()
            r, t, tr = 0.0, False, False
        else:
            _, r, t, tr, info = single.step(a)
        assert (vr[0], bool(vt[0]), bool(vtr[0])) == (r, t, tr)
        pending = t or tr
