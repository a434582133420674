"""The generic environment (gym_gridloc/envs/base.py): reset options, the order of calls, actions,
info keys and the referee's termination, the referee options (pose, fixed episode length, belief
reward), edge cases, and the simulator sampling exactly the model's probabilities."""

from __future__ import annotations

import math
import re

import gymnasium as gym
import numpy as np
import pytest

from gym_gridloc import GridLocEnv, HMMBeliefWrapper, ring_sensor_model
from gym_gridloc.engine import transition_matrix
from tests.helpers import (
    CONFIG_IDS,
    CONFIGS,
    DEFAULT_MODELS,
    ENV_CLASSES,
    ENV_IDS,
    ENV_OF_MODEL,
    assert_counts_match,
    exercise,
    pick_states,
)

INFO_KEYS = {"position", "estimate", "confidence", "error", "localised", "success", "entropy"}


# -- info, rewards, termination ---------------------------------------------------------------------
def entropy_bits(p: np.ndarray) -> float:
    p = p[p > 0]
    return float(-(p * np.log2(p)).sum())


def check_info(env, info) -> None:
    u = env.unwrapped
    post = u.posterior
    model = u.model
    assert INFO_KEYS <= set(info)
    pos, est = info["position"], info["estimate"]
    assert isinstance(pos, tuple) and len(pos) == 2 and all(isinstance(v, int) for v in pos)
    assert isinstance(est, tuple) and len(est) == 2 and all(isinstance(v, int) for v in est)
    assert pos == u.state[1:]
    assert model.grid.free[pos] and model.grid.free[est]
    assert isinstance(info["confidence"], float)
    if u.referee_pose:  # the referee tests the most probable hidden state (cell and heading)
        full = u._referee.full_belief
        assert type(info["estimate_heading"]) is int
        assert info["confidence"] == full.max() == full[(info["estimate_heading"], *est)]
        right = (info["estimate_heading"], *est) == u.state
    else:
        assert info["confidence"] == post.max() == post[est]
        assert "estimate_heading" not in info
        right = est == pos
    assert isinstance(info["error"], int) and info["error"] == abs(pos[0] - est[0]) + abs(pos[1] - est[1])
    assert type(info["localised"]) is bool
    assert info["localised"] == (info["confidence"] >= u.localise_threshold)
    assert type(info["success"]) is bool and info["success"] == (info["localised"] and right)
    assert isinstance(info["entropy"], float)
    assert info["entropy"] == pytest.approx(entropy_bits(post), abs=1e-9)
    assert 0.0 <= info["entropy"] <= math.log2(model.grid.n_free) + 1e-9
    assert abs(post.sum() - 1.0) < 1e-9 and np.all(post[~model.grid.free] == 0)
    if model.n_layers > 1:
        assert type(info["heading"]) is int and info["heading"] == u.state[0]
    else:
        assert "heading" not in info


@pytest.mark.parametrize("env_id,kwargs", CONFIGS, ids=CONFIG_IDS)
def test_info_keys_rewards_and_termination(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    rng = np.random.default_rng(1)
    n_terminated = 0
    for episode in range(4):
        obs, info = env.reset(seed=100 + episode)
        assert obs in env.observation_space
        check_info(env, info)
        for t in range(env.spec.max_episode_steps):
            obs, reward, terminated, truncated, info = env.step(int(rng.integers(env.action_space.n)))
            assert obs in env.observation_space
            assert type(reward) is float and reward == -1.0
            assert type(terminated) is bool and type(truncated) is bool
            check_info(env, info)
            assert terminated == (info["confidence"] >= env.unwrapped.localise_threshold)
            if terminated or truncated:
                n_terminated += terminated
                break
    assert n_terminated >= 1  # episodes do end by localising


@pytest.mark.parametrize("threshold", [0.5, 0.75, 0.99])
def test_threshold_controls_termination(threshold):
    env = gym.make("WindyMaze-v0", localise_threshold=threshold)
    env.reset(seed=0)
    for t in range(100):
        _, _, terminated, truncated, info = env.step(t % 4)
        assert terminated == (info["confidence"] >= threshold)
        if terminated or truncated:
            break


def test_single_free_cell_is_localised_at_once():
    env = gym.make("ColourGrid-v0", layout=[".,.,.", ".,G,.", ".,.,."])
    _, info = env.reset(seed=0)
    assert info["confidence"] == 1.0 and info["localised"] and info["success"] and info["entropy"] == 0.0
    _, _, terminated, _, info = env.step(0)
    assert terminated and info["position"] == (1, 1)


# -- the referee's options ---------------------------------------------------------------------------
def test_referee_pose_tests_the_most_probable_hidden_state():
    model = ring_sensor_model((5, 5), dynamics="passive", p_true=0.6, p_ring1=0.03, p_ring2=0.01)
    env = GridLocEnv(model, referee_pose=True, localise_threshold=0.5)
    plain = GridLocEnv(model, localise_threshold=0.5)
    obs, info = env.reset(seed=3)
    plain.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(60):
        a = int(rng.integers(4))
        _, _, terminated, _, info = env.step(a)
        _, _, _, _, pinfo = plain.step(a)
        full = env._referee.full_belief
        layer, r, c = np.unravel_index(int(np.argmax(full)), full.shape)
        assert info["estimate"] == (r, c) and info["estimate_heading"] == layer
        assert info["confidence"] == pytest.approx(full.max(), abs=1e-15)
        assert info["confidence"] <= pinfo["confidence"] + 1e-15  # a state is rarer than its position
        assert terminated == (info["confidence"] >= 0.5)
        assert info["success"] == (terminated and (layer, r, c) == env.state)
        assert "estimate_heading" not in pinfo
        if terminated:
            env.reset()
            plain.reset()


def test_fixed_episode_length_and_belief_reward():
    model = ring_sensor_model((4, 4))
    env = GridLocEnv(model, episode_length=7, reward="belief", localise_threshold=0.3)
    env.reset(seed=0)
    for t in range(1, 8):
        _, reward, terminated, truncated, info = env.step(t % 4)
        assert terminated is False  # never ended early, however localised
        assert truncated is (t == 7)
        assert type(reward) is float and reward == info["confidence"]
    with pytest.raises(ValueError, match=r"^episode_length must be at least 1, got 0"):
        GridLocEnv(model, episode_length=0)
    with pytest.raises(ValueError, match=r"^reward must be one of 'step', 'belief'; got 'x'"):
        GridLocEnv(model, reward="x")


# -- reset options, actions, the order of calls ------------------------------------------------------
def test_reset_option_state():
    env = gym.make("WindyMaze-v0").unwrapped
    _, info = env.reset(seed=0, options={"state": (5, 6)})
    assert info["position"] == (5, 6)
    env = gym.make("RingSensor8x8-v0", dynamics="passive").unwrapped
    _, info = env.reset(seed=0, options={"state": (2, 3, 4)})
    assert info["position"] == (3, 4) and info["heading"] == 2
    _, info = env.reset(seed=0, options={"state": (np.int64(3), 4)})  # (row, col): a random heading
    assert info["position"] == (3, 4) and 0 <= info["heading"] < 4


def test_unknown_reset_option():
    env = gym.make("WindyMaze-v0")
    with pytest.raises(ValueError, match=r"unknown reset option\(s\) \['start'\]"):
        env.reset(options={"start": (0, 0)})
    with pytest.raises(ValueError, match=r"reset option 'state' must name a free cell, got \(1, 2\)"):
        env.reset(options={"state": (1, 2)})  # an obstacle of the default maze
    for bad in ((True, 0), "ab", (0, 0, 0, 0), (1.0, 0)):
        with pytest.raises(ValueError, match=r"reset option 'state' must name a free cell"):
            env.reset(options={"state": bad})


def _makers(env_id):
    return {
        "unwrapped": lambda: gym.make(env_id).unwrapped,
        "made": lambda: gym.make(env_id),
        "wrapped": lambda: HMMBeliefWrapper(gym.make(env_id)),
        "wrapped-flat": lambda: HMMBeliefWrapper(gym.make(env_id).unwrapped, flatten=True),
    }


@pytest.mark.parametrize("kind", ["unwrapped", "made", "wrapped", "wrapped-flat"])
@pytest.mark.parametrize("action", [4, -1, 1.5, "a", None, np.array([1]), 2**40])
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_action_outside_the_action_space(env_id, action, kind):
    env = _makers(env_id)[kind]()
    env.reset(seed=0)
    belief_before = env.belief_array().copy() if isinstance(env, HMMBeliefWrapper) else None
    state_before = env.unwrapped.state
    model = env.unwrapped.model
    legend = {4: "0=N, 1=E, 2=S, 3=W", 3: "0=left, 1=right, 2=forward"}[model.n_actions]
    assert model.action_legend == legend
    with pytest.raises(ValueError, match=r"action .* is not in the action space " + re.escape(f"Discrete({model.n_actions}) ({legend})")):
        env.step(action)
    # Nothing changed: the robot did not move and the belief did not update.
    assert env.unwrapped.state == state_before
    if belief_before is not None:
        np.testing.assert_array_equal(env.belief_array(), belief_before)
    env.step(0)  # and the environment still works


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_numpy_integer_actions_are_accepted(env_id):
    env = gym.make(env_id)
    env.reset(seed=0)
    env.step(np.int64(2))
    env.step(np.array(env.action_space.n - 1))


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_step_before_reset(env_id):
    with pytest.raises(RuntimeError, match=r"call reset\(\) before step\(\)"):
        gym.make(env_id).unwrapped.step(0)
    with pytest.raises(gym.error.ResetNeeded):  # gym.make's OrderEnforcing says it first
        gym.make(env_id).step(0)
    with pytest.raises(RuntimeError, match=r"reset"):
        HMMBeliefWrapper(gym.make(env_id).unwrapped).step(0)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_render_before_reset(env_id):
    env = ENV_CLASSES[env_id](render_mode="ansi")
    with pytest.raises(RuntimeError, match=r"call reset\(\) before render\(\)"):
        env.render()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_unknown_render_mode(env_id):
    with pytest.raises(ValueError, match=r"^render_mode must be one of \['ansi', 'rgb_array', 'human'\] or None, got 'foo'"):
        ENV_CLASSES[env_id](render_mode="foo")


def test_render_without_mode_warns_and_returns_none():
    env = gym.make("WindyMaze-v0").unwrapped
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None


# -- edge cases --------------------------------------------------------------------------------------
# Edge cases named in the robustness issue, run explicitly (they are also in the property tests' reach).
EDGES = [
    ("WindyMaze-v0", {"layout": ["O"]}),  # 1x1
    ("ColourGrid-v0", {"layout": ["Y"]}),
    ("ColourGrid-v0", {"layout": [".,.,.", ".,G,.", ".,.,."]}),  # a single free cell
    ("WindyMaze-v0", {"layout": ["O#O", "###", "O#O"]}),  # four disconnected parts
    ("ColourGrid-v0", {"layout": ["R,.,R", ".,.,.", "R,.,G"], "slip": 0.0, "accuracy": 1.0}),
    ("ColourGrid-v0", {"accuracy": 1.0, "slip": 1.0, "localise_threshold": 1.0}),
    ("ColourGrid-v0", {"accuracy": 0.0, "slip": 0.0}),
    ("WindyMaze-v0", {"p_detect": 1.0, "p_false_alarm": 0.0, "drift": 0.0, "localise_threshold": 1.0}),
    ("WindyMaze-v0", {"p_detect": 0.0, "p_false_alarm": 1.0, "drift": 0.5}),
    ("RingSensor8x8-v0", {"p_true": 1.0, "p_ring1": 0.0, "p_ring2": 0.0}),
    ("RingSensor8x8-v0", {"p_true": 1.0, "p_ring1": 0.0, "p_ring2": 0.0, "dynamics": "passive", "localise_threshold": 1.0}),
    ("RingSensor8x8-v0", {"size": (1, 1)}),
    ("RingSensor8x8-v0", {"size": (1, 1), "dynamics": "passive"}),
    ("RingSensor8x8-v0", {"size": (1, 5), "keep_heading": 1.0}),
    ("RingSensor8x8-v0", {"size": (3, 3), "keep_heading": 0.0, "dynamics": "passive"}),
    ("RingSensor8x8-v0", {"p_true": 0.0, "p_ring1": 0.0, "p_ring2": 0.0}),  # the sensor says nothing
]


@pytest.mark.parametrize("env_id,kwargs", EDGES, ids=[f"{e}-{k}" for e, k in EDGES])
def test_edge_cases_run(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    exercise(lambda: env, set(), True)
    # Under the true model no observation is ever impossible, even with 0/1 probabilities.
    wrapped = HMMBeliefWrapper(gym.make(env_id, **kwargs))
    wrapped.reset(seed=1)
    for t in range(300):
        obs, _, terminated, truncated, _ = wrapped.step(t % wrapped.action_space.n)
        assert np.all(np.isfinite(obs["belief"]))
        if terminated or truncated:
            wrapped.reset()


# -- the simulator samples the model -------------------------------------------------------------------
@pytest.mark.parametrize("name", list(DEFAULT_MODELS))
def test_env_steps_sample_the_model(name):
    """Stepping the environment from a chosen state lands where ``model.outcomes`` says, and the
    first reading at a state follows ``model.sensor.distribution``."""
    env_id, kwargs = ENV_OF_MODEL[name]
    env = gym.make(env_id, **kwargs).unwrapped
    model = env.model
    n = 2000
    env.reset(seed=77)
    for state in pick_states(model, 3, seed=2):
        a = model.n_actions - 1
        probs: dict = {}
        for nxt, p in model.outcomes(state, a):
            key = nxt if model.n_layers > 1 else nxt[1:]
            probs[key] = probs.get(key, 0.0) + p
        readings, rprobs = model.sensor.distribution(state[1], state[2], state[0])
        assert rprobs.sum() == pytest.approx(1.0, abs=1e-12)
        rdist: dict = {}
        for rd, p in zip(readings.tolist(), rprobs.tolist()):
            if p > 0:
                rdist[rd] = rdist.get(rd, 0.0) + p
        moves: dict = {}
        reads: dict = {}
        start = state if model.n_layers > 1 else state[1:]
        for _ in range(n):
            obs, _ = env.reset(options={"state": start})
            rd = model.sensor.to_reading(obs)
            reads[rd] = reads.get(rd, 0) + 1
            _, _, _, _, info = env.step(a)
            key = (info["heading"], *info["position"]) if model.n_layers > 1 else info["position"]
            moves[key] = moves.get(key, 0) + 1
        assert_counts_match(moves, probs, n, f"{name} env step from {state}")
        assert_counts_match(reads, rdist, n, f"{name} env reading at {state}")


def test_env_teleports_at_the_model_rate():
    """One step from a fixed state, many seeds: the next-state frequencies match the dense row
    (1 - p) T[s] + p / S."""
    env = gym.make("WindyMaze-v0", kidnap_prob=0.3).unwrapped
    model = env.model
    start = (0, 2, 0)
    n = 4000
    counts = np.zeros(model.n_states)
    for seed in range(n):
        env.reset(seed=seed, options={"state": start[1:]})
        env.step(1)
        counts[model.state_index(env.state)] += 1
    expected = transition_matrix(model, 1).toarray()[model.state_index(start)]
    np.testing.assert_allclose(expected.sum(), 1.0)
    assert np.all(expected >= 0.3 / model.n_states - 1e-12)
    assert np.all(np.abs(counts - n * expected) <= 5 * np.sqrt(n * expected * (1 - expected)) + 1)


# -- keys for gymnasium.utils.play ------------------------------------------------------------------
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_keys_to_action_arrows_and_wasd_name_the_moves(env_id):
    pygame = pytest.importorskip("pygame")
    env = gym.make(env_id, render_mode="rgb_array")
    keys = env.get_wrapper_attr("get_keys_to_action")()
    names = env.unwrapped.model.action_names
    by_key = {k: names[a] for (k,), a in keys.items()}
    assert set(keys.values()) == set(range(env.action_space.n))
    if names == ("left", "right", "forward"):
        want = {pygame.K_LEFT: "left", pygame.K_RIGHT: "right", pygame.K_UP: "forward",
                "a": "left", "d": "right", "w": "forward"}
    else:
        want = {pygame.K_UP: "N", pygame.K_RIGHT: "E", pygame.K_DOWN: "S", pygame.K_LEFT: "W",
                "w": "N", "d": "E", "s": "S", "a": "W"}
    assert by_key == want


def test_keys_to_action_digits_for_unnamed_actions():
    from gym_gridloc.core.model import GridModel

    m = ring_sensor_model()
    model = GridModel(m.grid, m.transitions, m.sensor, name="renamed", action_names=("up", "across", "down", "back"))
    assert GridLocEnv(model).get_keys_to_action() == {("0",): 0, ("1",): 1, ("2",): 2, ("3",): 3}


@pytest.mark.filterwarnings("ignore:.*matplotlib is not installed")  # gymnasium.utils.play asks for TkAgg
@pytest.mark.parametrize("env_id", ["WindyMaze-v0", "DepthMaze-v0"])
def test_gymnasium_play_runs_out_of_the_box(env_id, monkeypatch):
    """``gymnasium.utils.play.play(gym.make(ID, render_mode="rgb_array"))`` finds the key map and
    steps the actions of the keys pressed (events scripted; SDL's dummy video driver)."""
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    monkeypatch.setenv("SDL_AUDIODRIVER", "dummy")
    pygame = pytest.importorskip("pygame")
    from gymnasium.utils import play

    down = lambda k: pygame.event.Event(pygame.KEYDOWN, key=k, mod=0, unicode="", scancode=0)  # noqa: E731
    up = lambda k: pygame.event.Event(pygame.KEYUP, key=k, mod=0, unicode="", scancode=0)  # noqa: E731
    script = iter([[down(pygame.K_UP)], [up(pygame.K_UP), down(pygame.K_d)], [up(pygame.K_d)],
                   [pygame.event.Event(pygame.QUIT)]])
    monkeypatch.setattr(pygame.event, "get", lambda *a, **k: next(script, [pygame.event.Event(pygame.QUIT)]))
    taken = []
    env = gym.make(env_id, render_mode="rgb_array")
    play.play(env, wait_on_player=True, fps=1000, seed=0,
              callback=lambda o0, o1, action, *rest: taken.append(int(action)))
    forward, right = (2, 1) if env_id == "DepthMaze-v0" else (0, 1)
    assert taken == [forward, right]
