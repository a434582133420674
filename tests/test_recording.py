"""Recording episodes (gym_gridloc/recording.py): RecordTrajectory feeds offline inference, and the
recovery from kidnapping is measured on recorded true states (kidnap_steps, steps_to_recover)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from gym_gridloc import ForwardFilter, RecordTrajectory, smooth, windy_maze_model
from gym_gridloc.recording import kidnap_steps, steps_to_recover


def test_record_trajectory():
    env = RecordTrajectory(gym.make("RingSensor8x8-v0", size=(4, 4), dynamics="passive"), max_episodes=2)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(0)
    for seed in range(3):
        env.reset(seed=seed)
        for _ in range(4 + seed):
            env.step(0)
    tr = env.trajectory
    assert len(tr) == 6 and len(tr.observations) == 7 and len(tr.infos) == 7 and len(tr.rewards) == 6
    assert [len(e) for e in env.episodes] == [4, 5]  # the last two finished episodes
    assert tr.states[-1] == env.unwrapped.state  # heading included
    assert tr.positions[-1] == env.unwrapped.state[1:]
    # the recorded episode is exactly what the environment's referee filtered
    post = smooth(env.unwrapped.model, tr.actions, tr.observations)
    np.testing.assert_allclose(post[-1], env.unwrapped.posterior, atol=1e-12)
    with pytest.raises(ValueError, match="max_episodes"):
        RecordTrajectory(gym.make("WindyMaze-v0"), max_episodes=-1)


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
        for p, found in results.items():
            f = ForwardFilter(model, kidnap_prob=p).reset(tr.observations[0])
            beliefs = [f.position_belief] + [f.step(a, o).position_belief for a, o in zip(tr.actions, tr.observations[1:])]
            est = [divmod(int(np.argmax(b)), model.shape[1]) for b in beliefs]
            conf = [float(b.max()) for b in beliefs]
            found.extend(x for x in steps_to_recover(est, conf, tr.positions, kidnaps, cap=50) if x is not None)
    mixed, plain = np.array(results[0.02]), np.array(results[0.0])
    assert len(mixed) >= 15 and len(plain) >= 10
    assert np.median(mixed) < np.median(plain)
    assert mixed.mean() < plain.mean()
