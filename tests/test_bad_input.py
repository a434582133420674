"""Bad input (SPEC section 7): every case gives an error that names what is wrong."""

from __future__ import annotations

import inspect
import math
import re

import gymnasium as gym
import numpy as np
import pytest

import gym_gridloc
from gym_gridloc import (
    ColourGridEnv,
    GridModel,
    HMMBeliefWrapper,
    MapError,
    RingSensorEnv,
    WindyMazeEnv,
    colour_grid_model,
    parse_colour_map,
    parse_maze,
    ring_sensor_model,
    windy_maze_model,
)

ENV_IDS = list(gym_gridloc.ENV_IDS)
ENV_CLASS = {"ColourGrid-v0": ColourGridEnv, "RingSensor8x8-v0": RingSensorEnv, "WindyMaze-v0": WindyMazeEnv}
NOT_PROBABILITIES = {"localise_threshold", "render_mode", "layout", "size", "dynamics"}


def probability_kwargs():
    """(env id, keyword) for every probability keyword of every registered environment: the
    float-valued keywords with a default in [0, 1] (so a new one is tested automatically)."""
    out = []
    for env_id in ENV_IDS:
        for name, p in inspect.signature(ENV_CLASS[env_id].__init__).parameters.items():
            if name in NOT_PROBABILITIES or not isinstance(p.default, float):
                continue
            assert 0.0 <= p.default <= 1.0, (env_id, name)
            out.append((env_id, name))
    return out


PROB_KWARGS = probability_kwargs()


def test_probability_keywords_are_found():
    names = {n for _, n in PROB_KWARGS}
    assert {"slip", "accuracy", "keep_heading", "p_true", "p_ring1", "p_ring2", "drift", "p_detect",
            "p_false_alarm"} <= names


# -- maps --------------------------------------------------------------------------------------
def test_ragged_rows_in_a_list():
    with pytest.raises(MapError, match=r"<layout>, line 2: ragged row: 1 cells where line 1 has 2"):
        gym.make("ColourGrid-v0", layout=["R,G", "R"])
    with pytest.raises(MapError, match=r"<layout>, line 3: ragged row"):
        WindyMazeEnv(layout=["OOO", "OOO", "OOOO"])


def test_ragged_rows_in_a_file_name_file_and_line(tmp_path):
    path = tmp_path / "ragged.txt"
    path.write_text("OOOO\nO#OO\nOOO\n")
    with pytest.raises(MapError, match=rf"{re.escape(str(path))}, line 3: ragged row: 3 cells where line 1 has 4"):
        gym.make("WindyMaze-v0", layout=str(path))


def test_unknown_symbol_names_line_and_column():
    with pytest.raises(MapError, match=r"line 2, column 3: unknown symbol 'X' \(allowed: 'R', 'G', 'B', 'Y', '\.'\)"):
        gym.make("ColourGrid-v0", layout=["R,G", "R,X"])
    with pytest.raises(MapError, match=r"line 1, column 4: unknown symbol 'x' \(allowed: 'O', '#'\)"):
        WindyMazeEnv(layout=["OO#x", "OOOO"])


def test_unknown_symbol_in_a_file_names_path_line_and_column(tmp_path):
    colour = tmp_path / "colours.csv"
    colour.write_text("R,G,B\nY, R,.\nB,Q,G\n")
    with pytest.raises(MapError, match=rf"^{re.escape(str(colour))}, line 3, column 3: unknown symbol 'Q'"):
        parse_colour_map(colour)
    with pytest.raises(MapError, match=rf"^{re.escape(str(colour))}, line 3, column 3: unknown symbol 'Q'"):
        gym.make("ColourGrid-v0", layout=str(colour))
    maze = tmp_path / "maze.txt"
    maze.write_text("OOOO\nO#O*\n")
    with pytest.raises(MapError, match=rf"^{re.escape(str(maze))}, line 2, column 4: unknown symbol '\*'"):
        gym.make("WindyMaze-v0", layout=maze)


def test_map_from_a_good_file(tmp_path):
    maze = tmp_path / "maze.txt"
    maze.write_text("OO#\nOOO\n")
    env = gym.make("WindyMaze-v0", layout=str(maze))
    assert env.unwrapped.model.grid.n_free == 5
    assert maze.read_text() == "OO#\nOOO\n"  # nothing is written over


@pytest.mark.parametrize(
    "make",
    [
        lambda: gym.make("ColourGrid-v0", layout=[".,.", ".,."]),
        lambda: gym.make("WindyMaze-v0", layout=["##", "##"]),
        lambda: parse_maze(["#"]),
    ],
)
def test_no_free_cell(make):
    with pytest.raises(MapError, match=r"no free cell"):
        make()


def test_map_file_missing(tmp_path):
    missing = tmp_path / "nowhere" / "map.txt"
    with pytest.raises(MapError, match=rf"layout: no map file at '{re.escape(str(missing))}'"):
        gym.make("WindyMaze-v0", layout=str(missing))
    with pytest.raises(MapError, match=r"no map file at"):
        gym.make("ColourGrid-v0", layout=missing)


@pytest.mark.parametrize(
    "layout,message",
    [
        ([], r"the map is empty"),
        ("", r"layout: got an empty string"),
        ("OOO\nOOO", r"layout: got a multi-line string"),
        (["OOO", ""], r"<layout>, line 2: empty row"),
        (42, r"layout must be a path to a map file or a list of row strings, got int"),
        (["OOO", 5], r"layout: row 2 must be a string, got int"),
    ],
)
def test_malformed_layouts(layout, message):
    with pytest.raises((MapError, TypeError), match=message):
        WindyMazeEnv(layout=layout)


def test_map_errors_are_value_errors():
    assert issubclass(MapError, ValueError)


# -- probabilities, threshold, sizes, options -------------------------------------------------
@pytest.mark.parametrize("value", [-0.1, 1.5, float("nan"), float("inf"), -1e-9, 1 + 1e-9])
@pytest.mark.parametrize("env_id,name", PROB_KWARGS, ids=[f"{e}-{n}" for e, n in PROB_KWARGS])
def test_probability_outside_unit_interval(env_id, name, value):
    with pytest.raises(ValueError, match=rf"^{name} must be (a probability )?in \[0, 1"):
        gym.make(env_id, **{name: value})


@pytest.mark.parametrize("value", ["0.5", None, True, [0.5]])
@pytest.mark.parametrize("env_id,name", PROB_KWARGS, ids=[f"{e}-{n}" for e, n in PROB_KWARGS])
def test_probability_of_the_wrong_type(env_id, name, value):
    with pytest.raises(TypeError, match=rf"^{name} must be a probability \(a number in \[0, 1\]\), got {re.escape(repr(value))}"):
        gym.make(env_id, **{name: value})


def test_combined_probabilities_checked():
    with pytest.raises(ValueError, match=r"p_true \+ 8 p_ring1 \+ 16 p_ring2 must be at most 1, got 1\.7"):
        gym.make("RingSensor8x8-v0", p_true=0.5, p_ring1=0.1)
    with pytest.raises(ValueError, match=r"drift must be in \[0, 0\.5\].*got 0\.6"):
        gym.make("WindyMaze-v0", drift=0.6)


@pytest.mark.parametrize("value", [0, 0.0, -0.1, 1.5, float("nan"), float("inf")])
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_localise_threshold_outside_open_closed_interval(env_id, value):
    with pytest.raises(ValueError, match=rf"^localise_threshold must be in \(0, 1\], got {re.escape(repr(value))}"):
        gym.make(env_id, localise_threshold=value)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_localise_threshold_of_the_wrong_type(env_id):
    with pytest.raises(TypeError, match=r"^localise_threshold must be a number in \(0, 1\], got 'high'"):
        gym.make(env_id, localise_threshold="high")


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


def test_unknown_dynamics():
    with pytest.raises(ValueError, match=r"^dynamics must be one of 'commanded', 'seed'; got 'foo'"):
        gym.make("RingSensor8x8-v0", dynamics="foo")


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_unknown_render_mode(env_id):
    with pytest.raises(ValueError, match=r"^render_mode must be one of \['ansi', 'rgb_array', 'human'\] or None, got 'foo'"):
        ENV_CLASS[env_id](render_mode="foo")


def test_unknown_on_impossible():
    with pytest.raises(ValueError, match=r"^on_impossible must be one of 'raise', 'reset'; got 'x'"):
        HMMBeliefWrapper(gym.make("WindyMaze-v0"), on_impossible="x")


def test_unknown_keyword():
    with pytest.raises(TypeError, match=r"unexpected keyword argument 'slipp'"):
        gym.make("ColourGrid-v0", slipp=0.2)


def test_unknown_reset_option():
    env = gym.make("WindyMaze-v0")
    with pytest.raises(ValueError, match=r"unknown reset option\(s\) \['start'\]"):
        env.reset(options={"start": (0, 0)})
    with pytest.raises(ValueError, match=r"reset option 'state' must name a free cell, got \(1, 2\)"):
        env.reset(options={"state": (1, 2)})  # an obstacle of the default maze


# -- actions and the order of calls ------------------------------------------------------------
def _makers(env_id):
    return {
        "unwrapped": lambda: gym.make(env_id).unwrapped,
        "made": lambda: gym.make(env_id),
        "wrapped": lambda: HMMBeliefWrapper(gym.make(env_id)),
        "wrapped-flat": lambda: HMMBeliefWrapper(gym.make(env_id).unwrapped, flatten=True),
    }


@pytest.mark.parametrize("kind", ["unwrapped", "made", "wrapped", "wrapped-flat"])
@pytest.mark.parametrize("action", [4, -1, 1.5, "a", None, np.array([1]), 2**40])
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_action_outside_the_action_space(env_id, action, kind):
    env = _makers(env_id)[kind]()
    env.reset(seed=0)
    belief_before = env.belief_array().copy() if isinstance(env, HMMBeliefWrapper) else None
    state_before = env.unwrapped.state
    with pytest.raises(ValueError, match=r"action .* is not in the action space Discrete\(4\) \(0=N, 1=E, 2=S, 3=W\)"):
        env.step(action)
    # Nothing changed: the robot did not move and the belief did not update.
    assert env.unwrapped.state == state_before
    if belief_before is not None:
        np.testing.assert_array_equal(env.belief_array(), belief_before)
    env.step(0)  # and the environment still works


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_numpy_integer_actions_are_accepted(env_id):
    env = gym.make(env_id)
    env.reset(seed=0)
    env.step(np.int64(2))
    env.step(np.array(3))


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_step_before_reset(env_id):
    with pytest.raises(RuntimeError, match=r"call reset\(\) before step\(\)"):
        gym.make(env_id).unwrapped.step(0)
    with pytest.raises(gym.error.ResetNeeded):  # gym.make's OrderEnforcing says it first
        gym.make(env_id).step(0)
    with pytest.raises(RuntimeError, match=r"reset"):
        HMMBeliefWrapper(gym.make(env_id).unwrapped).step(0)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_render_before_reset(env_id):
    env = ENV_CLASS[env_id](render_mode="ansi")
    with pytest.raises(RuntimeError, match=r"call reset\(\) before render\(\)"):
        env.render()


# -- the wrapper's own arguments ---------------------------------------------------------------
def test_wrapper_model_of_the_wrong_kind():
    with pytest.raises(TypeError, match=r"model must be a GridModel, got str"):
        HMMBeliefWrapper(gym.make("WindyMaze-v0"), model="windy")


def test_wrapper_model_with_another_observation_space():
    with pytest.raises(ValueError, match=r"the model's sensor emits Discrete\(4\) but the environment's observation space is MultiBinary\(4\)"):
        HMMBeliefWrapper(gym.make("WindyMaze-v0"), model=colour_grid_model())


def test_wrapper_model_with_another_number_of_actions():
    ring = ring_sensor_model((8, 8))
    two_actions = GridModel(ring.grid, ring.transitions[:2], ring.sensor)
    with pytest.raises(ValueError, match=r"the model has 2 actions but the environment's action space is Discrete\(4\)"):
        HMMBeliefWrapper(gym.make("RingSensor8x8-v0"), model=two_actions)


def test_wrapper_on_an_env_without_a_model():
    with pytest.raises(TypeError, match=r"no GridModel at env\.unwrapped\.model, so pass model="):
        HMMBeliefWrapper(gym.make("CartPole-v1"))


def test_wrapper_key_clash():
    env = HMMBeliefWrapper(gym.make("WindyMaze-v0"))
    with pytest.raises(ValueError, match=r"already has a key 'belief'"):
        HMMBeliefWrapper(env)
    assert "belief2" in HMMBeliefWrapper(env, key="belief2").observation_space.spaces


# -- models directly ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    "make,name",
    [
        (lambda v: colour_grid_model(slip=v), "slip"),
        (lambda v: colour_grid_model(accuracy=v), "accuracy"),
        (lambda v: windy_maze_model(p_detect=v), "p_detect"),
        (lambda v: ring_sensor_model(keep_heading=v), "keep_heading"),
    ],
)
def test_model_builders_check_their_arguments(make, name):
    with pytest.raises(ValueError, match=rf"^{name} must be a probability in \[0, 1\], got -0\.5"):
        make(-0.5)
    assert math.isclose(make(0.5).params.get(name, 0.5), 0.5)
