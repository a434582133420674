"""Rendering (gym_gridloc/rendering.py): the ANSI table and the RGB frame of a rendering.Frame, drawn
from the model, a position belief, the true state, the last reading and action (the environments'
render modes: tests/envs/test_registry.py)."""

from __future__ import annotations

import numpy as np
import pytest

from gym_gridloc import (
    colour_grid_model,
    rendering,
    ring_sensor_model,
    windy_maze_model,
)


def random_position_belief(model, seed: int = 0) -> np.ndarray:
    b = np.where(model.grid.free, np.random.default_rng(seed).random(model.shape), 0.0)
    return b / b.sum()


def tile(model) -> int:
    return int(max(1, min(32, 512 // max(model.shape))))


def test_ansi_is_the_belief_in_percent_with_the_truth_marked():
    model = windy_maze_model()
    belief = random_position_belief(model)
    frame = rendering.Frame(model, belief, (0, 2, 3), reading=9, action=1)
    text = rendering.ansi(frame)
    lines = text.rstrip("\n").splitlines()
    assert lines[0] == f"WindyMaze 6x7  action: E  reading: {model.sensor.describe(9)}"
    assert lines[1] == "position belief (%), * = true position"
    table = lines[2:]
    assert len(table) == 6
    for r, line in enumerate(table):
        cells = line.split()
        assert len(cells) == 7
        for c, cell in enumerate(cells):
            if not model.grid.free[r, c]:
                assert cell == "####"
            else:
                assert cell.endswith("*") == ((r, c) == (2, 3))
                assert float(cell.rstrip("*")) == pytest.approx(100 * belief[r, c], abs=0.005)
    # Without a state, reading or action: no mark, a bare header.
    bare = rendering.ansi(rendering.Frame(model, belief, None))
    assert "*" not in bare.splitlines()[2] and bare.splitlines()[0] == "WindyMaze 6x7"


def test_belief_table_formats_like_the_seed_tables():
    free = np.array([[True, False], [True, True]])
    text = rendering.belief_table(np.array([[0.25, 0.0], [0.5, 0.25]]), free, mark=(1, 0))
    assert text.splitlines() == ["  25.00    ####", " 50.00*   25.00"]


@pytest.mark.parametrize("make", [colour_grid_model, windy_maze_model, lambda: ring_sensor_model((6, 9))],
                         ids=["colour", "windy", "ring"])
def test_rgb_frame_draws_cells_belief_truth_and_reading(make):
    model = make()
    belief = random_position_belief(model, 3)
    state = model.state_of_index(model.n_states // 2)
    img = rendering.rgb_frame(rendering.Frame(model, belief, state, reading=1, action=0))
    t = tile(model)
    h, w = model.shape
    assert img.dtype == np.uint8 and img.flags.c_contiguous
    assert img.shape == (h * t + max(6, t), w * t, 3)
    # The true position: the dot's colour at the centre of its tile.
    _, r, c = state
    assert tuple(img[r * t + t // 2, c * t + t // 2]) == rendering.TRUTH_RGB
    # An obstacle tile is the obstacle colour (away from the grid lines).
    blocked = np.argwhere(~model.grid.free)
    for r, c in blocked[:3]:
        assert tuple(img[r * t + t // 2, c * t + t // 2]) == rendering.OBSTACLE_RGB
    # The most probable free cell is drawn darker (more belief colour) than the least probable one.
    probs = np.where(model.grid.free, belief, np.nan)
    hi = np.unravel_index(np.nanargmax(probs), probs.shape)
    lo = np.unravel_index(np.nanargmin(probs), probs.shape)
    if hi != (state[1], state[2]) and lo != (state[1], state[2]):
        def shade(rc):
            return int(img[rc[0] * t + 2, rc[1] * t + 2].astype(int).sum())

        assert shade(hi) < shade(lo)


def test_rgb_frame_strip_shows_the_reading():
    colour = colour_grid_model()
    img = rendering.rgb_frame(rendering.Frame(colour, colour.prior()[0], None, reading=3))
    t = tile(colour)
    assert tuple(img[-1, 0]) == rendering.COLOUR_RGB["Y"]  # reading 3 = Y
    assert img.shape[0] == 5 * t + max(6, t)
    maze = windy_maze_model()
    img = rendering.rgb_frame(rendering.Frame(maze, maze.prior()[0], None, reading=0b1010))  # W and E sensed
    q = img.shape[1] // 4
    bits = [tuple(img[-1, i * q + q // 2]) for i in range(4)]
    assert bits == [rendering.OBSTACLE_RGB, rendering.FREE_RGB, rendering.OBSTACLE_RGB, rendering.FREE_RGB]
    ring = ring_sensor_model((6, 9))
    t = tile(ring)
    cell = rendering.rgb_frame(rendering.Frame(ring, ring.prior()[0], None, reading=2 * 9 + 4))
    nothing = rendering.rgb_frame(rendering.Frame(ring, ring.prior()[0], None, reading=ring.sensor.nothing))
    assert tuple(cell[-1, 0]) == rendering.READING_RGB and tuple(nothing[-1, 0]) == rendering.FREE_RGB
    # The reported cell (2, 4) is outlined.
    assert tuple(cell[2 * t + 1, 4 * t + t // 2]) == rendering.READING_RGB
    assert tuple(nothing[2 * t + 1, 4 * t + t // 2]) != rendering.READING_RGB


def test_large_maps_get_small_tiles():
    model = ring_sensor_model((512, 300))
    img = rendering.rgb_frame(rendering.Frame(model, model.prior()[0], (0, 5, 7)))
    assert tile(model) == 1 and img.shape == (512 + 6, 300, 3)


def test_absolute_shading_draws_a_sure_cell_in_its_own_colour_and_half_a_belief_half():
    """``Frame(shading="absolute")``: opacity = probability over white, in the cell's map colour
    (navy on a map without colours); the default (relative) picture is unchanged."""
    import gymnasium as gym

    from gym_gridloc import rendering

    for env_id in ("ColourGrid-v0", "WindyMaze-v0"):
        env = gym.make(env_id).unwrapped
        env.reset(seed=0)
        model = env.model
        free = list(zip(*np.nonzero(model.grid.free)))
        a, b, z = free[0], free[1], free[2]
        belief = np.zeros(model.shape)
        belief[a], belief[b] = 1.0, 0.0
        t = 20
        own = rendering.cell_colours(model)
        for pa, pb in ((1.0, 0.0), (0.5, 0.5)):
            belief[a], belief[b] = pa, pb
            img = rendering.rgb_frame(rendering.Frame(model, belief, None, tile=t, shading="absolute"))
            for cell, p in ((a, pa), (b, pb), (z, 0.0)):
                got = img[cell[0] * t + 3, cell[1] * t + t // 2]
                assert np.allclose(got, (1 - p) * 255 + p * own[cell], atol=1.01), (env_id, cell, p)
        if env_id == "ColourGrid-v0":
            sym = model.grid.symbols[model.grid.labels[a]]
            assert tuple(own[a]) == rendering.COLOUR_RGB[sym]
        else:
            assert np.array_equal(own[a], rendering.BELIEF_RGB)
        relative = rendering.rgb_frame(rendering.Frame(model, belief, None, tile=t))
        assert not np.array_equal(relative, img)
    with pytest.raises(ValueError, match="shading"):
        rendering.rgb_frame(rendering.Frame(model, belief, None, shading="bright"))


def test_a_frame_with_headings_draws_the_true_heading_and_the_beliefs_headings():
    """A DepthMaze frame: the truth as an orange triangle pointing along its heading, a white
    triangle at a cell's side for each heading the belief gives that cell (opacity: its
    probability given the cell), none for a heading of probability 0."""
    from gym_gridloc import depth_maze_model

    model = depth_maze_model(["#######", "#OOOOO#", "#O###O#", "#OOOOO#", "#######"])
    t = 32
    along = {0: (-1, 0), 1: (0, 1), 2: (1, 0), 3: (0, -1)}

    def at(img, r, c, h, d):  # the pixel d half-cells from (r, c)'s centre along heading h
        dy, dx = along[h]
        return tuple(img[int(r * t + t / 2 + dy * d * t / 2), int(c * t + t / 2 + dx * d * t / 2)])

    for h in range(4):
        belief = np.zeros(model.belief_shape)
        belief[h, 1, 2] = 0.5
        belief[(h + 1) % 4, 1, 2] = 0.5
        belief[h, 3, 4] = 1.0
        belief /= belief.sum()
        img = rendering.rgb_frame(rendering.Frame(model, belief.sum(axis=0), (h, 3, 2), heading=True, tile=t,
                                                  headings=belief))
        assert at(img, 3, 2, h, 0.6) == rendering.TRUTH_RGB and at(img, 3, 2, (h + 2) % 4, 0.6) != rendering.TRUTH_RGB
        assert at(img, 3, 4, h, 0.75) == rendering.HEADING_RGB  # sure: fully white
        assert all(at(img, 3, 4, k, 0.75) != rendering.HEADING_RGB for k in range(4) if k != h)
        half = [at(img, 1, 2, k, 0.75) for k in range(4)]
        cell = np.array(img[1 * t + 4, 2 * t + 4], dtype=float)  # the cell's shade, off the marks
        for k in (h, (h + 1) % 4):  # half white over the shade
            assert np.allclose(half[k], 0.5 * cell + 0.5 * np.array(rendering.HEADING_RGB), atol=1.01)
        for k in ((h + 2) % 4, (h + 3) % 4):
            assert np.allclose(half[k], cell, atol=1.01)
        plain = rendering.rgb_frame(rendering.Frame(model, belief.sum(axis=0), (h, 3, 2), heading=True, tile=t))
        assert at(plain, 3, 4, h, 0.75) != rendering.HEADING_RGB  # headings=None: no marks
        thin = belief.copy()
        thin[h, 1, 1] = 0.02  # a light cell under absolute shading: the mark in navy, not white
        img = rendering.rgb_frame(rendering.Frame(model, thin.sum(axis=0), None, heading=True, tile=t, headings=thin,
                                                  shading="absolute"))
        assert at(img, 1, 1, h, 0.75) == rendering.HEADING_ON_LIGHT_RGB and at(img, 3, 4, h, 0.75) == rendering.HEADING_RGB


@pytest.mark.parametrize("depth", [1, 2, 4])
def test_the_strip_of_a_depth_reading_shows_the_free_cells_ahead_then_the_wall(depth):
    from gym_gridloc import depth_maze_model

    model = depth_maze_model(["#######", "#OOOOO#", "#O###O#", "#OOOOO#", "#######"])
    t = 32
    img = rendering.rgb_frame(rendering.Frame(model, model.prior()[0], None, reading=depth, tile=t))
    assert img.shape == (5 * t + t, 7 * t, 3)
    strip = img[5 * t :]
    mid = t // 2
    assert tuple(strip[mid, mid]) == rendering.VIEWPOINT_RGB  # the robot's cell, looking along the row
    for i in range(1, depth):
        assert tuple(strip[mid, i * t + mid]) == rendering.FREE_RGB
    assert tuple(strip[mid, depth * t + mid]) == rendering.OBSTACLE_RGB
    assert tuple(strip[mid, (depth + 1) * t + mid]) == (255, 255, 255)


def test_env_frames_draw_headings_and_take_the_shading_keyword():
    """``render_shading`` (``"relative"`` by default, or ``"absolute"``) reaches the frame; a
    DepthMaze frame draws the true heading, the belief's headings and the depth read."""
    import gymnasium as gym

    env = gym.make("DepthMaze-v0", render_mode="rgb_array").unwrapped
    env.reset(seed=4)
    env.step(2)
    frame = rendering.Frame(env.model, env.posterior, env.state, env.last_reading, 2, heading=True,
                            headings=env.exact_filter.full_belief)
    assert np.array_equal(env.render(), rendering.rgb_frame(frame))
    for env_id in ("ColourGrid-v0", "WindyMaze-v0", "RingSensor8x8-v0", "DepthMaze-v0"):
        for shading in ("relative", "absolute"):
            env = gym.make(env_id, render_mode="rgb_array", render_shading=shading).unwrapped
            env.reset(seed=1)
            heading = env.model.n_layers == 4
            want = rendering.rgb_frame(rendering.Frame(env.model, env.posterior, env.state, env.last_reading, None,
                                                       heading=heading, shading=shading,
                                                       headings=env.exact_filter.full_belief if heading else None))
            assert np.array_equal(env.render(), want), (env_id, shading)
        with pytest.raises(ValueError, match="render_shading"):
            gym.make(env_id, render_shading="bright")
