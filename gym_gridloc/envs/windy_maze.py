from __future__ import annotations

import functools

import numpy as np

from gym_gridloc.envs.base import GridLocEnv, MapFactory
from gym_gridloc.generators import maze_map
from gym_gridloc.models import windy_maze_model
from gym_gridloc.referee import LOCALISE_THRESHOLD


def _build(grid, *, drift, p_detect, p_false_alarm, kidnap_prob):
    return windy_maze_model(grid, drift=drift, p_detect=p_detect, p_false_alarm=p_false_alarm).with_kidnapping(kidnap_prob)


def _draw(rng, *, size):
    return maze_map(size, seed=rng)


class WindyMazeEnv(GridLocEnv):
    """A robot in a windy maze senses obstacles in the four directions (seed 004).

    ## Description
    The robot sits on an unknown free cell of a maze.  Wind makes it drift sideways; four noisy
    bits tell it whether an obstacle lies west, north, east or south.  The goal is to localise.

    ## Action Space
    ``Discrete(4)``: 0 = N, 1 = E, 2 = S, 3 = W.  The robot reaches the neighbour in that direction
    with ``1 - 2 drift`` (0.8) and the neighbour on the action's left or right with ``drift`` (0.1)
    each; a blocked target means staying in place.

    ## Observation Space
    ``MultiBinary(4)``: bits in the order (W, N, E, S), 1 = "obstacle sensed".  An obstacle (or the
    edge) is sensed with ``p_detect`` (0.85), a free neighbour with ``p_false_alarm`` (0.10),
    independently.

    ## Starting State
    Uniform over the free cells; the first observation is a reading at the start.

    ## Rewards
    -1 per step.

    ## Episode End
    Terminated when the largest posterior probability of a position reaches
    ``localise_threshold``; truncated at ``max_episode_steps`` (100 for ``WindyMaze-v0``).

    ## Arguments
    ``layout``: a path to a maze file or a list of rows of ``O`` (free) and ``#`` (obstacle)
    (default: seed 004's 6x7 maze, 31 free cells).  ``drift`` (0.1), ``p_detect`` (0.85),
    ``p_false_alarm`` (0.10), ``localise_threshold`` (0.9), ``kidnap_prob`` (0.0: after every move the
    robot is teleported to a uniformly chosen free cell with this probability), ``render_mode``,
    ``render_shading`` (``"relative"`` or ``"absolute"``, see :class:`~gym_gridloc.GridLocEnv`).

    Generated mazes (in place of ``layout``): ``size`` ((H, W); (7, 7) when only other generator
    options are given; corridors one cell wide, walls between, every free cell reachable),
    ``map_seed`` (0: the same seed gives the same maze) and ``new_map_each_reset`` (False; True:
    a new maze at every reset from the environment's ``np_random``, so the same reset seed gives
    the same maze).  See :func:`gym_gridloc.generators.maze_map`.

    ## Vector Environments
    ``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")`` (the native
    :class:`~gym_gridloc.GridLocVectorEnv`) observes the reading and the exact belief, as
    :class:`~gym_gridloc.HMMBeliefWrapper` does; ``"sync"`` and ``"async"`` vectorize this class, whose
    observation is the reading alone.  To make them agree: ``wrappers=[HMMBeliefWrapper]`` for
    ``"sync"``/``"async"``, or ``belief=None`` (a keyword of ``make_vec``) for the native one.

    ## Version History
    * v0: initial version.
    """

    def __init__(self, layout=None, *, drift: float = 0.1, p_detect: float = 0.85, p_false_alarm: float = 0.10,
                 localise_threshold: float = LOCALISE_THRESHOLD, kidnap_prob: float = 0.0,
                 render_mode: str | None = None, size=None, map_seed: int | None = None,
                 new_map_each_reset: bool = False, render_shading: str = "relative") -> None:
        generated = new_map_each_reset or size is not None or map_seed is not None
        if generated and layout is not None:
            raise ValueError("give either layout=... or a generated maze (size, map_seed, new_map_each_reset), not both")
        if not isinstance(new_map_each_reset, (bool, np.bool_)):
            raise TypeError(f"new_map_each_reset must be True or False, got {new_map_each_reset!r}")
        new_map_each_reset = bool(new_map_each_reset)

        # Module-level functions bound with partial: the environment pickles with them.
        build = functools.partial(_build, drift=drift, p_detect=p_detect, p_false_alarm=p_false_alarm,
                                  kidnap_prob=kidnap_prob)
        draw = functools.partial(_draw, size=(7, 7) if size is None else size)

        grid = draw(0 if map_seed is None else map_seed) if generated else layout
        super().__init__(build(grid), localise_threshold=localise_threshold, render_mode=render_mode, builder=build,
                         map_factory=MapFactory(build, draw) if new_map_each_reset else None, render_shading=render_shading)
