from __future__ import annotations

import functools

import numpy as np

from gym_gridloc.envs.base import GridLocEnv, MapFactory
from gym_gridloc.generators import colour_map
from gym_gridloc.models import colour_grid_model
from gym_gridloc.referee import LOCALISE_THRESHOLD


def _build(grid, *, slip, accuracy, kidnap_prob):
    return colour_grid_model(grid, slip=slip, accuracy=accuracy).with_kidnapping(kidnap_prob)


def _draw(rng, *, size, obstacle_density, n_colours):
    return colour_map(size, obstacle_density=obstacle_density, n_colours=n_colours, seed=rng)


class ColourGridEnv(GridLocEnv):
    """A robot on a coloured grid reads the colour beneath it (seed 000, Shu 2014).

    ## Description
    The robot sits on an unknown free cell of a map whose cells are coloured R, G, B or Y (or are
    obstacles).  It moves with noise and reads the colour of its cell with a noisy sensor.  The
    goal is to localise: to make the exact posterior over positions confident.

    ## Action Space
    ``Discrete(4)``: 0 = N (row-1), 1 = E (col+1), 2 = S (row+1), 3 = W (col-1).  With probability
    ``1 - slip`` the robot moves one cell that way, with probability ``slip`` one cell in a uniformly
    random direction of the four; a move into an obstacle or off the grid leaves it in place.

    ## Observation Space
    ``Discrete(4)``: the colour read, an index into ``R, G, B, Y``.  The true colour is read with
    probability ``accuracy`` (0.88), each wrong colour with ``(1 - accuracy) / 3`` (0.04).

    ## Starting State
    Uniform over the free cells; the first observation is a reading at the start.

    ## Rewards
    -1 per step.

    ## Episode End
    Terminated when the largest posterior probability of a position reaches
    ``localise_threshold``; truncated at ``max_episode_steps`` (100 for ``ColourGrid-v0``).

    ## Arguments
    ``layout``: a path to a map file or a list of comma-separated rows (default: seed 000's 5x5
    map ``R,G,B,Y,B / .,R,R,G,G / .,.,B,.,Y / Y,Y,B,.,R / B,G,G,.,Y``).  ``slip`` (0.1; 1.0 is the
    seed's random walk), ``accuracy`` (0.88), ``localise_threshold`` (0.9), ``kidnap_prob`` (0.0: after every move the
    robot is teleported to a uniformly chosen free cell with this probability), ``render_mode``
    (``"ansi"``, ``"rgb_array"``, ``"human"``), ``render_shading`` (``"relative"``, the default:
    the pastel map colours darkened towards navy by the belief relative to its peak, which shows a
    belief spread thin but can be mistaken for a blue cell; ``"absolute"``: each cell in its own map
    colour with opacity equal to its probability, as ``gridloc view`` draws it; see
    :class:`~gym_gridloc.GridLocEnv`).

    Generated maps (in place of ``layout``): ``size`` ((H, W); (5, 5) when only other generator
    options are given), ``obstacle_density`` (0.2: each cell an obstacle with this probability;
    free cells cut off from the largest free region become obstacles too, so the free cells are
    connected), ``n_colours`` (4: ``R, G, B, Y``, then further letters; the observation space is
    ``Discrete(n_colours)``), ``map_seed`` (0: the same seed gives the same map), and
    ``new_map_each_reset`` (False: one fixed map; True: a new map at every reset, drawn from the
    environment's ``np_random``, so the same reset seed gives the same map).  See
    :func:`gym_gridloc.generators.colour_map`.

    ## Vector Environments
    ``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")`` (the native
    :class:`~gym_gridloc.GridLocVectorEnv`) observes the reading and the exact belief, as
    :class:`~gym_gridloc.HMMBeliefWrapper` does; ``"sync"`` and ``"async"`` vectorize this class, whose
    observation is the reading alone.  To make them agree: ``wrappers=[HMMBeliefWrapper]`` for
    ``"sync"``/``"async"``, or ``belief=None`` (a keyword of ``make_vec``) for the native one.

    ## Version History
    * v0: initial version.
    """

    def __init__(self, layout=None, *, slip: float = 0.1, accuracy: float = 0.88,
                 localise_threshold: float = LOCALISE_THRESHOLD, kidnap_prob: float = 0.0,
                 render_mode: str | None = None, size=None, obstacle_density: float | None = None,
                 n_colours: int | None = None, map_seed: int | None = None,
                 new_map_each_reset: bool = False, render_shading: str = "relative") -> None:
        options = {"size": size, "obstacle_density": obstacle_density, "n_colours": n_colours, "map_seed": map_seed}
        generated = new_map_each_reset or any(v is not None for v in options.values())
        if generated and layout is not None:
            given = [k for k, v in options.items() if v is not None] or ["new_map_each_reset"]
            raise ValueError(f"give either layout=... or a generated map ({', '.join(given)}), not both")
        if not isinstance(new_map_each_reset, (bool, np.bool_)):
            raise TypeError(f"new_map_each_reset must be True or False, got {new_map_each_reset!r}")
        new_map_each_reset = bool(new_map_each_reset)

        # Module-level functions bound with partial: the environment pickles with them.
        build = functools.partial(_build, slip=slip, accuracy=accuracy, kidnap_prob=kidnap_prob)
        draw = functools.partial(_draw, size=(5, 5) if size is None else size,
                                 obstacle_density=0.2 if obstacle_density is None else obstacle_density,
                                 n_colours=4 if n_colours is None else n_colours)

        grid = draw(0 if map_seed is None else map_seed) if generated else layout
        super().__init__(build(grid), localise_threshold=localise_threshold, render_mode=render_mode, builder=build,
                         map_factory=MapFactory(build, draw) if new_map_each_reset else None, render_shading=render_shading)
