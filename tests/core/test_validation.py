"""Parameter checks (gym_gridloc/core/validation.py): each error names the parameter, the value and
what is allowed, wherever the parameter enters (a builder, a registered environment)."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

from gym_gridloc import ring_sensor_model
from gym_gridloc.core.validation import (
    check_choice,
    check_int,
    check_probability,
    check_size,
    check_threshold,
)


def test_check_probability():
    assert check_probability("p", 0) == 0.0 and check_probability("p", 1) == 1.0
    assert check_probability("p", np.float32(0.25)) == 0.25
    assert type(check_probability("p", np.float64(0.5))) is float
    for bad in (-1e-9, 1 + 1e-9, math.nan, math.inf):
        with pytest.raises(ValueError, match=rf"^p must be a probability in \[0, 1\], got {bad!r}"):
            check_probability("p", bad)
    for bad in (True, "0.5", None, [0.5]):
        with pytest.raises(TypeError, match=r"^p must be a probability \(a number in \[0, 1\]\)"):
            check_probability("p", bad)


def test_check_threshold():
    assert check_threshold("t", 1) == 1.0 and check_threshold("t", 1e-9) == 1e-9
    for bad in (0, 0.0, -0.1, 1.5, math.nan, math.inf):
        with pytest.raises(ValueError, match=r"^t must be in \(0, 1\]"):
            check_threshold("t", bad)
    with pytest.raises(TypeError, match=r"^t must be a number in \(0, 1\], got 'high'"):
        check_threshold("t", "high")


def test_check_int_and_choice():
    assert check_int("n", np.int64(3)) == 3
    with pytest.raises(ValueError, match=r"^n must be at least 1, got 0"):
        check_int("n", 0)
    with pytest.raises(ValueError, match=r"^n must be at least 0 and at most 5, got 6"):
        check_int("n", 6, 0, 5)
    for bad in (True, 1.0, "1"):
        with pytest.raises(TypeError, match=r"^n must be an integer"):
            check_int("n", bad)
    assert check_choice("mode", "a", ("a", "b")) == "a"
    with pytest.raises(ValueError, match=r"^mode must be one of 'a', 'b'; got 'c'"):
        check_choice("mode", "c", ("a", "b"))


@pytest.mark.parametrize(
    "size,message",
    [
        ((0, 5), r"size\[0\] \(rows\) must be at least 1.*got 0"),
        ((5, 0), r"size\[1\] \(columns\) must be at least 1.*got 0"),
        (-1, r"size\[0\] \(rows\) must be at least 1.*got -1"),
        (0, r"size\[0\] \(rows\) must be at least 1.*got 0"),
        ((3, -2), r"size\[1\] \(columns\) must be at least 1.*got -2"),
    ],
)
def test_grid_size_below_one(size, message):
    with pytest.raises(ValueError, match=message):
        gym.make("RingSensor8x8-v0", size=size)
    with pytest.raises(ValueError, match=message):
        ring_sensor_model(size)
    with pytest.raises(ValueError, match=message):
        check_size("size", size)


@pytest.mark.parametrize(
    "size,message",
    [
        ((1.5, 2), r"size\[0\] \(rows\) must be an integer, got 1\.5"),
        ("ab", r"size must be a pair \(H, W\) of integers, got 'ab'"),
        ((2, 2, 2), r"size must be a pair \(H, W\) of integers"),
        (None, r"size must be a pair \(H, W\) of integers, got None"),
    ],
)
def test_grid_size_of_the_wrong_type(size, message):
    with pytest.raises(TypeError, match=message):
        gym.make("RingSensor8x8-v0", size=size)


def test_grid_size_forms():
    assert check_size("size", 4) == (4, 4)
    assert check_size("size", (2, np.int64(3))) == (2, 3)
    assert check_size("size", [5, 1]) == (5, 1)
    with pytest.raises(ValueError, match=r"size\[0\] \(rows\) must be at least 1 and at most 4096, got 5000"):
        check_size("size", (5000, 2))
