"""WindyMaze-v0 (gym_gridloc/envs/windy_maze.py): any maze text and keyword arguments either build a
working environment or raise an error naming what is wrong (hypothesis, with an independent
oracle of validity)."""

from __future__ import annotations

import gymnasium as gym
from hypothesis import given
from hypothesis import strategies as st

from gym_gridloc import WindyMazeEnv
from tests.helpers import (
    PROPERTY_SETTINGS,
    bad_keywords,
    exercise,
    is_probability,
    kwargs_for,
    maybe,
)


@st.composite
def maze_rows(draw):
    clean = draw(st.integers(0, 3)) > 0
    char = st.sampled_from("OOO#") if clean else st.sampled_from("OO##x. \t")
    if draw(st.integers(0, 3)) > 0:
        h, w = draw(st.integers(1, 6)), draw(st.integers(1, 6))
        return ["".join(draw(char) for _ in range(w)) for _ in range(h)]
    return draw(st.lists(st.text(char, max_size=6), max_size=5))


def maze_ok(rows: list[str]) -> bool:
    if not rows or any(r == "" for r in rows) or len({len(r) for r in rows}) != 1:
        return False
    if any(c not in "O#" for r in rows for c in r):
        return False
    return any("O" in r for r in rows)


def drift_check(kwargs, bad):
    v = kwargs.get("drift", 0.1)
    return {"drift"} if is_probability(v) and v > 0.5 else set()


@PROPERTY_SETTINGS
@given(rows=maze_rows(), kwargs=kwargs_for(WindyMazeEnv, {"drift": maybe(st.floats(0.0, 0.5) | st.sampled_from([0.0, 0.5]),
                                                                          st.floats(0.5, 1.0, exclude_min=True))}))
def test_windy_maze_any_input(rows, kwargs):
    exercise(lambda: gym.make("WindyMaze-v0", layout=rows, **kwargs), bad_keywords(kwargs, [drift_check]), maze_ok(rows))
