"""The planners: expectimax equals brute force, MCTS converges to expectimax, central, the lower
bound, the leaves; expectimax at depth 1 with an entropy leaf chooses as greedy does; MCTS with a
large budget does no worse than its rollout policy."""

from __future__ import annotations

import functools

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc
import gym_gridloc_agents.planners as P
from gym_gridloc.engine import transition_matrix
from gym_gridloc_agents.policies import GreedyPolicy, make_policy
from gym_gridloc_agents.evaluation.rollout import rollout


def models():
    return {
        "colour": gym_gridloc.colour_grid_model(),
        "windy": gym_gridloc.windy_maze_model(),
        "ring": gym_gridloc.ring_sensor_model(),
        "ring5-passive": gym_gridloc.ring_sensor_model((5, 5), dynamics="passive"),  # L = 4 headings
        "windy-kidnap": gym_gridloc.windy_maze_model().with_kidnapping(0.05),
    }


MODELS = models()


def random_belief(model, rng):
    v = rng.random(model.n_states) ** 3
    return model.from_vector(v / v.sum())


# -- the engine function -----------------------------------------------------------------------------
@pytest.mark.parametrize("name", list(MODELS))
def test_predict_batch_equals_filter_and_dense(name):
    m = MODELS[name]
    rng = np.random.default_rng(0)
    bs = np.stack([random_belief(m, rng) for _ in range(7)])
    acts = rng.integers(m.n_actions, size=7)
    out = P.predict_batch(m, bs, acts)
    assert out.shape == (7, *m.belief_shape)
    for b, a, o in zip(bs, acts, out):
        dense = transition_matrix(m, int(a)).toarray().T @ m.to_vector(b)
        np.testing.assert_allclose(m.to_vector(o), dense, atol=1e-13)
        f = gym_gridloc.ForwardFilter(m)
        f.reset()
        f.set_belief(b)
        f.predict(int(a))
        np.testing.assert_allclose(o, f.full_belief, atol=1e-12)
        assert np.all(o[:, ~m.grid.free] == 0)


def test_ops_likelihood_broadcasts_to_layers():
    m = MODELS["ring5-passive"]
    ops = P.BeliefOps(m)
    assert ops.lik.shape == (m.sensor.n_readings, *m.belief_shape)
    for z in (0, 7, m.sensor.n_readings - 1):
        np.testing.assert_allclose(m.to_vector(ops.lik[z]), m.likelihood_vector(z))


# -- expectimax against a brute-force recursion on dense matrices ------------------------------------
def brute_value(m, b, depth, leaf_value, thr=0.9, prune=0.0, renormalise=True):
    """min_a Q(a) with the recursion written out over dense matrices and likelihood_vector."""
    T = [transition_matrix(m, a).toarray() for a in range(m.n_actions)]
    O = np.stack([m.likelihood_vector(z) for z in range(m.sensor.n_readings)])
    nf = m.grid.n_free

    def localised(v):
        return v.reshape(m.n_layers, nf).sum(axis=0).max() >= thr

    def q(v, d):
        out = []
        for a in range(m.n_actions):
            pred = T[a].T @ v
            total, acc, kept = 0.0, 0.0, 0.0
            for z in range(O.shape[0]):
                pz = float(O[z] @ pred)
                total += pz
                if pz <= 0 or pz < prune * (O @ pred).sum():
                    continue
                kept += pz
                post = O[z] * pred / pz
                if localised(post):
                    continue
                acc += pz * (leaf_value if d == 1 else min(q(post, d - 1)))
            out.append(1.0 + acc / (kept if renormalise else total))
        return out

    return np.array(q(m.to_vector(b), depth))


@pytest.mark.parametrize("name,depth", [("colour", 1), ("colour", 2), ("colour", 3), ("windy", 1), ("windy", 2),
                                        ("ring5-passive", 2), ("windy-kidnap", 1)])
def test_expectimax_equals_brute_force(name, depth):
    m = MODELS[name]
    ops = P.BeliefOps(m)
    rng = np.random.default_rng(1)
    for _ in range(2):
        b = random_belief(m, rng)
        got = P.expectimax_q(ops, b, depth, P.ConstantLeaf(1.7), memo=True, max_pairs=64)  # tiny batches
        want = brute_value(m, b, depth, 1.7)
        np.testing.assert_allclose(got, want, rtol=1e-10)
        got = P.expectimax_q(ops, b, depth, P.ConstantLeaf(1.0), prune=0.02, renormalise=False)
        want = brute_value(m, b, depth, 1.0, prune=0.02, renormalise=False)
        np.testing.assert_allclose(got, want, rtol=1e-10)
        got = P.expectimax_q(ops, b, depth, P.ConstantLeaf(1.0), prune=0.02)
        want = brute_value(m, b, depth, 1.0, prune=0.02)
        np.testing.assert_allclose(got, want, rtol=1e-10)


def test_expectimax_localised_branches_cost_one_step():
    # 0.95 on one cell, a perfect sensor and no slip: every action localises in one step (cost 1,
    # the leaf never used); the root itself is not treated as localised.
    m = gym_gridloc.colour_grid_model(accuracy=1.0, slip=0.0)
    b = np.zeros(m.belief_shape)
    free = np.argwhere(m.grid.free)
    b[(0, *free[0])] = 0.95
    b[(0, *free[5])] = 0.05
    q = P.expectimax_q(P.BeliefOps(m), b, 3, P.ConstantLeaf(50.0))
    np.testing.assert_allclose(q, 1.0)


def test_expectimax_policy_interface_and_ties():
    m = MODELS["windy"]
    pol = P.ExpectimaxPolicy(m, depth=2, leaf="one", prune=1e-3, seed=0)
    b = m.prior()
    pol.reset(seed=3)
    a1 = [pol.act(None, b) for _ in range(5)]
    pol.reset(seed=3)
    a2 = [pol.act(None, b[0]) for _ in range(5)]  # (H, W) accepted when L = 1
    assert a1 == a2 and all(isinstance(a, int) and 0 <= a < 4 for a in a1)
    with pytest.raises(ValueError):
        P.ExpectimaxPolicy(m, depth=0)
    with pytest.raises(ValueError):
        pol.act(None, np.ones((3, 3)))


# -- central --------------------------------------------------------------------------------------
def test_central_matches_direct_computation_and_refuses_other_sensors():
    m = MODELS["ring"]
    pol = P.CentralPolicy(m, seed=0)
    rng = np.random.default_rng(2)
    nothing = m.sensor.n_readings - 1
    for _ in range(5):
        b = random_belief(m, rng)
        p = [m.likelihood_vector(nothing) @ (transition_matrix(m, a).toarray().T @ m.to_vector(b)) for a in range(4)]
        np.testing.assert_allclose(pol.values(b), p, atol=1e-14)
        assert pol.act(None, b) == int(np.argmin(p))
    with pytest.raises(ValueError, match="nothing"):
        P.CentralPolicy(MODELS["colour"]).act(None, MODELS["colour"].prior())
    P.CentralPolicy(MODELS["colour"], nothing=0).act(None, MODELS["colour"].prior())  # explicit reading: allowed


# -- MCTS -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("name,rollout", [("colour", "greedy"), ("windy", "random"), ("ring", "central"),
                                          ("ring5-passive", "greedy"), ("windy", "none")])
def test_mcts_valid_and_seeded(name, rollout):
    m = MODELS[name]
    pol = P.MCTSPolicy(m, simulations=40, rollout=rollout, rollout_steps=5)
    b = random_belief(m, np.random.default_rng(4))
    pol.reset(seed=11)
    a = pol.act(None, b)
    pol.reset(seed=11)
    assert pol.act(None, b) == a and 0 <= a < m.n_actions
    root = pol.search(b)
    assert root.na.sum() == 40


def test_mcts_time_budget():
    m = MODELS["windy"]
    pol = P.MCTSPolicy(m, time_ms=30, rollout="greedy")
    pol.reset(seed=0)
    pol.act(None, m.prior())
    assert 0.02 < pol.seconds < 0.3


def test_mcts_depth_one_values_converge_to_expectimax():
    # With max_depth=1 and no rollout, a simulation's cost is 1 + leaf(posterior) (0 if localised)
    # for a reading drawn from p(z | b, a): its mean is the depth-1 expectimax Q(a).
    m = MODELS["windy"]
    ops = P.BeliefOps(m)
    b = random_belief(m, np.random.default_rng(7)) ** 0.2
    b = b / b.sum()
    leaf = P.ConstantLeaf(3.0)
    pol = P.MCTSPolicy(m, simulations=4000, rollout="none", leaf=leaf, max_depth=1, c=20.0)
    pol.reset(seed=1)
    root = pol.search(b)
    want = P.expectimax_q(ops, b, 1, leaf)
    se = 3.0 / np.sqrt(root.na)
    assert np.all(np.abs(root.qa - want) < 4 * se + 1e-9), (root.qa, want, root.na)


# -- leaves and the lower bound -------------------------------------------------------------------
def test_leaves_roundtrip(tmp_path):
    m = MODELS["windy"]
    ops = P.BeliefOps(m)
    rng = np.random.default_rng(6)
    bs = np.stack([random_belief(m, rng) for _ in range(300)])
    y = 1 + 5 * ops.entropy(bs) / 5
    ent = P.EntropyLeaf.fit(ops.entropy(bs), y)
    assert np.all(np.diff(ent.y) >= 0)
    for leaf in (ent, P.ConstantLeaf(2.5)):
        path = tmp_path / f"{leaf.kind}.json"
        leaf.save(path)
        np.testing.assert_allclose(P.load_leaf(str(path))(ops, bs), leaf(ops, bs))
    shipped = P.load_leaf("shipped", "WindyMaze-v0")
    assert isinstance(shipped, P.EntropyLeaf) and np.all(np.diff(shipped.y) >= 0)
    assert isinstance(P.load_leaf("shipped", "DepthMaze-v0"), P.ConstantLeaf)  # none shipped: one step


def test_lower_bound_depth_one_and_monotone():
    m = MODELS["colour"]
    ops = P.BeliefOps(m)
    b0, p0 = P.initial_beliefs(ops)
    assert p0.sum() == pytest.approx(1.0)
    # depth 1: 1 + min_a P(not localised after a) per first reading
    want = 0.0
    for b, p in zip(b0, p0):
        want += p * brute_value(m, b, 1, 1.0, thr=0.9 - 1e-9).min()
    lb1 = P.lower_bound(m, 1)["bound"]
    assert lb1 == pytest.approx(want, rel=1e-12)
    lb2 = P.lower_bound(m, 2)["bound"]
    lb2p = P.lower_bound(m, 2, prune=0.01)["bound"]
    assert lb1 <= lb2 and lb2p <= lb2 + 1e-12


@functools.lru_cache
def _greedy_steps(name):
    m = MODELS[name]
    pol = P.ExpectimaxPolicy(m, depth=1, leaf="one")
    return P.belief_rollouts(m, pol, 300, seed=5, record=False)["steps"].mean()


def test_lower_bound_below_a_policy():
    lb = P.lower_bound(MODELS["colour"], 3)["bound"]
    assert lb < _greedy_steps("colour")


def test_expected_mcts_one_expansion_is_depth_one_expectimax():
    m = MODELS["windy"]
    ops = P.BeliefOps(m)
    b = random_belief(m, np.random.default_rng(8))
    leaf = P.ConstantLeaf(2.5)
    pol = P.ExpectedMCTSPolicy(m, simulations=1, leaf=leaf, prune=0.0)
    pol.reset(seed=0)
    root = pol.search(b)
    # one simulation expands the root and one child: Q of the untouched actions is depth-1 exact
    want = P.expectimax_q(ops, b, 1, leaf)
    touched = np.flatnonzero(root.na > 0)
    untouched = np.flatnonzero(root.na == 0)
    np.testing.assert_allclose(root.q[untouched], want[untouched], rtol=1e-12)
    assert len(touched) == 1


def test_expected_mcts_full_budget_matches_depth_two():
    # With a budget that expands every depth-1 child, Q at the root equals depth-2 expectimax.
    m = MODELS["colour"]
    ops = P.BeliefOps(m)
    b = random_belief(m, np.random.default_rng(9))
    leaf = P.ConstantLeaf(2.0)
    pol = P.ExpectedMCTSPolicy(m, simulations=3000, leaf=leaf, prune=0.0, max_depth=1, c=100.0)
    pol.reset(seed=0)
    root = pol.search(b)
    np.testing.assert_allclose(root.q, P.expectimax_q(ops, b, 2, leaf), rtol=1e-10)


# -- what the issue asks of the planners ----------------------------------------------------------
@pytest.mark.parametrize("name", ["colour", "windy", "ring", "ring5-passive"])
def test_expectimax_depth_one_with_an_entropy_leaf_chooses_as_greedy(name):
    # Q(a) = 1 + E_z[leaf(b_az)] with leaf = the posterior's position entropy and a threshold no
    # belief reaches: the same order of actions as greedy's expected entropy.
    m = MODELS[name]
    identity = P.EntropyLeaf([0.0, 64.0], [0.0, 64.0])
    ex = P.ExpectimaxPolicy(m, depth=1, leaf=identity, prune=0.0, threshold=1.5)
    greedy = GreedyPolicy(m)
    rng = np.random.default_rng(3)
    for _ in range(20):
        b = random_belief(m, rng)
        q, h = ex.values(b / b.sum()), greedy.expected_entropies(b)
        np.testing.assert_allclose(q - 1.0, h, rtol=1e-9, atol=1e-9)
        assert set(ex.best(q)) == set(greedy.best(h))


def test_mcts_with_a_large_budget_is_no_worse_than_its_rollout_policy():
    # Same episodes (common random numbers); MCTS rolls out greedy, so it should at least match
    # greedy: the upper end of the paired difference's 95% interval stays below a small margin.
    env = gym_gridloc.HMMBeliefWrapper(gym.make("ColourGrid-v0"))
    m = env.unwrapped.model
    greedy = GreedyPolicy(m)
    mcts = P.MCTSPolicy(m, simulations=300, rollout="greedy", rollout_steps=10, c=0.3, leaf="one")
    seeds = range(150)
    steps_g = np.array([rollout(env, greedy, s).steps for s in seeds])
    steps_m = np.array([rollout(env, mcts, s).steps for s in seeds])
    diff = steps_m - steps_g
    upper = diff.mean() + 1.96 * diff.std(ddof=1) / np.sqrt(len(diff))
    assert upper < 0.2, (steps_m.mean(), steps_g.mean(), upper)


def test_planners_through_make_policy_and_soft_labels():
    m = MODELS["windy"]
    pol = make_policy("expectimax", m, env_id="WindyMaze-v0", seed=0)
    assert isinstance(pol.leaf, P.EntropyLeaf)
    p = pol.probabilities(None, m.prior())
    assert p.sum() == pytest.approx(1.0) and set(np.flatnonzero(p)) <= set(range(4))
    assert make_policy("mcts", m, readings="sample", simulations=5).name == "mcts"
    with pytest.raises(ValueError, match="readings must be"):
        make_policy("mcts", m, readings="guess")
