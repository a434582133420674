"""ColourGrid-v0 (gym_gridloc/envs/colour_grid.py): any map text and keyword arguments either build
a working environment or raise an error naming what is wrong (hypothesis, with an independent
oracle of validity)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import gymnasium as gym
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gym_gridloc import ColourGridEnv
from tests.helpers import PROPERTY_SETTINGS, bad_keywords, exercise, kwargs_for

COLOUR_CELLS = ["R", "G", "B", "Y", "."]
ODD_CELLS = ["X", "", " R", "G ", "r", "RR", "\t", "é", "O", "#"]


@st.composite
def colour_rows(draw):
    """Rows of comma-separated cells: mostly rectangular and valid, sometimes ragged or odd."""
    clean = draw(st.integers(0, 3)) > 0  # only valid symbols 3 times in 4
    cell = st.sampled_from(COLOUR_CELLS) if clean else st.one_of(st.sampled_from(COLOUR_CELLS), st.sampled_from(ODD_CELLS))
    if draw(st.integers(0, 3)) > 0:  # rectangular
        h, w = draw(st.integers(1, 5)), draw(st.integers(1, 5))
        cells = [[draw(cell) for _ in range(w)] for _ in range(h)]
    else:
        cells = draw(st.lists(st.lists(cell, max_size=5), max_size=5))
    return [",".join(r) for r in cells]


def colour_map_ok(rows: list[str]) -> bool:
    if not rows:
        return False
    split = [[c.strip() for c in r.split(",")] for r in rows]
    if any(r == "" for r in rows) or len({len(s) for s in split}) != 1:
        return False
    if any(c not in COLOUR_CELLS for s in split for c in s):
        return False
    return any(c != "." for s in split for c in s)


@PROPERTY_SETTINGS
@given(rows=colour_rows(), kwargs=kwargs_for(ColourGridEnv), as_file=st.booleans())
def test_colour_grid_any_input(rows, kwargs, as_file):
    if as_file:
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "map.csv"
            path.write_text("\n".join(rows) + "\n", encoding="utf-8")
            # A file's trailing blank lines are not rows.
            trimmed = list(rows)
            while trimmed and not trimmed[-1].strip():
                trimmed.pop()
            ok = colour_map_ok(trimmed) and "\r" not in "".join(rows)
            exercise(lambda: gym.make("ColourGrid-v0", layout=str(path), **kwargs), bad_keywords(kwargs), ok, str(path))
    else:
        exercise(lambda: gym.make("ColourGrid-v0", layout=rows, **kwargs), bad_keywords(kwargs), colour_map_ok(rows))


def test_unknown_keyword():
    with pytest.raises(TypeError, match=r"unexpected keyword argument 'slipp'"):
        gym.make("ColourGrid-v0", slipp=0.2)
