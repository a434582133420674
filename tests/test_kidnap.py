"""The kidnapped robot: the environment option, the filter option, and recovery."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc
from gym_gridloc import ForwardFilter, ImpossibleObservationError, RecordTrajectory, colour_grid_model, windy_maze_model
from gym_gridloc.recording import kidnap_steps, steps_to_recover


@pytest.mark.parametrize("env_id", gym_gridloc.ENV_IDS)
def test_env_option_sets_the_simulated_and_referee_model(env_id):
    env = gym.make(env_id, kidnap_prob=0.05)
    assert env.unwrapped.model.kidnap_prob == 0.05
    assert env.unwrapped._referee.model is env.unwrapped.model
    assert gym.make(env_id).unwrapped.model.kidnap_prob == 0.0  # off by default
    with pytest.raises(ValueError, match="kidnap_prob"):
        gym.make(env_id, kidnap_prob=1.5)
    with pytest.raises(TypeError, match="kidnap_prob"):
        gym.make(env_id, kidnap_prob="often")


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
    expected = model.transition_matrix(1).toarray()[model.state_index(start)]
    np.testing.assert_allclose(expected.sum(), 1.0)
    assert np.all(expected >= 0.3 / model.n_states - 1e-12)
    assert np.all(np.abs(counts - n * expected) <= 5 * np.sqrt(n * expected * (1 - expected)) + 1)


@pytest.mark.parametrize("p", [0.0, 0.02, 0.5])
def test_filter_option_equals_dense_mixing(p):
    base = windy_maze_model()
    rng = np.random.default_rng(1)
    f = ForwardFilter(base, kidnap_prob=p).reset([0, 1, 0, 1])
    assert f.model.kidnap_prob == p and base.kidnap_prob == 0.0  # the given model is not changed
    T = base.transition_matrix(0).toarray()
    S = base.n_states
    ref = base.to_vector(f.full_belief)
    for _ in range(6):
        a = int(rng.integers(4))
        obs = rng.integers(0, 2, size=4).astype(np.int8)
        f.step(a, obs)
        T = base.transition_matrix(a).toarray()
        ref = ((1 - p) * T.T @ ref + p / S) * base.likelihood_vector(base.sensor.to_reading(obs))
        ref /= ref.sum()
        np.testing.assert_allclose(f.belief, ref, atol=1e-12)
    # and the option overrides a model's own kidnapping in both directions
    assert ForwardFilter(base.with_kidnapping(0.1), kidnap_prob=0.0).model.kidnap_prob == 0.0
    assert ForwardFilter(base.with_kidnapping(0.1)).model.kidnap_prob == 0.1


def test_mixing_makes_a_kidnap_possible():
    """Perfect sensor, no slip: without mixing a kidnap gives an impossible observation; with the
    mixing the belief jumps to the only explanation."""
    model = colour_grid_model(["R,G", "B,Y"], slip=0.0, accuracy=1.0)
    plain = ForwardFilter(model).reset(0)  # on R at (0, 0)
    with pytest.raises(ImpossibleObservationError):
        plain.step(1, 2)  # moving E reads B: only a kidnap explains it
    mixed = ForwardFilter(model, kidnap_prob=0.01).reset(0)
    mixed.step(1, 2)
    assert mixed.position_belief[1, 0] == pytest.approx(1.0)
    # in an environment with kidnapping, a wrapper whose model has no mixing needs
    # on_impossible="reset"; with the environment's own model (mixing on) it never restarts
    env = gym_gridloc.ColourGridEnv(["R,G", "B,Y"], slip=0.0, accuracy=1.0, kidnap_prob=0.3)
    plain_env = gym_gridloc.HMMBeliefWrapper(env, model=env.model.with_kidnapping(0.0), on_impossible="reset")
    mixed_env = gym_gridloc.HMMBeliefWrapper(gym_gridloc.ColourGridEnv(["R,G", "B,Y"], slip=0.0, accuracy=1.0, kidnap_prob=0.3))
    for wrapped in (plain_env, mixed_env):
        wrapped.reset(seed=0)
        resets = 0
        for k in range(100):
            obs, _, _, _, info = wrapped.step(k % 4)
            resets += bool(info.get("belief_reset", False))
            assert np.isfinite(obs["belief"]).all() and obs["belief"].sum() == pytest.approx(1.0, abs=1e-6)
            if wrapped is mixed_env:  # the mixing filter is exact: it agrees with the referee
                np.testing.assert_allclose(obs["belief"], wrapped.unwrapped.posterior, atol=1e-6)
        if wrapped is plain_env:
            assert resets > 5
    with pytest.raises(ImpossibleObservationError):
        strict = gym_gridloc.HMMBeliefWrapper(gym_gridloc.ColourGridEnv(["R,G", "B,Y"], slip=0.0, accuracy=1.0, kidnap_prob=0.3),
                                              model=env.model.with_kidnapping(0.0))
        strict.reset(seed=0)
        for k in range(100):
            strict.step(k % 4)


def test_kidnap_steps_and_steps_to_recover():
    model = windy_maze_model()
    states = [(0, 5, 0), (0, 4, 0), (0, 0, 6), (0, 0, 6), (0, 1, 6)]
    actions = [0, 0, 0, 2]
    assert kidnap_steps(model, states, actions) == [2]  # (4,0) -> (0,6) is no move
    positions = [s[1:] for s in states] + [(2, 6)] * 3
    estimates = [(5, 0), (4, 0), (4, 0), (3, 0), (1, 6), (2, 6), (2, 6), (2, 6)]
    confs = [0.9, 0.9, 0.9, 0.6, 0.4, 0.7, 0.7, 0.7]
    # kidnap at 2: right at 4 but confidence 0.4 < 0.5, right and confident at 5
    assert steps_to_recover(estimates, confs, positions, [2], cap=10) == [3]
    assert steps_to_recover(estimates, confs, positions, [2], cap=2) == [3]  # cap + 1: not recovered
    # cut short by the next kidnap; the one at 4 did not find the filter localised at 3
    assert steps_to_recover(estimates, confs, positions, [2, 4], cap=10) == [None, None]
    assert steps_to_recover(estimates, confs, positions, [2, 4], cap=10, localised_before=False) == [None, 1]
    assert steps_to_recover(estimates[:4], confs[:4], positions[:4], [2], cap=10) == [None]  # by the end
    confs[1] = 0.3  # not localised before the kidnap at 2
    assert steps_to_recover(estimates, confs, positions, [2], cap=10) == [None]
    assert steps_to_recover(estimates, confs, positions, [2], cap=10, localised_before=False) == [3]
    with pytest.raises(ValueError, match="one element fewer"):
        kidnap_steps(model, states, actions[:2])


def test_mixing_recovers_faster_on_recorded_kidnaps():
    """Kidnapping on, random actions: over the kidnaps of a few long episodes, the exact filter
    with the mixing option recovers sooner (median and mean) than without it."""
    env = RecordTrajectory(gym.make("WindyMaze-v0", kidnap_prob=0.02).unwrapped)
    model = env.unwrapped.model
    results = {0.02: [], 0.0: []}
    rng = np.random.default_rng(0)
    for seed in range(4):
        env.reset(seed=seed)
        for _ in range(500):
            env.step(int(rng.integers(4)))
        tr = env.trajectory
        kidnaps = kidnap_steps(model, tr.states, tr.actions)
        assert 4 <= len(kidnaps) <= 20  # about 500 * 0.02 * (the chance a teleport is not a move)
        for p in results:
            f = ForwardFilter(model, kidnap_prob=p).reset(tr.observations[0])
            beliefs = [f.position_belief] + [f.step(a, o).position_belief for a, o in zip(tr.actions, tr.observations[1:])]
            est = [divmod(int(np.argmax(b)), model.shape[1]) for b in beliefs]
            conf = [float(b.max()) for b in beliefs]
            results[p].extend(x for x in steps_to_recover(est, conf, tr.positions, kidnaps, cap=50) if x is not None)
    mixed, plain = np.array(results[0.02]), np.array(results[0.0])
    assert len(mixed) >= 15 and len(plain) >= 10
    assert np.median(mixed) < np.median(plain)
    assert mixed.mean() < plain.mean()
