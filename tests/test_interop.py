"""gym_gridloc/interop.py: pomdp_py's models of a GridModel give the model's probabilities exactly,
sample them (chi-square at fixed seeds), convert states, actions and observations both ways, and
the planning model ends where the referee would."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from scipy import stats

from gym_gridloc import (
    ForwardFilter,
    colour_grid_model,
    depth_maze_model,
    engine,
    interop,
    pomdp_models,
    ring_sensor_model,
    windy_maze_model,
)
from gym_gridloc.generators import perfect_maze
from tests.helpers import likelihood_at, pick_states, run_python

pomdp_py = pytest.importorskip("pomdp_py", reason="pomdp_py is not installed (pip install 'gym_gridloc[planning]')")

MODELS = {
    "colour default": colour_grid_model,
    "windy default": windy_maze_model,
    "ring 5x5 commanded": lambda: ring_sensor_model((5, 5)),
    "ring 5x5 passive": lambda: ring_sensor_model((5, 5), dynamics="passive"),
    "depth 7x7": lambda: depth_maze_model(perfect_maze(7, seed=0), max_depth=5, p_turn_fail=0.1, p_move_fail=0.1,
                                          p_depth_error=0.2),
    "windy kidnapped": lambda: windy_maze_model(["OOO#", "O#OO", "OOO#"]).with_kidnapping(0.05),
}
ALL = pytest.mark.parametrize("name", list(MODELS))
N_DRAWS = 3000
P_MIN = 1e-4  # a right sampler fails a test with this probability


def chi_square_p(counts: dict, probs: dict, n: int) -> float:
    """The chi-square test's p-value of ``counts`` (n draws) against ``probs``, outcomes expected
    fewer than 5 times pooled into one bin; an outcome of probability 0 that occurs gives 0."""
    if any(probs.get(k, 0.0) <= 0.0 for k in counts):
        return 0.0
    keys = sorted(probs, key=lambda k: probs[k])
    obs, exp, pool_o, pool_e = [], [], 0, 0.0
    for k in keys:
        e = n * probs[k]
        if e < 5:
            pool_o, pool_e = pool_o + counts.get(k, 0), pool_e + e
        else:
            obs.append(counts.get(k, 0))
            exp.append(e)
    if pool_e > 0:
        obs.append(pool_o)
        exp.append(pool_e)
    if len(obs) < 2:
        return 1.0 if sum(obs) == n else 0.0
    exp = np.array(exp) * (n / np.sum(exp))
    return float(stats.chisquare(obs, exp).pvalue)


def counts_of(values) -> dict:
    out: dict = {}
    for v in values:
        out[v] = out.get(v, 0) + 1
    return out


@ALL
def test_transition_probabilities_are_the_models(name):
    model = MODELS[name]()
    pp = interop.to_pomdp_py(model)
    states = pp.transition_model.get_all_states()
    assert len(states) == model.n_states == len(set(states))
    for a in range(model.n_actions):
        dense = engine.transition_matrix(model, a).toarray()
        action = pp.to_action(a)
        got = np.array([[pp.transition_model.probability(s2, s, action) for s2 in states] for s in states])
        np.testing.assert_allclose(got, dense, rtol=0, atol=1e-12)
        np.testing.assert_allclose(got.sum(axis=1), 1.0, rtol=0, atol=1e-12)


@ALL
def test_observation_probabilities_are_the_sensors(name):
    model = MODELS[name]()
    pp = interop.to_pomdp_py(model)
    obs = pp.observation_model.get_all_observations()
    assert [o.reading for o in obs] == list(range(model.sensor.n_readings))
    action = pp.actions[0]
    for s in pp.transition_model.get_all_states():
        got = np.array([pp.observation_model.probability(o, s, action) for o in obs])
        want = np.array([likelihood_at(model, z, s.tuple) for z in range(model.sensor.n_readings)])
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)
        assert got.sum() == pytest.approx(1.0, abs=1e-12)
        assert pp.observation_model.probability(pp.done, s, action) == 0.0


@ALL
def test_sampling_matches_the_probabilities(name):
    model = MODELS[name]()
    pp = interop.to_pomdp_py(model, seed=12)
    for state in pick_states(model, 3, seed=5):
        s = pp.to_state(state)
        for a in range(model.n_actions):
            action = pp.to_action(a)
            draws = counts_of(pp.transition_model.sample(s, action) for _ in range(N_DRAWS))
            probs = {s2: pp.transition_model.probability(s2, s, action) for s2 in pp.transition_model.get_all_states()}
            probs = {k: v for k, v in probs.items() if v > 0}
            p = chi_square_p(draws, probs, N_DRAWS)
            assert p > P_MIN, f"{name}: next states of {state} under {a}: chi-square p = {p:.2g}"
        draws = counts_of(pp.observation_model.sample(s, pp.actions[0]) for _ in range(N_DRAWS))
        probs = {o: pp.observation_model.probability(o, s, pp.actions[0]) for o in pp.observations}
        probs = {k: v for k, v in probs.items() if v > 0}
        p = chi_square_p(draws, probs, N_DRAWS)
        assert p > P_MIN, f"{name}: readings in {state}: chi-square p = {p:.2g}"


def test_the_chi_square_check_catches_a_wrong_sampler():
    """The check has teeth: readings drawn in one state fail against another state's probabilities,
    and an outcome of probability 0 fails outright."""
    model = colour_grid_model()
    pp = interop.to_pomdp_py(model, seed=0)
    a, b = _two_states_of_different_colour(model, pp)
    draws = counts_of(pp.observation_model.sample(a, pp.actions[0]) for _ in range(N_DRAWS))
    wrong = {o: pp.observation_model.probability(o, b, pp.actions[0]) for o in pp.observations}
    assert chi_square_p(draws, wrong, N_DRAWS) < 1e-12
    assert chi_square_p({"x": 1}, {"y": 1.0}, 1) == 0.0


def _two_states_of_different_colour(model, pp):
    cells = model.grid.free_cells
    first = cells[0]
    other = next(c for c in cells if model.grid.labels[c[0], c[1]] != model.grid.labels[first[0], first[1]])
    return pp.to_state((0, *first)), pp.to_state((0, *other))


def test_sampling_goes_through_the_engine_with_the_adapters_generator():
    """The same generator state gives the engine's own draws; seed() makes runs repeat."""
    model = windy_maze_model()
    pp = interop.to_pomdp_py(model, seed=3)
    s, action = pp.to_state((0, 1, 1)), pp.to_action(2)
    mine = [pp.transition_model.sample(s, action).tuple for _ in range(50)]
    rng = np.random.default_rng(3)
    theirs = [tuple(int(v) for v in engine.sample_next(model, np.array([[0, 1, 1]]), 2, rng)[0]) for _ in range(50)]
    assert mine == theirs
    pp.seed(7)
    first = [pp.observation_model.sample(s, action).reading for _ in range(50)]
    pp.seed(7)
    assert first == [pp.observation_model.sample(s, action).reading for _ in range(50)]
    rng = np.random.default_rng(7)
    assert first == [int(engine.sample_readings(model, np.array([[0, 1, 1]]), rng)[0]) for _ in range(50)]


def test_conversions_round_trip():
    model = windy_maze_model()  # observations are 4-bit arrays, readings 0..15
    pp = interop.to_pomdp_py(model)
    for i in range(model.n_states):
        st = model.state_of_index(i)
        assert pp.from_state(pp.to_state(st)) == st
        assert pp.to_state(np.array(st)) == pp.to_state(st) and hash(pp.to_state(st)) == hash(pp.to_state(st))
    for a in range(model.n_actions):
        act = pp.to_action(a)
        assert pp.from_action(act) == a and act.name == model.action_names[a] and act == pp.to_action(np.int64(a))
    for z in range(model.sensor.n_readings):
        obs = model.sensor.to_observation(z)
        o = pp.to_observation(obs)
        assert o.reading == z and np.array_equal(pp.from_observation(o), obs)
    with pytest.raises(ValueError):
        pp.to_action(4)
    with pytest.raises(ValueError, match="not a free state"):
        pp.to_state((1, 0, 0))
    with pytest.raises(ValueError, match="done"):
        pp.from_observation(pp.done)


def test_reward_and_policy_models():
    model = colour_grid_model()
    pp = interop.to_pomdp_py(model, seed=0)
    s = pp.to_state((0, 0, 0))
    assert pp.reward_model.sample(s, pp.actions[1], s) == -1.0
    assert pp.reward_model.probability(-1.0, s, pp.actions[1], s) == 1.0
    assert pp.policy_model.get_all_actions() == list(pp.actions)
    assert pp.policy_model.probability(pp.actions[0], s) == pytest.approx(0.25)
    drawn = counts_of(pp.policy_model.rollout(s).index for _ in range(4000))
    assert stats.chisquare([drawn.get(a, 0) for a in range(4)]).pvalue > P_MIN


def test_agent_particles_come_from_the_exact_belief():
    model = windy_maze_model()
    pp = interop.to_pomdp_py(model, seed=1)
    belief = np.zeros(model.belief_shape)
    cells = model.grid.free_cells[:3]
    for (r, c), p in zip(cells, (0.6, 0.3, 0.1)):
        belief[0, r, c] = p
    agent = pp.agent(belief, n_particles=2000)
    assert isinstance(agent, pomdp_py.Agent) and isinstance(agent.belief, pomdp_py.Particles)
    got = counts_of(s.tuple for s in agent.belief.particles)
    assert set(got) == {(0, int(r), int(c)) for r, c in cells}
    assert got[(0, int(cells[0][0]), int(cells[0][1]))] / 2000 == pytest.approx(0.6, abs=0.05)
    plain = pp.agent(belief, n_particles=10, plan=False)
    assert all(type(s) is pp.State for s in plain.belief.particles) and plain.transition_model is pp.transition_model
    with pytest.raises(ValueError, match="shape"):
        pp.agent(np.ones((2, 2)))


def test_the_planning_model_follows_the_exact_belief_and_ends_at_the_referee():
    """Along a simulated history the node's belief is the forward filter's; the reward is -1 until
    the referee's test holds, then 0 with the 'done' observation in an absorbing state."""
    model = windy_maze_model()
    pp = interop.to_pomdp_py(model, threshold=0.9, seed=4)
    f = ForwardFilter(model).reset(model.sensor.to_observation(0))
    state = pp.agent(f.full_belief, n_particles=1).belief.particles[0]
    for step in range(200):
        a = pp.actions[step % 4]
        nxt, obs, reward, nsteps = pp.blackbox_model.sample(state, a)
        assert nsteps == 1
        if state.node.done:
            assert (nxt, obs, reward) == (state, pp.done, 0.0)
            break
        assert reward == -1.0
        f.step(a.index, model.sensor.to_observation(obs.reading))
        np.testing.assert_allclose(nxt.node.belief, f.full_belief, rtol=0, atol=1e-12)
        assert nxt.node.done == (f.full_belief.max() >= 0.9)
        assert state.node.child(a.index, obs.reading) is nxt.node  # one node per (action, reading)
        state = nxt
    else:
        pytest.fail("the simulated robot was never localised")


def test_pose_referee_tests_the_full_state():
    model = depth_maze_model(perfect_maze(7, seed=0), max_depth=5)
    b = np.zeros(model.belief_shape)
    r, c = model.grid.free_cells[0]
    b[:, r, c] = 0.25  # the position is certain, the heading is not
    assert interop.to_pomdp_py(model).localised(b)
    assert not interop.to_pomdp_py(model, pose=True).localised(b)


def test_a_clear_error_without_pomdp_py(monkeypatch):
    monkeypatch.setitem(sys.modules, "pomdp_py", None)
    pomdp_models.classes.cache_clear()
    try:
        with pytest.raises(ImportError, match=r"pip install 'gym_gridloc\[planning\]'"):
            interop.to_pomdp_py(colour_grid_model())
    finally:
        pomdp_models.classes.cache_clear()


def test_the_core_does_not_import_pomdp_py():
    out = run_python("import sys, gym_gridloc, gym_gridloc.interop; print('pomdp_py' in sys.modules)")
    assert out == "False"
