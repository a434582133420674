"""The exact optimal policy of noiseless models: its search over belief sets equals brute force."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc  # noqa: F401 - registers the environments
from gym_gridloc_agents.planners.optimal import BeliefSetSearch


def _brute_value(search: BeliefSetSearch, B: tuple[int, ...], r: int) -> int:
    """How many states of B some closed-loop policy isolates within r actions: every action, every
    reading, no bound and no memory."""
    if len(B) == 1:
        return 1
    if r == 0:
        return 0
    return max(_brute_q(search, B, r, a) for a in range(search.next.shape[0]))


def _brute_q(search: BeliefSetSearch, B: tuple[int, ...], r: int, a: int) -> int:
    groups: dict[int, list[int]] = {}
    for s in B:
        nxt = int(search.next[a, s])
        groups.setdefault(int(search.reading[nxt]), []).append(nxt)
    return sum(_brute_value(search, tuple(sorted(g)), r - 1) for g in groups.values())


@pytest.mark.parametrize("map_seed", [1, 2])
def test_search_equals_brute_force_on_small_mazes(map_seed):
    env = gym.make("DepthMaze-v0", size=5, map_seed=map_seed)
    model = env.unwrapped.model
    search = BeliefSetSearch(model)
    rng = np.random.default_rng(map_seed)
    reading = search.reading
    for z in np.unique(reading):  # the beliefs after the first reading, and random subsets of them
        first = np.flatnonzero(reading == z)
        sets = [first] + [np.sort(rng.choice(first, size=k, replace=False)) for k in range(2, len(first)) for _ in range(2)]
        for B in sets:
            for r in range(4):
                key = tuple(B.tolist())
                assert search.value(key, r) == _brute_value(search, key, r), (key, r)
                if len(B) > 1 and r > 0:
                    q = [_brute_q(search, key, r, a) for a in range(3)]
                    assert [search.q(B, r, a) for a in range(3)] == q
                    best = search.best_actions(B, r)
                    # optimal within r steps (ties narrowed by fewer steps): a non-empty subset of the argmax
                    assert best.any() and all(q[a] == max(q) for a in np.flatnonzero(best))
