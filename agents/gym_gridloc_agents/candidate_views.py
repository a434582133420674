"""What the maze looks like from the poses the belief holds most: egocentric views for an MLP.

A flat MLP over the pose belief and the maze ties each weight to one place of the maze; a 15 x 15
random maze never repeats, so what it learns about telling two poses apart in one corridor does
not carry over to another.  Yet what tells two hypotheses apart does not depend on where they
are: the robot acts in its own frame, and what a sequence of turns and moves would read from
pose ``p`` is decided by the maze around ``p`` turned so that ``p``'s heading points up.

:class:`CandidateViews` reads the flat observation of ``HMMBeliefWrapper(full_state=True,
map=True, flatten=True)`` on a square ``size x size`` maze (the encoded reading's ``readings``
entries, DepthMaze's ``size - 1`` by default; the pose belief's ``4 * size**2``, heading-major; the
maze's ``size**2`` free cells; then any history) and appends, for the ``candidates`` most probable
poses (most probable first), their probability and the ``(2 radius + 1)**2`` cells around them in
the robot's frame (forward up, outside the maze a wall).  With ``keep: true`` the raw observation
is passed on in front of them (else only the reading and the history).  It is a view of the belief
and the maze, nothing a planner computed.

Config: ``policy: MlpPolicy``, ``policy_kwargs: {features_extractor: candidate_views,
features_extractor_kwargs: {size: 15, candidates: 4, radius: 6}}``.
"""

from __future__ import annotations

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

from gym_gridloc.core.validation import check_int

#: The unit steps of headings N, E, S, W (rows down, columns right): forward, and to the right.
_FORWARD = ((-1, 0), (0, 1), (1, 0), (0, -1))
_RIGHT = ((0, 1), (1, 0), (0, -1), (-1, 0))


def view_cells(size: int, radius: int) -> np.ndarray:
    """``(4 * size**2, (2 radius + 1)**2)`` int64: for pose ``h * size**2 + r * size + c``, the
    cells of the maze padded by ``radius`` walls on each side (flat, row-major, side
    ``size + 2 radius``) that its egocentric view shows, row by row from the farthest ahead to the
    farthest behind, each row from left to right."""
    side, span = size + 2 * radius, np.arange(-radius, radius + 1)
    ahead, right = -span[:, None], span[None, :]  # view row i looks radius - i cells ahead
    out = np.empty((4, size, size, (2 * radius + 1) ** 2), dtype=np.int64)
    rows, cols = np.meshgrid(np.arange(size), np.arange(size), indexing="ij")
    for h, ((fr, fc), (rr, rc)) in enumerate(zip(_FORWARD, _RIGHT)):
        dr, dc = ahead * fr + right * rr, ahead * fc + right * rc
        out[h] = ((rows[..., None, None] + dr + radius) * side + cols[..., None, None] + dc + radius).reshape(size, size, -1)
    return out.reshape(4 * size * size, -1)


class CandidateViews(BaseFeaturesExtractor):
    """The observation (or what follows the maze in it), then for each of the ``candidates`` most
    probable poses its probability and its egocentric view of the maze (see the module).

    Parameters: ``size`` (the maze's side), ``candidates`` (4), ``radius`` (6), ``keep`` (True),
    ``readings`` (the encoded reading's entries; None: ``size - 1``, DepthMaze's depths).
    """

    #: Reads flat ``Box`` observations (``MlpPolicy``), not Dict ones.
    dict_observations = False

    def __init__(self, observation_space: spaces.Box, size: int = 15, candidates: int = 4, radius: int = 6,
                 keep: bool = True, readings: int | None = None) -> None:
        size = check_int("CandidateViews: size", size, 3, error=ValueError)
        readings = size - 1 if readings is None else check_int("CandidateViews: readings", readings, 1, error=ValueError)
        radius = check_int("CandidateViews: radius", radius, 1, 2 * size, error=ValueError)
        candidates = check_int("CandidateViews: candidates", candidates, 1, 4 * size * size, error=ValueError)
        if not isinstance(keep, bool):
            raise ValueError(f"CandidateViews: keep must be true or false, got {keep!r}")
        if not isinstance(observation_space, spaces.Box) or len(observation_space.shape) != 1:
            raise ValueError(f"CandidateViews reads flat Box observations (wrapper.flatten: true); got {observation_space}")
        n, states = int(observation_space.shape[0]), 4 * size * size
        if n < readings + states + size * size:
            raise ValueError(f"CandidateViews: a {size}x{size} maze's flat observation holds the reading ({readings}), the pose "
                             f"belief ({states}) and the maze ({size * size}) (wrapper full_state, map, flatten); got {n} entries")
        cells = (2 * radius + 1) ** 2
        rest = n - states - size * size
        super().__init__(observation_space, features_dim=(n if keep else rest) + candidates * (1 + cells))
        self.size, self.radius, self.candidates, self.keep = size, radius, candidates, keep
        self.readings, self.states = readings, states
        self.register_buffer("cells", torch.from_numpy(view_cells(size, radius)), persistent=False)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        obs = obs.flatten(1).float()
        b, s, r = obs.shape[0], self.size, self.radius
        start, end = self.readings, self.readings + self.states
        belief, maze = obs[:, start:end], obs[:, end : end + s * s]
        padded = torch.nn.functional.pad(maze.view(b, 1, s, s), (r, r, r, r)).flatten(1)  # outside: a wall (0)
        prob, pose = torch.topk(belief, self.candidates, dim=1)
        views = torch.gather(padded, 1, self.cells[pose].flatten(1))
        head = obs if self.keep else torch.cat([obs[:, :start], obs[:, end + s * s :]], dim=1)
        return torch.cat([head, prob, views], dim=1)
