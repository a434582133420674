from __future__ import annotations

from gym_gridloc.envs.base import GridLocEnv
from gym_gridloc.models import ring_sensor_model
from gym_gridloc.referee import LOCALISE_THRESHOLD


class RingSensorEnv(GridLocEnv):
    """A robot on an empty grid with a vague location sensor (seeds 001 and 003).

    ## Description
    The robot sits on an unknown cell of an empty H x W grid (8x8 by default).  Its sensor reports
    a cell near it, or nothing.  The goal is to localise.

    ## Action Space
    ``Discrete(4)``: 0 = N, 1 = E, 2 = S, 3 = W.  With ``dynamics="commanded"`` (the default) the
    action plays the role of the heading: the robot follows it with ``keep_heading`` (0.7) when it
    does not face a wall, otherwise it takes a uniformly chosen heading that does not face a wall;
    then it moves one cell.  With ``dynamics="passive"`` (the seeds' robot; ``"seed"`` is a
    deprecated alias) the robot keeps a hidden heading and follows the seeds' rule whatever the
    action: the action space is still ``Discrete(4)``, as in every environment, but the action
    plays no part (a passive tracking task).

    ## Observation Space
    ``Discrete(H * W + 1)``: ``r * W + c`` is a reported cell, ``H * W`` is "nothing".  The true
    cell is reported with 0.1, each of the 8 cells at Chebyshev distance 1 with 0.05, each of the
    16 at distance 2 with 0.025; readings off the grid, and the remaining 0.1, are "nothing".

    ## Starting State
    Uniform over cells (and, with passive dynamics, over the four headings); the first observation is
    a reading at the start.

    ## Rewards
    -1 per step.

    ## Episode End
    Terminated when the largest posterior probability of a position reaches
    ``localise_threshold``; truncated at ``max_episode_steps`` (400 for ``RingSensor8x8-v0``: the
    sensor is vague and a random walk needs a median of about 170 steps).

    ## Arguments
    ``size`` ((8, 8)), ``layout`` (None: an empty grid; or a maze file / list of rows of ``O`` and
    ``#`` whose obstacles the robot cannot enter and whose cells the sensor may still report), ``dynamics`` (``"commanded"`` or ``"passive"``), ``keep_heading`` (0.7),
    ``p_true`` (0.1), ``p_ring1`` (0.05), ``p_ring2`` (0.025), ``localise_threshold`` (0.9), ``kidnap_prob`` (0.0: after every move the
    robot is teleported to a uniformly chosen free state with this probability),
    ``render_mode``, ``render_shading`` (``"relative"`` or ``"absolute"``, see :class:`~gym_gridloc.GridLocEnv`).

    ## Vector Environments
    ``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")`` (the native
    :class:`~gym_gridloc.GridLocVectorEnv`) observes the reading and the exact belief, as
    :class:`~gym_gridloc.HMMBeliefWrapper` does; ``"sync"`` and ``"async"`` vectorize this class, whose
    observation is the reading alone.  To make them agree: ``wrappers=[HMMBeliefWrapper]`` for
    ``"sync"``/``"async"``, or ``belief=None`` (a keyword of ``make_vec``) for the native one.

    ## Version History
    * v0: initial version.
    """

    def __init__(self, size=(8, 8), *, layout=None, dynamics: str = "commanded", keep_heading: float = 0.7,
                 p_true: float = 0.1, p_ring1: float = 0.05, p_ring2: float = 0.025,
                 localise_threshold: float = LOCALISE_THRESHOLD, kidnap_prob: float = 0.0,
                 render_mode: str | None = None, render_shading: str = "relative") -> None:
        model = ring_sensor_model(size, dynamics=dynamics, keep_heading=keep_heading,
                                  p_true=p_true, p_ring1=p_ring1, p_ring2=p_ring2, layout=layout).with_kidnapping(kidnap_prob)
        super().__init__(model, localise_threshold=localise_threshold, render_mode=render_mode, render_shading=render_shading)
