"""The benchmark's statistics: hierarchical and paired bootstraps, rliable's aggregates, normalised
scores, checked against scipy (and rliable's metrics where they import) on fixed inputs."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sps

from gym_gridloc_agents.evaluation import aggregate, paired, scores, stats
from gym_gridloc_agents.evaluation.rows import Task, add_gaps, episode_arrays, seed_aggregate, summarise


def _part(steps, collapsed=None, length=None, max_steps=100):
    """A :func:`simulate` result with these per-episode steps (and collapsed flags under the protocol)."""
    steps = np.asarray(steps, dtype=np.int64)
    n = steps.size
    correct = np.zeros((n, max(max_steps, 50) + 1), dtype=bool)  # as simulate: to the largest budget
    for i, s in enumerate(steps):
        correct[i, s:] = True
    done = steps < max_steps
    return {"steps": steps, "localised": done, "success": done, "truncated": ~done, "correct_at": correct,
            "collapsed_end": np.asarray(collapsed if collapsed is not None else done, dtype=bool), "max_steps": max_steps,
            "episode_length": length, "seconds": 0.0, "decision_seconds": 0.0, "decisions": int(steps.sum()), "model": None}


def _row(policy, steps, env="WindyMaze-v0", **kw):
    return summarise(Task(env, policy), parts=[_part(steps, **kw)], seed_start=0)


# -- bootstraps ----------------------------------------------------------------------------------------
def test_one_seed_hierarchical_interval_is_scipys_percentile_bootstrap():
    x = np.random.default_rng(3).poisson(5.0, 400).astype(float)
    ours = stats.hierarchical_ci(x[None])
    ref = sps.bootstrap((x,), np.mean, method="percentile", n_resamples=10_000, rng=np.random.default_rng(1)).confidence_interval
    width = ref.high - ref.low
    assert abs(ours[0] - ref.low) < 0.05 * width and abs(ours[1] - ref.high) < 0.05 * width


def test_three_seeds_interval_is_not_their_range():
    # three seeds whose means differ, each with episode noise: the old interval (a bootstrap of the three
    # seed means) was exactly their lowest and highest mean
    rng = np.random.default_rng(0)
    runs = [[_part(rng.integers(2, 12, 300) + shift)] for shift in (0, 1, 2)]
    row = seed_aggregate(Task("WindyMaze-v0", "ppo"), runs, seed_start=0)
    means = [r["mean_steps"] for r in row["per_seed"]]
    assert row["mean_steps_seed_range"] == [min(means), max(means)]
    lo, hi = row["mean_steps_ci95"]
    assert lo < row["mean_steps"] < hi
    assert [lo, hi] != [min(means), max(means)]
    assert "seeds, then the episodes" in row["ci95"] and row["iqm_trimmed"] is False
    assert row["per_episode"]["seeds"] == 3 and episode_arrays(row)["steps"].shape == (3, 300)
    # three seeds with the same mean over very different episodes: the seeds' range is one point, the
    # uncertainty over episodes is not
    x = rng.integers(1, 40, 300)
    same = seed_aggregate(Task("WindyMaze-v0", "ppo"), [[_part(rng.permutation(x))] for _ in range(3)], seed_start=0)
    lo, hi = same["mean_steps_ci95"]
    assert same["mean_steps_seed_range"][0] == same["mean_steps_seed_range"][1]
    assert hi - lo > 1.0 and lo < x.mean() < hi  # (the seeds' range: width 0)


def test_pairing_removes_the_spread_common_episodes_share():
    a = np.random.default_rng(1).integers(1, 60, 500)
    ra, rb = _row("greedy2", a), _row("random", a + 1)
    c = paired.compare(ra, rb)
    assert c["ci95"] == [-1.0, -1.0] and c["difference"] == -1.0 and c["verdict"] == "better"
    assert c["probability_of_improvement"] == 1.0 and c["interval_over"] == "episodes (paired bootstrap)"
    assert paired.compare(rb, ra)["verdict"] == "worse"
    # unpaired, the same difference would be a tie: the episodes' spread (sd ~17) swamps 1 step
    ind = sps.bootstrap((a, a + 1), lambda x, y: np.mean(x) - np.mean(y), paired=False, method="percentile",
                        n_resamples=2000, rng=np.random.default_rng(0), vectorized=False).confidence_interval
    assert ind.low < 0 < ind.high


def test_paired_interval_matches_scipys_paired_bootstrap_and_decides_the_verdict():
    rng = np.random.default_rng(2)
    a = rng.integers(1, 20, 300)
    b = np.clip(a + rng.integers(-3, 4, 300), 1, None)
    c = paired.compare(_row("greedy", a), _row("greedy2", b))
    ref = sps.bootstrap((a - b,), np.mean, method="percentile", n_resamples=10_000, rng=np.random.default_rng(0)).confidence_interval
    width = ref.high - ref.low
    assert abs(c["ci95"][0] - ref.low) < 0.05 * width and abs(c["ci95"][1] - ref.high) < 0.05 * width
    assert c["difference"] == pytest.approx(np.mean(a - b))
    assert c["verdict"] == paired.verdict(c["ci95"], True)
    assert paired.verdict([-0.5, 0.1], True) == "tie"  # a negative point estimate is no win
    assert paired.verdict([-0.5, -0.1], True) == "better" and paired.verdict([-0.5, -0.1], False) == "worse"
    assert paired.verdict([0.1, 0.5], False) == "better"


def test_several_seeds_resample_seeds_then_episodes():
    rng = np.random.default_rng(4)
    base = rng.integers(2, 30, 200)
    runs = [[_part(base + s)] for s in (0, 3, 6)]  # seeds far apart, each pairs with B episode by episode
    agg = seed_aggregate(Task("WindyMaze-v0", "ppo"), runs, seed_start=0)
    c = paired.compare(agg, _row("greedy2", base))
    assert c["difference"] == pytest.approx(3.0) and c["seeds"] == [3, 1]
    assert c["interval_over"].startswith("seeds, then")
    assert c["ci95"][0] == pytest.approx(0.0) and c["ci95"][1] == pytest.approx(6.0)  # the seeds' spread alone
    assert c["verdict"] == "tie"


def test_mcnemar_is_the_exact_binomial_test_of_the_discordant_episodes():
    a = np.array([1] * 10 + [0] * 2 + [1] * 30 + [0] * 8, dtype=bool)
    b = np.array([0] * 10 + [1] * 2 + [1] * 30 + [0] * 8, dtype=bool)
    m = paired.mcnemar(a, b)
    assert (m["a_only"], m["b_only"]) == (10, 2)
    assert m["p_value"] == pytest.approx(sps.binomtest(10, 12, 0.5).pvalue)
    assert paired.mcnemar(a, a)["p_value"] == 1.0
    steps = np.full(a.size, 15)
    ra = _row("optimal", steps, env="DepthMaze-v0", collapsed=a, length=15, max_steps=15)
    rb = _row("greedy2", steps, env="DepthMaze-v0", collapsed=b, length=15, max_steps=15)
    for r in (ra, rb):
        r["episode_length"] = 15
    c = paired.compare(ra, rb)
    assert c["metric"] == "accuracy_at_L" and c["mcnemar"] == m and c["difference"] == pytest.approx(8 / 50)


# -- rliable's aggregates -------------------------------------------------------------------------------
SCORES = {"a": [0.1, 0.5, 0.9, 0.4, 0.35], "b": [0.3, 0.4, 1.0, 0.8, 0.2], "c": [0.0, 0.05, 0.7, 0.6, 0.95]}


def test_iqm_is_the_trimmed_mean_of_all_runs_and_tasks():
    pooled = np.concatenate(list(SCORES.values()))
    assert aggregate.iqm_interval(SCORES)["iqm"] == pytest.approx(sps.trim_mean(pooled, 0.25))
    rliable = pytest.importorskip("rliable.metrics")
    matrix = np.array(list(SCORES.values())).T  # runs x tasks
    assert aggregate.iqm_interval(SCORES)["iqm"] == pytest.approx(rliable.aggregate_iqm(matrix))


def test_the_bootstrap_is_stratified_by_task():
    # runs that agree within each task: a stratified bootstrap has nothing to vary, a pooled one would
    out = aggregate.iqm_interval({"a": [1.0] * 4, "b": [0.0] * 4})
    assert out["iqm"] == 0.5 and out["ci95"] == [0.5, 0.5]
    one = aggregate.iqm_interval({"a": SCORES["a"] * 4})  # one task: the ordinary bootstrap of the IQM
    x = np.array(SCORES["a"] * 4)
    ref = sps.bootstrap((x,), lambda v, axis=-1: sps.trim_mean(v, 0.25, axis=axis), method="percentile",
                        n_resamples=10_000, rng=np.random.default_rng(1)).confidence_interval
    width = ref.high - ref.low
    assert abs(one["ci95"][0] - ref.low) < 0.06 * width and abs(one["ci95"][1] - ref.high) < 0.06 * width
    assert aggregate.iqm_interval({"a": [0.2], "b": [0.9]})["ci95"] is None  # one run per task: no interval


def test_performance_profile_and_probability_of_improvement():
    prof = aggregate.performance_profile(SCORES, taus=(0.0, 0.5, 0.9))
    pooled = np.concatenate(list(SCORES.values()))
    assert prof["fraction"] == [np.mean(pooled > t) for t in (0.0, 0.5, 0.9)]
    assert all(lo <= f <= hi for f, (lo, hi) in zip(prof["fraction"], prof["ci95"]))
    other = {k: [v * 0.9 for v in vals] for k, vals in SCORES.items()}
    p = aggregate.probability_of_improvement(SCORES, other)
    by_hand = np.mean([np.mean([[1.0 if u > w else 0.5 if u == w else 0.0 for w in other[t]] for u in SCORES[t]])
                       for t in SCORES])
    assert p == pytest.approx(by_hand)
    assert aggregate.probability_of_improvement(SCORES, SCORES) == 0.5
    rliable = pytest.importorskip("rliable.metrics")
    x, y = np.array(list(SCORES.values())).T, np.array(list(other.values())).T
    assert p == pytest.approx(rliable.probability_of_improvement(x, y))


# -- normalised scores ------------------------------------------------------------------------------------
def test_normalised_scores_name_their_references():
    rows = add_gaps([_row("random", [10] * 4), _row("greedy2", [6] * 4), _row("expectimax", [4] * 4)])
    for r, want in zip(rows, (0.0, 4 / 6, 1.0)):
        assert r["normalised_score"] == pytest.approx(want)
        assert r["normalised_reference"]["one"] == {"name": "expectimax", "value": 4.0, "kind": "best planner"}
    lo, hi = rows[1]["normalised_score_ci95"]
    assert lo <= rows[1]["normalised_score"] <= hi
    colour = add_gaps([_row("random", [6] * 4, env="ColourGrid-v0"), _row("expectimax", [3] * 4, env="ColourGrid-v0")])
    bound = scores.CERTIFIED["ColourGrid-v0"]["value"]
    assert colour[1]["normalised_score"] == pytest.approx((6 - 3) / (6 - bound))
    maze = [_row(p, [15] * 10, env="DepthMaze-v0", collapsed=[1] * k + [0] * (10 - k), length=15, max_steps=15)
            for p, k in (("random", 3), ("greedy2", 6), ("optimal", 9))]
    for r in maze:
        r.update(episode_length=15, env_kwargs={"size": 7, "episode_length": 15})
    maze = add_gaps(maze)
    assert [r["normalised_score"] for r in maze] == pytest.approx([0.0, 0.5, 1.0])
    assert maze[0]["normalised_reference"]["one"]["name"] == "optimal"
    ceiling = add_gaps(maze[:2])
    assert ceiling[1]["normalised_score"] == pytest.approx((0.6 - 0.3) / (1.0 - 0.3))
    assert add_gaps([_row("greedy2", [6] * 4)])[0]["normalised_score"] is None  # no random walk: no scale
