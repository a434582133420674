"""The referee (gym_gridloc/referee.py): info, reward and termination from exact beliefs, for a batch
(the single environment is a batch of one).  Checked against a direct computation per belief."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gym_gridloc import referee, ring_sensor_model, windy_maze_model
from tests.helpers import random_belief


def direct(belief: np.ndarray, state, threshold: float, pose: bool) -> dict:
    """The referee's view of one (L, H, W) belief, computed cell by cell."""
    L, H, W = belief.shape
    pos = belief.sum(axis=0)
    if pose:
        best = max((belief[l, r, c], -(l * H * W + r * W + c), (l, r, c)) for l in range(L) for r in range(H)
                    for c in range(W))
        confidence, _, (layer, er, ec) = best
    else:
        best = max((pos[r, c], -(r * W + c), (r, c)) for r in range(H) for c in range(W))
        confidence, _, (er, ec) = best
        layer = None
    error = abs(er - state[1]) + abs(ec - state[2])
    localised = confidence >= threshold
    right = error == 0 and (not pose or layer == state[0])
    p = pos[pos > 0]
    out = {
        "position": (state[1], state[2]), "estimate": (er, ec), "confidence": confidence, "error": error,
        "localised": localised, "success": localised and right, "entropy": float(-(p * np.log2(p)).sum()),
    }
    if L > 1:
        out["heading"] = state[0]
    if pose:
        out["estimate_heading"] = layer
    return out


@pytest.mark.parametrize("pose", [False, True])
@pytest.mark.parametrize("make", [windy_maze_model, lambda: ring_sensor_model((4, 5), dynamics="passive")],
                         ids=["windy", "ring-passive"])
def test_summarise_equals_a_direct_computation(make, pose):
    model = make()
    rng = np.random.default_rng(0)
    n = 12
    beliefs = np.stack([random_belief(model, rng, power=8.0) for _ in range(n)])
    states = np.array([model.state_of_index(int(s)) for s in rng.integers(model.n_states, size=n)])
    # Two beliefs localised on the truth, one confident elsewhere.
    for i, st in ((0, states[0]), (1, states[1])):
        beliefs[i] = 0.0
        beliefs[i][tuple(st)] = 1.0
    other = model.state_of_index((model.state_index(tuple(states[2])) + 1) % model.n_states)
    beliefs[2] = 0.0
    beliefs[2][other] = 1.0
    threshold = 0.3
    info = referee.summarise(beliefs, states, threshold, pose=pose)
    assert all(v.shape[0] == n for v in info.values())
    for i in range(n):
        one = referee.summary(beliefs[i], states[i], threshold, pose=pose)
        ref = direct(beliefs[i], tuple(int(v) for v in states[i]), threshold, pose)
        assert one.keys() == ref.keys() == info.keys()
        for key, value in one.items():  # the single environment's summary is the batch's row, exactly
            row = info[key][i]
            assert (tuple(row.tolist()) if row.ndim else row.item()) == value, (i, key)
        for key, value in ref.items():
            if key in ("confidence", "entropy"):
                assert type(one[key]) is float and one[key] == pytest.approx(value, abs=1e-12)
            else:
                assert one[key] == value, (i, key)
    assert info["success"][0] and info["success"][1] and not info["success"][2] and info["localised"][2]
    assert info["entropy"][0] == 0.0


def test_summary_gives_python_scalars_and_tuples():
    model = windy_maze_model()
    info = referee.summary(model.prior(), np.array([0, 5, 0]), 0.9)
    assert info["position"] == (5, 0) and type(info["position"][0]) is int
    assert type(info["estimate"]) is tuple and type(info["error"]) is int
    assert type(info["localised"]) is bool and type(info["success"]) is bool and info["localised"] is False
    assert info["confidence"] == pytest.approx(1 / 31) and info["entropy"] == pytest.approx(math.log2(31))


def test_rewards():
    info = {"confidence": np.array([0.25, 1.0, 0.5])}
    np.testing.assert_array_equal(referee.rewards("step", info), [-1.0, -1.0, -1.0])
    got = referee.rewards("belief", info)
    assert got.dtype == np.float64
    np.testing.assert_array_equal(got, [0.25, 1.0, 0.5])
    assert referee.REWARDS == ("step", "belief")


@pytest.mark.parametrize("kind", referee.REWARDS)
def test_rewards_of_reset_environments_are_zero(kind):
    """With ``stepped``, the rewards are those of the steps and 0.0 (not -0.0) where an
    environment was reset: the vector env's rewards."""
    info = {"confidence": np.array([0.2, 0.95, 0.5, 1.0])}
    stepped = np.array([True, False, True, False])
    got = referee.rewards(kind, info, stepped)
    want = np.where(stepped, referee.rewards(kind, info), 0.0)
    assert got.dtype == np.float64 and got.tobytes() == want.tobytes()


@pytest.mark.parametrize("kind", referee.REWARDS)
@pytest.mark.parametrize("limit, fixed_length", [(None, False), (3, False), (4, True)])
def test_outcomes_compiled_and_numpy_agree(kind, limit, fixed_length):
    """referee.outcomes, the end of a step: rewards (0.0 where restarted), terminated (localised,
    on a step, unless the length is fixed), truncated (at the limit) and the step counts (+1, or
    0 where restarted), in numpy and as the compiled step fills them (its ``batch_outcomes``), to
    the bit; a row the compiled step keeps keeps its step count and ends nothing."""
    from gym_gridloc import kernels

    rng = np.random.default_rng(1)
    n = 40
    info = {"localised": rng.random(n) < 0.3, "confidence": rng.random(n)}
    restarted = rng.random(n) < 0.2
    elapsed = rng.integers(0, 5, size=n)
    e = elapsed.copy()
    out = referee.outcomes(kind, info, restarted, e, limit, fixed_length)
    rewards, terminated, truncated, done = out
    after = np.where(restarted, 0, elapsed + 1)
    assert np.array_equal(e, after)
    assert rewards.tobytes() == np.where(restarted, 0.0, info["confidence"] if kind == "belief" else -1.0).tobytes()
    assert np.array_equal(terminated, info["localised"] & ~restarted & (not fixed_length))
    assert np.array_equal(truncated, after >= limit if limit else np.zeros(n, dtype=bool))
    assert np.array_equal(done, terminated | truncated)
    fast = kernels.compiled(1)
    if fast is None:
        return
    b = referee.Blocks(n, 1, 0.9, False, kind=kind, limit=limit, fixed_length=fixed_length)
    modes = restarted.astype(np.int8)  # (0: a step, 1: a new episode)
    modes[-1] = 2  # kept
    e2 = elapsed.copy()
    fast.batch_outcomes(modes, info["localised"], info["confidence"], e2, b.limit, b.fixed_length, b.belief_reward, b.rewards, b.ends)
    kept = slice(0, n - 1)
    assert e2[:-1].tobytes() == e[:-1].tobytes() and e2[-1] == elapsed[-1]
    for got, want in zip(b.outcomes(), out):
        assert got[kept].tobytes() == want[kept].tobytes()
    assert b.rewards[-1] == 0.0 and not b.ends[:, -1].any()
