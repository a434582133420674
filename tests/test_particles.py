"""The particle filter (gym_gridloc/particles.py): moves by the engine's sampler, resampling, convergence
to the exact belief, depletion, kidnapping, the wrapper option."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import gym_gridloc
from gym_gridloc import (
    ForwardFilter,
    HMMBeliefWrapper,
    ImpossibleObservationError,
    ParticleFilter,
    colour_grid_model,
    engine,
    ring_sensor_model,
    windy_maze_model,
)
from gym_gridloc.particles import systematic_resample
from tests.helpers import simulate

MODELS = {
    "colour": colour_grid_model,
    "maze": windy_maze_model,
    "ring-commanded": lambda: ring_sensor_model((5, 5)),
    "ring-seed": lambda: ring_sensor_model((4, 4), dynamics="passive"),
    "maze-kidnap": lambda: windy_maze_model().with_kidnapping(0.05),
}


@pytest.mark.parametrize("name", sorted(MODELS))
def test_predict_moves_the_particles_by_the_engine_sampler(name):
    """The particles move by :func:`gym_gridloc.engine.sample_next` (whose draws are checked
    against the transition in tests/test_engine.py): the same generator, the same next states."""
    model = MODELS[name]()
    for action in (0, model.n_actions - 1, None):
        pf = ParticleFilter(model, 500, rng=1).reset()
        before = pf.particles
        pf.seed(7).predict(action)
        expected = engine.sample_next(model, before, action, np.random.default_rng(7))
        np.testing.assert_array_equal(pf.particles, expected)
        assert not np.array_equal(pf.particles, before)


def test_systematic_resampling_copies_floor_or_ceil():
    rng = np.random.default_rng(0)
    for _ in range(20):
        w = rng.random(50) ** 3
        w /= w.sum()
        counts = np.bincount(systematic_resample(w, rng), minlength=50)
        assert counts.sum() == 50
        assert np.all(counts >= np.floor(50 * w) - 1e-9) and np.all(counts <= np.ceil(50 * w) + 1e-9)


def test_resampling_only_below_the_threshold():
    model = windy_maze_model()
    acts, obs, _ = simulate(model, 20, 1)
    never = ParticleFilter(model, 300, resample_threshold=0.0, rng=0).reset(obs[0])
    always = ParticleFilter(model, 300, resample_threshold=1.0, rng=0).reset(obs[0])
    half = ParticleFilter(model, 300, resample_threshold=0.5, rng=0).reset(obs[0])
    for a, o in zip(acts, obs[1:]):
        before = half.effective_sample_size  # after the last update (and resample, if any)
        for pf in (never, always, half):
            pf.step(a, o)
        assert before >= 150 or half.n_resamples > 0
    assert never.n_resamples == 0
    assert always.n_resamples == 21  # every update has unequal weights (the reading is informative)
    assert 0 < half.n_resamples < 21
    assert half.effective_sample_size >= 150  # the rule: below N/2 means resampling right away
    for pf in (never, always, half):
        np.testing.assert_allclose(pf.position_belief.sum(), 1.0)
        assert np.all(pf.position_belief[~model.grid.free] == 0)


@pytest.mark.parametrize("name", ["colour", "maze", "ring-commanded", "ring-seed"])
def test_particle_belief_converges_to_the_exact_belief(name):
    """Mean total-variation distance to the exact belief over an episode, averaged over seeds,
    shrinks as N grows (about as 1/sqrt(N)) and is small for N = 20,000."""
    model = MODELS[name]()
    acts, obs, _ = simulate(model, 15, 2)
    exact = ForwardFilter(model).reset(obs[0])
    beliefs = [exact.position_belief]
    for a, o in zip(acts, obs[1:]):
        beliefs.append(exact.step(a, o).position_belief)
    tv = {}
    for n in (200, 2_000, 20_000):
        dists = []
        for seed in range(3):
            pf = ParticleFilter(model, n, rng=seed).reset(obs[0])
            d = [0.5 * np.abs(pf.position_belief - beliefs[0]).sum()]
            for a, o, b in zip(acts, obs[1:], beliefs[1:]):
                d.append(0.5 * np.abs(pf.step(a, o).position_belief - b).sum())
            dists.append(np.mean(d))
        tv[n] = float(np.mean(dists))
    assert tv[200] > tv[2_000] > tv[20_000], tv
    assert tv[20_000] < 0.03, tv
    assert tv[20_000] < tv[200] / 4, tv  # 1/sqrt(N) predicts a factor 10


def test_log_likelihood_estimate_is_close():
    """The particle estimate of P(e_0:t) is unbiased; its log has a spread (one unlikely reading
    explained by a rare state dominates it), so compare the mean over seeds."""
    model = windy_maze_model()
    acts, obs, _ = simulate(model, 20, 4)
    exact = ForwardFilter(model).reset(obs[0])
    for a, o in zip(acts, obs[1:]):
        exact.step(a, o)
    diffs = []
    for seed in range(4):
        pf = ParticleFilter(model, 20_000, rng=seed).reset(obs[0])
        for a, o in zip(acts, obs[1:]):
            pf.step(a, o)
        diffs.append(pf.log_likelihood - exact.log_likelihood)
    assert abs(np.mean(diffs)) < 0.1 and max(map(abs, diffs)) < 0.5, diffs


def test_depletion_reinitialises_or_raises():
    model = colour_grid_model(["R,G", "B,Y"], slip=0.0, accuracy=1.0)
    pf = ParticleFilter(model, 50, rng=0).reset(0)  # all particles on the R cell
    assert pf.position_belief[0, 0] == pytest.approx(1.0)
    pf.step(1, 2)  # moving E cannot read B: no particle explains it
    assert pf.n_reinitialisations == 1 and pf.position_belief[1, 0] == pytest.approx(1.0)
    strict = ParticleFilter(model, 50, rng=0, on_depletion="raise").reset(0)
    before = strict.particles
    with pytest.raises(ImpossibleObservationError, match="particle deprivation"):
        strict.step(1, 2)
    np.testing.assert_array_equal(strict.particles, before)  # left as it was
    maze = windy_maze_model(["OO"], p_detect=1.0, p_false_alarm=0.0)
    with pytest.raises(ImpossibleObservationError, match="every state"):
        ParticleFilter(maze, 10, rng=0).reset([0, 0, 0, 0])  # W wall of (0,0) always sensed


def test_kidnapping_option_spreads_particles():
    model = colour_grid_model(["R,G", "B,Y"], slip=0.0, accuracy=1.0)
    pf = ParticleFilter(model, 2000, rng=0, kidnap_prob=0.2).reset(0)
    pf.predict(1)
    b = pf.position_belief
    # 0.8 + 0.2/4 on (0, 1), 0.05 on each other cell
    np.testing.assert_allclose(b, [[0.05, 0.85], [0.05, 0.05]], atol=0.03)


def test_bad_parameters_are_named():
    model = windy_maze_model()
    with pytest.raises(ValueError, match="n_particles"):
        ParticleFilter(model, 0)
    with pytest.raises(ValueError, match="resample_threshold"):
        ParticleFilter(model, 10, resample_threshold=1.5)
    with pytest.raises(ValueError, match="resampling"):
        ParticleFilter(model, 10, resampling="stratified-ish")
    with pytest.raises(RuntimeError, match="reset"):
        ParticleFilter(model, 10).predict(0)
    with pytest.raises(ValueError, match="action"):
        ParticleFilter(model, 10).reset().predict(9)
    with pytest.raises(ValueError, match="belief must be one of"):
        HMMBeliefWrapper(gym.make("WindyMaze-v0"), belief="histogram")


@pytest.mark.filterwarnings("ignore:.*is different from the unwrapped version")
@pytest.mark.parametrize("env_id", gym_gridloc.ENV_IDS)
def test_wrapper_particle_option(env_id):
    env = HMMBeliefWrapper(gym.make(env_id), belief="particles", n_particles=300)
    check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=5)
    model = env.unwrapped.model
    assert obs["belief"].shape == model.shape and obs["belief"].dtype == np.float32
    assert obs["belief"].sum() == pytest.approx(1.0, abs=1e-5)
    assert isinstance(env.filter, ParticleFilter) and env.filter.n_particles == 300
    first = [obs["belief"]]
    for _ in range(5):
        first.append(env.step(1)[0]["belief"])
    obs, _ = env.reset(seed=5)  # the same seed gives the same particle beliefs
    again = [obs["belief"]] + [env.step(1)[0]["belief"] for _ in range(5)]
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    flat = HMMBeliefWrapper(gym.make(env_id), belief="particles", n_particles=50, flatten=True, full_state=True)
    o, _ = flat.reset(seed=0)
    assert flat.observation_space.contains(o)
    assert isinstance(HMMBeliefWrapper(gym.make(env_id)).filter, ForwardFilter)  # the default stays exact
