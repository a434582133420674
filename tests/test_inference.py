"""Smoothing, fixed-lag smoothing and Viterbi (gym_gridloc/inference.py): against brute-force
enumeration, hmmlearn, the forward filter, and on long episodes.  (The backward pass is the
engine's: tests/test_engine.py.)"""

from __future__ import annotations

import itertools

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc
from gym_gridloc import (
    FixedLagSmoother,
    ForwardFilter,
    ImpossibleObservationError,
    RecordTrajectory,
    colour_grid_model,
    fixed_lag_smooth,
    forward_backward,
    ring_sensor_model,
    smooth,
    viterbi,
    windy_maze_model,
)
from gym_gridloc.engine import transition_matrix
from tests.helpers import simulate


def brute_force(model, actions, observations):
    """Joint probabilities of every state sequence, by enumeration with dense matrices."""
    S = model.n_states
    n = len(observations)
    seqs = np.array(list(itertools.product(range(S), repeat=n)))
    readings = [model.sensor.to_reading(o) for o in observations]
    lik = np.stack([model.likelihood_vector(z) for z in readings])  # (n, S)
    joint = np.full(len(seqs), 1.0 / S) * lik[0, seqs[:, 0]]
    for k in range(1, n):
        T = transition_matrix(model, actions[k - 1]).toarray()
        joint *= T[seqs[:, k - 1], seqs[:, k]] * lik[k, seqs[:, k]]
    return seqs, joint


TINY = {
    "colour2x2": lambda: colour_grid_model(["R,G", "B,R"], slip=0.3, accuracy=0.7),
    "colour2x2-kidnap": lambda: colour_grid_model(["R,G", "B,R"], slip=0.3, accuracy=0.7).with_kidnapping(0.1),
    "maze3x3": lambda: windy_maze_model(["OOO", "O#O", "OO#"], drift=0.15, p_detect=0.8, p_false_alarm=0.2),
    "ring2x2-seed": lambda: ring_sensor_model((2, 2), dynamics="passive"),
    "ring3x1-commanded": lambda: ring_sensor_model((3, 1)),
}


@pytest.mark.parametrize("name", sorted(TINY))
@pytest.mark.parametrize("seed", [0, 1])
def test_smoothing_and_viterbi_equal_brute_force(name, seed):
    model = TINY[name]()
    n_steps = 3 if model.n_states > 8 else 4
    actions, obs, _ = simulate(model, n_steps, seed)
    seqs, joint = brute_force(model, actions, obs)
    total = joint.sum()

    result = forward_backward(model, actions, obs)
    assert result.log_likelihood == pytest.approx(np.log(total), abs=1e-12)
    for k in range(len(obs)):
        marginal = np.bincount(seqs[:, k], weights=joint, minlength=model.n_states) / total
        np.testing.assert_allclose(model.to_vector(result.smoothed[k]), marginal, atol=1e-12)
        # filtering: the same enumeration truncated at k
        s_k, j_k = brute_force(model, actions[:k], obs[: k + 1])
        filt = np.bincount(s_k[:, k], weights=j_k, minlength=model.n_states) / j_k.sum()
        np.testing.assert_allclose(model.to_vector(result.filtered[k]), filt, atol=1e-12)
    np.testing.assert_allclose(smooth(model, actions, obs), result.smoothed.sum(axis=1), atol=1e-15)

    path, log_prob = viterbi(model, actions, obs, full_state=True)
    best = int(np.argmax(joint))
    assert log_prob == pytest.approx(np.log(joint[best]), abs=1e-10)
    ours = [model.state_index(s) for s in path]
    ours_joint = joint[np.flatnonzero((seqs == ours).all(axis=1))[0]]
    assert np.log(ours_joint) == pytest.approx(np.log(joint[best]), abs=1e-10)  # optimal (ties allowed)
    positions, log_prob2 = viterbi(model, actions, obs)
    assert log_prob2 == log_prob and positions == [(r, c) for _, r, c in path]


def test_unknown_actions_average_the_transitions():
    model = TINY["colour2x2"]()
    actions, obs, _ = simulate(model, 3, 5)
    seqs, joint = brute_force(model, [None] * 3, obs)
    post = smooth(model, None, obs, full_state=True)
    for k in range(4):
        marginal = np.bincount(seqs[:, k], weights=joint, minlength=model.n_states) / joint.sum()
        np.testing.assert_allclose(model.to_vector(post[k]), marginal, atol=1e-12)
    _, log_prob = viterbi(model, [None, None, None], obs)
    assert log_prob == pytest.approx(np.log(joint.max()), abs=1e-10)


def joint_log_prob(model, actions, observations, states):
    """log P(x_0:t, e_0:t) of one state sequence, from the dense matrices."""
    readings = [model.sensor.to_reading(o) for o in observations]
    lp = -np.log(model.n_states) + np.log(model.likelihood_vector(readings[0])[states[0]])
    for k in range(1, len(states)):
        T = transition_matrix(model, None if actions is None else actions[k - 1]).toarray()
        lp += np.log(T[states[k - 1], states[k]]) + np.log(model.likelihood_vector(readings[k])[states[k]])
    return lp


# Episodes whose most likely path is unique.  The seed dynamics are symmetric (a robot facing a
# corner turns to either open heading with 1/2), so some episodes have several optimal paths with
# exactly equal probability; there hmmlearn and we may pick different ones (both are checked to be
# optimal below), and these cases check the path itself.
UNIQUE = [((4, 4), 0), ((4, 4), 1), ((4, 4), 4), ((5, 5), 1), ((5, 5), 2), ((3, 4), 1)]
TIED = [((3, 3), 0), ((4, 4), 2), ((5, 5), 0)]


@pytest.mark.parametrize("size,seed", UNIQUE + TIED)
def test_plain_hmm_equals_hmmlearn(size, seed):
    hmm = pytest.importorskip("hmmlearn.hmm")
    model = ring_sensor_model(size, dynamics="passive")  # the action plays no part: a plain HMM
    actions, obs, _ = simulate(model, 40, seed, actions=[0] * 40)
    S = model.n_states
    ref = hmm.CategoricalHMM(n_components=S, init_params="", params="")
    ref.n_features = model.sensor.n_readings
    ref.startprob_ = np.full(S, 1.0 / S)
    ref.transmat_ = transition_matrix(model, None).toarray()
    ref.emissionprob_ = np.stack([model.likelihood_vector(z) for z in range(model.sensor.n_readings)], axis=1)
    X = np.array([model.sensor.to_reading(o) for o in obs]).reshape(-1, 1)

    post = smooth(model, actions, obs, full_state=True)
    ours = np.stack([model.to_vector(p) for p in post])
    np.testing.assert_allclose(ours, ref.predict_proba(X), atol=1e-10)
    assert forward_backward(model, actions, obs).log_likelihood == pytest.approx(ref.score(X), abs=1e-8)

    ref_logprob, ref_states = ref.decode(X, algorithm="viterbi")
    path, log_prob = viterbi(model, None, obs, full_state=True)
    assert log_prob == pytest.approx(ref_logprob, abs=1e-8)
    states = [model.state_index(s) for s in path]
    assert joint_log_prob(model, None, obs, states) == pytest.approx(log_prob, abs=1e-8)
    assert joint_log_prob(model, None, obs, [int(s) for s in ref_states]) == pytest.approx(log_prob, abs=1e-8)
    if (size, seed) in UNIQUE:
        assert states == [int(s) for s in ref_states]


ENV_IDS = gym_gridloc.ENV_IDS


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_last_smoothed_equals_filtered_and_the_referee(env_id):
    env = RecordTrajectory(gym.make(env_id))
    env.reset(seed=3)
    for _ in range(25):
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            break
    tr = env.trajectory
    model = env.unwrapped.model
    post = smooth(model, tr.actions, tr.observations)
    assert post.shape == (len(tr.observations), *model.shape)
    np.testing.assert_allclose(post.sum(axis=(1, 2)), 1.0, atol=1e-12)
    f = ForwardFilter(model).reset(tr.observations[0])
    for a, o in zip(tr.actions, tr.observations[1:]):
        f.step(a, o)
    np.testing.assert_allclose(post[-1], f.position_belief, atol=1e-12)
    np.testing.assert_allclose(post[-1], env.unwrapped.posterior, atol=1e-12)
    env.close()


@pytest.mark.parametrize("model_fn", [windy_maze_model, lambda: ring_sensor_model((5, 5), dynamics="passive")])
def test_fixed_lag(model_fn):
    model = model_fn()
    actions, obs, _ = simulate(model, 12, 7)
    fb = forward_backward(model, actions, obs)
    # lag 0 is filtering
    np.testing.assert_allclose(fixed_lag_smooth(model, actions, obs, 0), fb.filtered_positions, atol=1e-12)
    # a lag as long as the episode is full smoothing
    np.testing.assert_allclose(fixed_lag_smooth(model, actions, obs, 12), fb.smoothed_positions, atol=1e-12)
    np.testing.assert_allclose(fixed_lag_smooth(model, actions, obs, 50), fb.smoothed_positions, atol=1e-12)
    # lag d: row k is smoothing of the episode cut after observation k + d
    for d in (1, 3, 5):
        fl = fixed_lag_smooth(model, actions, obs, d, full_state=True)
        for k in range(len(obs)):
            end = min(k + d, len(obs) - 1)
            ref = smooth(model, actions[:end], obs[: end + 1], full_state=True)[k]
            np.testing.assert_allclose(fl[k], ref, atol=1e-12)
    # the online interface: None until d observations have followed
    s = FixedLagSmoother(model, 3)
    assert s.reset(obs[0]) is None
    out = [s.step(a, o) for a, o in zip(actions, obs[1:])]
    assert out[:2] == [None, None]
    np.testing.assert_allclose(out[2], fb_k(model, actions, obs, 0, 3), atol=1e-12)
    np.testing.assert_allclose(s.filtered, fb.filtered_positions[-1], atol=1e-12)
    assert len(s.flush()) == 3


def fb_k(model, actions, obs, k, d):
    return smooth(model, actions[: k + d], obs[: k + d + 1])[k]


@pytest.mark.parametrize("model_fn", [colour_grid_model, lambda: ring_sensor_model((4, 4), dynamics="passive").with_kidnapping(0.01)])
def test_ten_thousand_steps_are_stable(model_fn):
    model = model_fn()
    actions, obs, states = simulate(model, 10_000, 11)
    fb = forward_backward(model, actions, obs)
    post = fb.smoothed_positions
    assert np.all(np.isfinite(post)) and np.all(post >= 0)
    np.testing.assert_allclose(post.sum(axis=(1, 2)), 1.0, atol=1e-9)
    np.testing.assert_allclose(post[-1], fb.filtered_positions[-1], atol=1e-15)
    assert np.isfinite(fb.log_likelihood) and fb.log_likelihood < -1000
    path, log_prob = viterbi(model, actions, obs)
    assert len(path) == 10_001 and np.isfinite(log_prob)
    assert log_prob < fb.log_likelihood  # one path's joint is below the evidence's total
    truth = [(r, c) for _, r, c in states]
    est = [np.unravel_index(int(np.argmax(p)), model.shape) for p in post]
    smooth_acc = np.mean([tuple(map(int, e)) == t for e, t in zip(est, truth)])
    filt = fb.filtered_positions
    filt_acc = np.mean([tuple(map(int, np.unravel_index(int(np.argmax(p)), model.shape))) == t for p, t in zip(filt, truth)])
    assert smooth_acc > filt_acc  # hindsight helps over 10,000 steps
    assert np.mean([p == t for p, t in zip(path, truth)]) > 0.5 * smooth_acc


def test_bad_input_is_named():
    model = windy_maze_model()
    obs = [[0, 0, 0, 1], [0, 1, 0, 0]]
    with pytest.raises(ValueError, match="actions must have exactly one element fewer"):
        smooth(model, [0, 1], obs)
    with pytest.raises(ValueError, match="at least one observation"):
        viterbi(model, [], [])
    with pytest.raises(ValueError, match="action must be an integer"):
        smooth(model, [7], obs)
    with pytest.raises(ValueError, match="not in the sensor's space"):
        smooth(model, [0], [[0, 0, 0, 1], [0, 2, 0, 0]])
    with pytest.raises(TypeError, match="GridModel"):
        smooth("maze", [0], obs)
    with pytest.raises(ValueError, match="lag must be at least 0"):
        FixedLagSmoother(model, -1)
    with pytest.raises(RuntimeError, match="reset"):
        FixedLagSmoother(model, 1).step(0, obs[0])


def test_impossible_observation_raises():
    model = colour_grid_model(["R,G", "B,Y"], slip=0.0, accuracy=1.0)  # a perfect sensor, no slip
    # from R at (0,0), moving E must read G; reading B is impossible
    with pytest.raises(ImpossibleObservationError, match="observation 1"):
        smooth(model, [1], [0, 2])
    with pytest.raises(ImpossibleObservationError, match="observation 1"):
        viterbi(model, [1], [0, 2])
    path, log_prob = viterbi(model, [1], [0, 1])
    assert path == [(0, 0), (0, 1)] and log_prob == pytest.approx(np.log(0.25))
    # with kidnapping the same episode is possible
    post = smooth(model.with_kidnapping(0.1), [1], [0, 2])
    assert post[1][1, 0] == pytest.approx(1.0)
