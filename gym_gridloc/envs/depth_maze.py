from __future__ import annotations

import functools

import numpy as np

from gym_gridloc.core.grid import GridMap
from gym_gridloc.core.validation import check_int
from gym_gridloc.envs.base import GridLocEnv, MapFactory
from gym_gridloc.generators import (MAZE_GENERATORS, perfect_maze, perfect_maze_codes, perfect_maze_graph, perfect_maze_of_code,
                                    random_maze)
from gym_gridloc.models import depth_maze_model, parse_maze
from gym_gridloc.referee import LOCALISE_THRESHOLD


def _build(grid, *, p_turn_fail, p_move_fail, p_depth_error, max_depth, kidnap_prob):
    return depth_maze_model(grid, p_turn_fail=p_turn_fail, p_move_fail=p_move_fail, p_depth_error=p_depth_error,
                            max_depth=max_depth).with_kidnapping(kidnap_prob)


def _draw(rng, *, size):
    return perfect_maze(size, seed=rng)


def _draw_maze(rng, *, size, generator, reject_symmetric):
    return random_maze(size, rng, generator=generator, reject_symmetric=reject_symmetric)


def map_options(env_kwargs: dict) -> dict:
    """How a DepthMaze with these keywords draws its mazes: ``{"generator": ..., "reject_symmetric": ...}``
    (the defaults resolved: mazes equal to their rotation are rejected under the research protocol,
    ``episode_length`` given).  The held-out sets of :mod:`gym_gridloc.maps` take the same options."""
    generator = env_kwargs.get("generator", "kruskal")
    if generator not in MAZE_GENERATORS:
        raise ValueError(f"generator must be one of {', '.join(map(repr, MAZE_GENERATORS))} (how perfect mazes are drawn), got {generator!r}")
    reject = env_kwargs.get("reject_symmetric")
    if reject is None:
        reject = env_kwargs.get("episode_length") is not None
    if not isinstance(reject, (bool, np.bool_)):
        raise TypeError(f"reject_symmetric must be True, False or None, got {reject!r}")
    return {"generator": generator, "reject_symmetric": bool(reject)}


def _codes(rng, count, *, size):
    return perfect_maze_codes(size, rng, count)


def _of_code(code, *, size):
    return perfect_maze_of_code(size, code)


#: The largest DepthMaze side: its tables grow about as size**2.7 (401 needs 4.2 GB); 201 about 0.6 GB.
MAX_SIZE = 201
#: The longest ``episode_length``: ``DepthMaze-v0``'s ``max_episode_steps`` (a longer episode would be cut by the time limit).
MAX_EPISODE_LENGTH = 100


class DepthMazeEnv(GridLocEnv):
    """A robot with a heading and a depth sensor in random perfect mazes (the Maze2D setting of
    Active Neural Localization, Chaplot et al., ICLR 2018).

    ## Description
    The robot sits on an unknown free cell of a maze, facing an unknown direction.  It can turn
    or move forward, and it reads the depth to the wall ahead.  The goal is to localise its pose
    (cell and heading).  By default a new maze is drawn at every reset, so a policy must work on
    mazes it never saw.

    ## Action Space
    ``Discrete(3)``: 0 = turn left (heading - 1 mod 4), 1 = turn right (heading + 1 mod 4),
    2 = move one cell forward (into a wall: stay).  A turn fails (does nothing) with
    ``p_turn_fail``, a move with ``p_move_fail`` (both 0 by default).

    ## Observation Space
    ``Discrete(D + 1)``: the depth ``1 +`` (free cells between the robot and the first wall ahead);
    1 = a wall right ahead; 0 is never read.  ``D = size - 2``, the largest depth a maze of this
    size can have.  With ``p_depth_error`` the depth is off by one (either way) with that
    probability.

    ## Starting State
    Uniform over the free cells and the four headings (0 = N, 1 = E, 2 = S, 3 = W); the first
    observation is a reading there.

    ## Rewards
    -1 per step (``reward="step"``), or the belief's largest pose probability after the step
    (``reward="belief"``, the research protocol's reward).

    ## Episode End
    Terminated when the largest posterior probability of a POSE (cell and heading) reaches
    ``localise_threshold``; truncated at ``max_episode_steps`` (100 for ``DepthMaze-v0``).  With
    ``episode_length=L``, the research protocol: exactly L steps, never terminated early
    (truncated at L).  ``L`` is at most the step limit, 100 (a longer episode would be cut short by
    the time limit: refused, never truncated; so is an ``L`` above the vector env's ``max_episode_steps``).

    ## Arguments
    ``size`` (7: an odd side >= 5; the protocol's sizes are 7, 15 and 21), ``layout`` (a fixed maze:
    a file or rows of ``O`` and ``#``), ``map_seed`` (a fixed generated maze), ``new_map_each_reset``
    (default True unless ``layout`` or ``map_seed`` is given: a new maze at every reset, drawn from
    the environment's ``np_random``, so the same reset seed gives the same maze), ``p_turn_fail``,
    ``p_move_fail``, ``p_depth_error`` (0.0 each), ``localise_threshold`` (0.9), ``episode_length``
    (None), ``reward`` (``"step"`` or ``"belief"``), ``kidnap_prob`` (0.0), ``render_mode``,
    ``render_shading`` (``"relative"`` or ``"absolute"``, see :class:`~gym_gridloc.GridLocEnv`).
    An ``rgb_array`` frame draws the true pose as an orange triangle pointing along the heading,
    the belief's headings as small triangles at each cell's sides (white, navy on a light cell;
    opacity: the heading's probability given the cell), and the depth read in the strip under the maze (the robot's
    cell, the free cells it sees, the wall).

    ``generator`` (``"kruskal"``, ``"eller"`` or ``"mixed"``) and ``reject_symmetric`` (None) choose how mazes are drawn.

    Mazes are perfect (one path between any two cells, walls all round), drawn by Kruskal's
    algorithm (:func:`gym_gridloc.generators.perfect_maze`, the default) or row by row by Eller's
    (``generator="eller"``: :func:`gym_gridloc.generators.eller_maze`, the construction Active
    Neural Localization's mazes come from), or by either, each with probability 1/2
    (``generator="mixed"``: :func:`gym_gridloc.generators.mixed_maze`, for training a policy that
    meets both; the held-out sets are per generator).  With ``reject_symmetric``, a drawn maze equal to its
    own 90- or 180-degree rotation is drawn again: in such a maze every pose has a twin that reads
    the same depths whatever the robot does, so no policy can localise there and a score on such
    mazes measures the maze, not the policy (about 5% of 7x7 mazes; none seen at 15x15).  Its
    default (None) rejects them under the research protocol (``episode_length`` given) and keeps
    them otherwise; a ``layout`` is never rejected.  Held-out test mazes, drawn the same way:
    :func:`gym_gridloc.maps.test_set`.

    ## Vector Environments
    ``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")`` (the native
    :class:`~gym_gridloc.GridLocVectorEnv`) observes the reading and the exact belief, as
    :class:`~gym_gridloc.HMMBeliefWrapper` does; ``"sync"`` and ``"async"`` vectorize this class, whose
    observation is the reading alone.  To make them agree: ``wrappers=[HMMBeliefWrapper]`` for
    ``"sync"``/``"async"``, or ``belief=None`` (a keyword of ``make_vec``) for the native one.

    ## Version History
    * v0: initial version.
    """

    #: What a None keyword stands for (size None: 7, or a layout's own size).
    DEFAULTS = {"size": 7}

    def __init__(self, size: int | None = None, *, layout=None, map_seed: int | None = None,
                 new_map_each_reset: bool | None = None, p_turn_fail: float = 0.0, p_move_fail: float = 0.0,
                 p_depth_error: float = 0.0, localise_threshold: float = LOCALISE_THRESHOLD, episode_length: int | None = None,
                 reward: str = "step", kidnap_prob: float = 0.0, generator: str = "kruskal",
                 reject_symmetric: bool | None = None, render_mode: str | None = None, render_shading: str = "relative") -> None:
        if new_map_each_reset is None:
            new_map_each_reset = layout is None and map_seed is None
        if not isinstance(new_map_each_reset, (bool, np.bool_)):
            raise TypeError(f"new_map_each_reset must be True or False, got {new_map_each_reset!r}")
        new_map_each_reset = bool(new_map_each_reset)
        if layout is not None and (map_seed is not None or new_map_each_reset):
            raise ValueError("give either layout=... (a fixed maze) or a generated one (map_seed, new_map_each_reset), not both")
        n = check_int("size", 7 if size is None else size, 5, MAX_SIZE)  # (the cap: tables that fit in memory)
        if layout is not None:  # the same cap for a layout's sides, read before any table is built
            layout = layout if isinstance(layout, GridMap) else parse_maze(layout)
            if max(layout.shape) > MAX_SIZE:
                raise ValueError(f"layout is a {layout.shape[0]}x{layout.shape[1]} maze; a DepthMaze side is at most "
                                 f"{MAX_SIZE} (its tables grow about as side**2.7: {MAX_SIZE} needs about 0.6 GB)")
        if episode_length is not None:
            check_int("episode_length", episode_length, 1, MAX_EPISODE_LENGTH,
                      what=f"a whole number in 1..{MAX_EPISODE_LENGTH} (DepthMaze-v0's max_episode_steps)")
        if n % 2 == 0:
            raise ValueError(f"size must be odd (rooms at odd coordinates, walls all round), got {size!r}")

        # Module-level functions bound with partial: the environment pickles with them.
        build = functools.partial(_build, p_turn_fail=p_turn_fail, p_move_fail=p_move_fail, p_depth_error=p_depth_error,
                                  max_depth=n - 2 if layout is None else None, kidnap_prob=kidnap_prob)
        options = map_options({"generator": generator, "reject_symmetric": reject_symmetric, "episode_length": episode_length})
        if options == {"generator": "kruskal", "reject_symmetric": False}:  # Kruskal's codes: the vector env draws them in its step
            draw = functools.partial(_draw, size=n)
            factory = MapFactory(build, draw, codes=functools.partial(_codes, size=n), of_code=functools.partial(_of_code, size=n),
                                 graph=perfect_maze_graph(n))
        else:
            draw = functools.partial(_draw_maze, size=n, **options)
            factory = MapFactory(build, draw)
        first = layout if layout is not None else draw(0 if map_seed is None else map_seed)
        if layout is not None and size is not None:  # the layout's size is the maze's: a different size= is no size
            model = build(layout)
            if model.shape != (n, n):
                raise ValueError(f"size={size!r} but the layout is a {model.shape[0]}x{model.shape[1]} maze: give one of them")
        super().__init__(build(first), localise_threshold=localise_threshold, render_mode=render_mode, builder=build,
                         map_factory=factory if new_map_each_reset else None,
                         referee_pose=True, episode_length=episode_length, reward=reward, render_shading=render_shading)
        self.size = n
        #: How the mazes are drawn (:func:`map_options`): ``generator`` and ``reject_symmetric``.
        self.map_options = options
