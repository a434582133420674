"""The model builders (gym_gridloc/models.py): colour_grid_model, windy_maze_model and
ring_sensor_model build the documented models, check their arguments, and build at 512 x 512 with
stencil-sized structures only."""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import pytest

from gym_gridloc import (
    ColourSensor,
    ForwardFilter,
    RingSensor,
    WallSensor,
    colour_grid_model,
    ring_sensor_model,
    windy_maze_model,
)
from gym_gridloc.engine import transition_matrix
from gym_gridloc.generators import colour_map, maze_map
from gym_gridloc.seeds import COLOUR_GRID_LAYOUT, WINDY_MAZE_LAYOUT
from tests.helpers import arrays_of


def test_the_builders_make_the_documented_models():
    colour = colour_grid_model()
    assert colour.grid.to_text(",") == list(COLOUR_GRID_LAYOUT) and colour.grid.n_free == 19
    assert isinstance(colour.sensor, ColourSensor) and colour.name == "ColourGrid"
    assert colour.params == {"slip": 0.1, "accuracy": 0.88} and colour.n_layers == 1 and colour.n_actions == 4
    # Under action a: 1 - slip to the a-neighbour plus slip/4 for each direction (blocked: stay).
    assert dict(colour.outcomes((0, 1, 2), 3)) == pytest.approx({(0, 1, 1): 0.925, (0, 0, 2): 0.025, (0, 1, 3): 0.025, (0, 2, 2): 0.025})
    assert dict(colour.outcomes((0, 1, 1), 3)) == pytest.approx({(0, 1, 1): 0.95, (0, 0, 1): 0.025, (0, 1, 2): 0.025})  # W and S blocked
    maze = windy_maze_model()
    assert maze.grid.to_text() == list(WINDY_MAZE_LAYOUT) and maze.grid.n_free == 31
    assert isinstance(maze.sensor, WallSensor) and maze.action_names == ("N", "E", "S", "W")
    # Action N from (5, 0): 0.8 north, 0.1 west (the edge: stay), 0.1 east.
    assert dict(maze.outcomes((0, 5, 0), 0)) == pytest.approx({(0, 4, 0): 0.8, (0, 5, 0): 0.1, (0, 5, 1): 0.1})
    ring = ring_sensor_model()
    assert ring.shape == (8, 8) and ring.n_layers == 1 and isinstance(ring.sensor, RingSensor)
    assert ring.params["dynamics"] == "commanded" and ring.sensor.n_readings == 65
    passive = ring_sensor_model((5, 6), dynamics="passive")
    assert passive.n_layers == 4 and passive.n_states == 4 * 30 and passive.belief_shape == (4, 5, 6)
    # The passive robot ignores the action: every action has the same transition.
    for a in range(1, 4):
        assert (transition_matrix(passive, a) != transition_matrix(passive, 0)).nnz == 0


def test_seed_dynamics_is_a_deprecated_alias_of_passive():
    with pytest.warns(DeprecationWarning, match=r'dynamics="seed" is deprecated: use dynamics="passive"'):
        old = ring_sensor_model((4, 5), dynamics="seed", keep_heading=0.6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        new = ring_sensor_model((4, 5), dynamics="passive", keep_heading=0.6)
    assert old.params == new.params and old.params["dynamics"] == "passive"
    assert old.n_layers == new.n_layers == 4
    for a in [*range(4), None]:
        assert (transition_matrix(old, a) != transition_matrix(new, a)).nnz == 0
    with pytest.warns(DeprecationWarning, match="deprecated"):
        env = gym.make("RingSensor8x8-v0", dynamics="seed")
    assert env.unwrapped.model.params["dynamics"] == "passive" and env.unwrapped.model.n_layers == 4


def test_unknown_dynamics():
    with pytest.raises(ValueError, match=r"^dynamics must be one of 'commanded', 'passive'; got 'foo'"):
        gym.make("RingSensor8x8-v0", dynamics="foo")


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


def test_combined_probabilities_checked():
    with pytest.raises(ValueError, match=r"p_true \+ 8 p_ring1 \+ 16 p_ring2 must be at most 1, got 1\.7"):
        gym.make("RingSensor8x8-v0", p_true=0.5, p_ring1=0.1)
    with pytest.raises(ValueError, match=r"drift must be in \[0, 0\.5\].*got 0\.6"):
        gym.make("WindyMaze-v0", drift=0.6)


def test_every_model_builds_at_512x512_with_stencil_sized_structures():
    cells = 512 * 512
    for model in (
        colour_grid_model(colour_map((512, 512), seed=0)),
        windy_maze_model(maze_map((512, 512), seed=0)),
        ring_sensor_model((512, 512), dynamics="passive"),
    ):
        # A transition term is one (H, W) weight array: never S x S.
        for terms in model.transitions:
            assert all(t.weight.shape == (512, 512) for t in terms)
            assert len(terms) <= 5 * model.n_layers
        assert max(a.size for a in arrays_of(model.sensor)) <= 16 * cells
        f = ForwardFilter(model).reset(model.sensor.to_observation(0))
        f.step(0, model.sensor.to_observation(1))
        assert abs(f.full_belief.sum() - 1.0) < 1e-9
