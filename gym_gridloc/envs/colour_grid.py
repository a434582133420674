from __future__ import annotations

from gym_gridloc.envs.base import GridLocEnv
from gym_gridloc.models import colour_grid_model


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
    (``"ansi"``, ``"rgb_array"``, ``"human"``).

    ## Version History
    * v0: initial version.
    """

    def __init__(self, layout=None, *, slip: float = 0.1, accuracy: float = 0.88,
                 localise_threshold: float = 0.9, kidnap_prob: float = 0.0,
                 render_mode: str | None = None) -> None:
        super().__init__(colour_grid_model(layout, slip=slip, accuracy=accuracy).with_kidnapping(kidnap_prob),
                         localise_threshold=localise_threshold, render_mode=render_mode)
