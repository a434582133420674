"""Features extractors for stable-baselines3 policies: over the map (CNNs) and over the flat belief.

stable-baselines3's ``NatureCNN`` needs images of at least 36 x 36; the maps here are 5 x 5 to
21 x 21.  :class:`BeliefMapCNN` stacks the belief's channels (one per heading with
``full_state``) and the map's channels (``HMMBeliefWrapper(map=True)``) into one image, runs a
few 3 x 3 convolutions that keep the size (padding 1), flattens, and appends the reading
(stable-baselines3 one-hot encodes a ``Discrete`` reading before it gets here).

The flattened image and its linear layer tie every feature to one place of the map.
:class:`PosePoolCNN` (for DepthMaze's pose beliefs) does not: it computes egocentric features of
every pose from the maze alone (turned per heading, depths included, receptive field the whole
maze) and pools them over the poses the belief holds, so what it learns on one part of one maze
applies anywhere on any maze (on 15 x 15 random mazes, accuracy 0.95-0.97 at 20 steps on the
validation mazes after cloning the optimal policy, where BeliefMapCNN reached 0.61).

Configs name them (never evaluate them): ``policy_kwargs: {features_extractor: belief_map_cnn,
features_extractor_kwargs: {channels: 32, layers: 3, features: 256}}`` (or ``pose_pool_cnn``,
``cell_pool_cnn``).  :class:`CellPoolCNN` is PosePoolCNN's idea for position beliefs on maps
with colours or walls: features of every cell from the map alone, pooled over the belief.

:class:`BeliefLogFeatures` is for flat belief observations (``wrapper.flatten: true``, policy
``MlpPolicy``): an MLP on raw probabilities hardly tells 1e-4 from 1e-2, yet a planner's choice
often turns on such small probabilities; it appends ``log(belief + eps)``, scaled to [0, 1], to
the raw observation (``policy_kwargs: {features_extractor: belief_log,
features_extractor_kwargs: {readings: 4}}``: the first ``readings`` entries, the encoded sensor
reading, are passed on raw only).  :class:`ReadingCellFeatures` is for raw readings that report a
cell (``recurrent_ppo`` on RingSensor8x8): the reported cell's row and column beside the one-hot.
"""

from __future__ import annotations

import itertools
import math

import torch
from gymnasium import spaces
from stable_baselines3.common.preprocessing import get_flattened_obs_dim
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from gym_gridloc.core.validation import check_int
from gym_gridloc_agents.candidate_views import CandidateViews


class BeliefMapCNN(BaseFeaturesExtractor):
    """3 x 3 convolutions over belief + map channels, then a linear layer; the reading beside.

    Parameters: ``channels`` per convolution (32), ``layers`` of convolution (3), ``features``
    out of the linear layer (256).
    """

    #: Reads Dict observations (``MultiInputPolicy``).
    dict_observations = True

    def __init__(self, observation_space: spaces.Dict, channels: int = 32, layers: int = 3, features: int = 256) -> None:
        _require_keys(observation_space, "BeliefMapCNN", ("observation", "belief"),
                      "'observation', 'belief' (and 'map')")
        belief = observation_space["belief"].shape
        image = belief if len(belief) == 3 else (1, *belief)
        maps = observation_space.spaces.get("map")
        c_in = image[0] + (maps.shape[0] if maps is not None else 0)
        reading = get_flattened_obs_dim(observation_space["observation"])
        super().__init__(observation_space, features_dim=features + reading + _history_dim(observation_space))
        convs = [m for k in range(layers)
                 for m in (nn.Conv2d(c_in if k == 0 else channels, channels, 3, padding=1), nn.ReLU())]
        self.cnn = nn.Sequential(*convs, nn.Flatten(), nn.Linear(channels * math.prod(image[1:]), features), nn.ReLU())
        self.has_map = maps is not None

    def forward(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        belief = obs["belief"].unsqueeze(1) if obs["belief"].dim() == 3 else obs["belief"]
        image = torch.cat([belief, obs["map"]], dim=1) if self.has_map else belief
        return _with_history(torch.cat([self.cnn(image), obs["observation"].flatten(1)], dim=1), obs)


def _history_dim(space: spaces.Dict) -> int:
    """The size of the ``"history"`` entry (:mod:`gym_gridloc_agents.history`: the last actions and
    the steps left) that every Dict extractor passes on beside its features, 0 without one."""
    history = space.spaces.get("history")
    return int(math.prod(history.shape)) if history is not None else 0


def _with_history(features: torch.Tensor, obs: dict[str, torch.Tensor]) -> torch.Tensor:
    return torch.cat([features, obs["history"].flatten(1)], dim=1) if "history" in obs else features


# -- pooling over the belief's poses -------------------------------------------------------------
def _require_keys(space: spaces.Dict, name: str, keys=("observation", "belief", "map"),
                  listed: str = "'observation', 'belief' and 'map'") -> None:
    if any(key not in space.spaces for key in keys):
        raise ValueError(f"{name} reads Dict observations with {listed}; got {space}")


def _dilated_convs(channels: int, layers: int, max_dilation: int) -> nn.ModuleList:
    """``layers - 1`` residual 3 x 3 convolutions with dilations 1, 2, 4, ... (back to 1 past
    ``max_dilation``), keeping the size."""
    dilations = list(itertools.accumulate(range(layers - 1), lambda d, _: 1 if d * 2 > max_dilation else d * 2,
                                          initial=1))[:-1]
    return nn.ModuleList(nn.Conv2d(channels, channels, 3, padding=k, dilation=k) for k in dilations)


def _residual_stack(first: nn.Module, convs: nn.ModuleList, x: torch.Tensor) -> torch.Tensor:
    x = torch.relu(first(x))
    for conv in convs:
        x = x + torch.relu(conv(x))
    return x


def _support(b: torch.Tensor, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The belief's support (entries >= 1% of its largest) as 0/1, and its log-size scaled by
    ``log n`` (0 for one hypothesis, 1 for all ``n``)."""
    support = (b >= 0.01 * b.amax(dim=1, keepdim=True)).to(b.dtype)
    return support, torch.log(support.sum(dim=1, keepdim=True).clamp(min=1)) / math.log(max(n, 2))


def _shifted(x: torch.Tensor, dy: int, dx: int) -> torch.Tensor:
    """``out[..., y, x] = x[..., y + dy, x + dx]``, zero outside the grid (outside is a wall)."""
    h, w = x.shape[-2:]
    pad = torch.nn.functional.pad(x, (max(-dx, 0), max(dx, 0), max(-dy, 0), max(dy, 0)))
    y0, x0 = max(dy, 0), max(dx, 0)
    return pad[..., y0 : y0 + h, x0 : x0 + w]


def depth_channels(free: torch.Tensor) -> torch.Tensor:
    """The depth each cell reads facing N, E, S, W: ``(N, 1, H, W)`` free cells -> ``(N, 4, H, W)``,
    ``1 +`` the free cells in a row before the first wall (0 on walls), as DepthMaze reads it."""
    out = []
    for dy, dx in ((-1, 0), (0, 1), (1, 0), (0, -1)):
        run, depth = free, free.clone()
        for k in range(1, max(free.shape[-2:])):
            run = run * _shifted(free, k * dy, k * dx)
            depth = depth + run
        out.append(depth)
    return torch.cat(out, dim=1)


class PosePoolCNN(BaseFeaturesExtractor):
    """Egocentric map features of every pose, averaged (and max-pooled) over the belief's poses.

    For heading h the maze is turned so that h points up and a convolution stack (shared by the
    four headings; dilations 1, 2, 4, ... cycled, residual) computes per-cell features in the
    robot's own frame from the free cells and the depths ahead, right, behind and left.  Pose
    (h, cell) gets the features of its cell in the turn of h.  The features are pooled with the
    belief as weights (the hypotheses' mean) and by a max over the belief's support; with the
    support's log-size and the reading they go through a linear layer.  The maze's features do
    not depend on the belief: the maps of a batch are convolved once each (a batch of one
    episode's steps shares one maze).  Square maps only (``full_state`` belief + ``map``).

    Parameters: ``channels`` (32), ``layers`` (6), ``features`` out (256), ``max_dilation`` (8).
    """

    #: Reads Dict observations (``MultiInputPolicy``).
    dict_observations = True

    def __init__(self, observation_space: spaces.Dict, channels: int = 32, layers: int = 6, features: int = 256,
                 max_dilation: int = 8) -> None:
        _require_keys(observation_space, "PosePoolCNN")
        belief = observation_space["belief"].shape
        if len(belief) != 3 or belief[0] != 4 or belief[1] != belief[2]:
            raise ValueError(f"PosePoolCNN needs a square pose belief (4, N, N) (full_state=True, four headings); got {belief}")
        reading = get_flattened_obs_dim(observation_space["observation"])
        super().__init__(observation_space, features_dim=features + reading + _history_dim(observation_space))
        self.first = nn.Conv2d(5, channels, 3, padding=1)
        self.convs = _dilated_convs(channels, layers, max_dilation)
        self.head = nn.Sequential(nn.Linear(2 * channels + 1, features), nn.ReLU())
        self.n_states = 4 * belief[1] * belief[2]

    def pose_features(self, free: torch.Tensor) -> torch.Tensor:
        """``(M, 1, H, W)`` mazes -> ``(M, 4, C, H, W)`` features of every pose."""
        depth = depth_channels(free) / max(free.shape[-1] - 2, 1)
        turned = torch.cat([torch.rot90(torch.cat([free, depth[:, [h, (h + 1) % 4, (h + 2) % 4, (h + 3) % 4]]], dim=1),
                                        h, dims=(2, 3)) for h in range(4)])
        x = _residual_stack(self.first, self.convs, turned)  # the four turns, one after another
        return torch.stack([torch.rot90(turn, -h, dims=(2, 3)) for h, turn in enumerate(x.chunk(4))], dim=1)

    def forward(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        belief, free = obs["belief"], obs["map"][:, :1]
        mazes, which = torch.unique(free.flatten(1), dim=0, return_inverse=True)
        feats = self.pose_features(mazes.view(-1, *free.shape[1:]))  # (M, 4, C, H, W)
        m, _, c = feats.shape[:3]
        feats = feats.permute(0, 1, 3, 4, 2).reshape(m, -1, c)  # (M, poses, C)
        b = belief.flatten(1)
        support, size = _support(b, self.n_states)
        mean, top = [], []
        order = torch.argsort(which)
        for k in range(m):  # the samples of each maze, pooled over its poses' features
            rows = order[which[order] == k]
            mean.append(b[rows] @ feats[k])
            top.append((support[rows].unsqueeze(2) * feats[k]).amax(dim=1))
        pooled = torch.cat([torch.cat(mean), torch.cat(top)], dim=1)[torch.argsort(order)]
        return _with_history(torch.cat([self.head(torch.cat([pooled, size], dim=1)), obs["observation"].flatten(1)], dim=1), obs)


class CellPoolCNN(BaseFeaturesExtractor):
    """Map features of every cell, pooled over the position belief: mean, spread and maximum.

    A convolution stack over the map's channels alone (free cells, and the colours where the map
    has them; dilations 1, 2, 4, ... cycled, residual; outside the grid is a wall) computes
    features of every cell's surroundings.  The position belief (summed over layers) weighs them:
    their mean over the hypotheses, their standard deviation (how much the hypotheses'
    surroundings differ: what a move could tell apart) and their maximum over the belief's
    support; with the support's log-size and the reading they go through a linear layer.  Nothing
    is tied to a place of the map, so what it learns on one map applies on any (the position
    counterpart of :class:`PosePoolCNN`, for ``ColourGrid-v0`` and ``WindyMaze-v0`` maps).

    With a ``"lookahead"`` observation (``HMMBeliefWrapper(lookahead=...)``: the expected
    entropies after each first action) these go into the linear layer too, and are passed on
    beside its output as they are and less their row's minimum (how much worse than the best
    action each action is expected to leave the belief), so that the policy can rank the actions
    by them directly.

    Parameters: ``channels`` (32), ``layers`` (4), ``features`` out (256), ``max_dilation`` (4).
    """

    #: Reads Dict observations (``MultiInputPolicy``).
    dict_observations = True

    def __init__(self, observation_space: spaces.Dict, channels: int = 32, layers: int = 4, features: int = 256,
                 max_dilation: int = 4) -> None:
        _require_keys(observation_space, "CellPoolCNN")
        belief, maps = observation_space["belief"].shape, observation_space["map"].shape
        if belief[-2:] != maps[-2:]:
            raise ValueError(f"CellPoolCNN: the belief {belief} and the map {maps} must cover the same grid")
        reading = get_flattened_obs_dim(observation_space["observation"])
        look = observation_space.spaces.get("lookahead")
        self.n_look = int(math.prod(look.shape)) if look is not None else 0
        super().__init__(observation_space, features_dim=features + 2 * self.n_look + reading + _history_dim(observation_space))
        self.first = nn.Conv2d(maps[0], channels, 3, padding=1)
        self.convs = _dilated_convs(channels, layers, max_dilation)
        self.head = nn.Sequential(nn.Linear(3 * channels + 1 + 2 * self.n_look, features), nn.ReLU())
        self.n_cells = belief[-1] * belief[-2]

    def cell_features(self, maps: torch.Tensor) -> torch.Tensor:
        """``(B, K, H, W)`` map channels -> ``(B, C, H*W)`` features of every cell."""
        return _residual_stack(self.first, self.convs, maps).flatten(2)

    def forward(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        belief = obs["belief"]
        b = (belief.sum(dim=1) if belief.dim() == 4 else belief).flatten(1)
        b = b / b.sum(dim=1, keepdim=True).clamp(min=1e-12)
        f = self.cell_features(obs["map"])  # (B, C, cells)
        mean = torch.einsum("bcs,bs->bc", f, b)
        spread = torch.sqrt((torch.einsum("bcs,bs->bc", f * f, b) - mean * mean).clamp(min=0.0) + 1e-6)
        support, size = _support(b, self.n_cells)
        top = (f * support.unsqueeze(1)).amax(dim=2)
        pooled = torch.cat([mean, spread, top, size], dim=1)
        if not self.n_look:
            return _with_history(torch.cat([self.head(pooled), obs["observation"].flatten(1)], dim=1), obs)
        look = obs["lookahead"]  # (B, depth, A)
        look = torch.cat([look, look - look.amin(dim=2, keepdim=True)], dim=1).flatten(1)
        return _with_history(torch.cat([self.head(torch.cat([pooled, look], dim=1)), look, obs["observation"].flatten(1)], dim=1), obs)


class BeliefLogFeatures(BaseFeaturesExtractor):
    """The flat observation ``[reading, belief]`` followed by ``1 + log(belief + eps) / log(1 / eps)``
    (0 for a zero probability, 1 for certainty), ``eps = 10 ** -eps_exponent``.

    Parameters: ``readings``, how many leading entries are the encoded reading (no logarithm:
    the belief follows them; 0 takes the logarithm of every entry), and ``eps_exponent`` (6).
    """

    #: Reads flat ``Box`` observations (``MlpPolicy``), not Dict ones.
    dict_observations = False

    def __init__(self, observation_space: spaces.Box, readings: int = 0, eps_exponent: int = 6) -> None:
        if not isinstance(observation_space, spaces.Box) or len(observation_space.shape) != 1:
            raise ValueError(f"BeliefLogFeatures reads flat Box observations (wrapper.flatten: true); got {observation_space}")
        n = observation_space.shape[0]
        if not 0 <= readings < n:
            raise ValueError(f"BeliefLogFeatures: readings must be in [0, {n}) for {observation_space}, got {readings}")
        eps_exponent = check_int("BeliefLogFeatures: eps_exponent", eps_exponent, whole=True, error=ValueError)
        super().__init__(observation_space, features_dim=2 * n - readings)
        self.readings = int(readings)
        self.eps = 10.0 ** -int(eps_exponent)
        self.scale = 1.0 / (int(eps_exponent) * math.log(10.0))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        obs = obs.flatten(1).float()
        logs = 1.0 + torch.log(obs[:, self.readings :].clamp(min=0.0) + self.eps) * self.scale
        return torch.cat([obs, logs], dim=1)


class ReadingCellFeatures(BaseFeaturesExtractor):
    """For a sensor that reports a cell of an ``height x width`` grid or nothing (RingSensor8x8's
    ``Discrete(H * W + 1)``: ``r * W + c``, then ``H * W`` for nothing), read raw (no belief, e.g.
    by ``recurrent_ppo``): the flat observation, one-hot reading first (stable-baselines3 encodes
    a ``Discrete`` reading so; :class:`gym_gridloc.PreviousActionWrapper` keeps it first),
    followed by the reported cell's row and column scaled to [0, 1] and a flag for nothing.

    One-hot, each of the ``H * W`` cells is an input of its own that the network learns about
    separately; the row and column let what it learns about one reported cell carry over to its
    neighbours (e.g. "reported near the top: go south").  Parameters: ``height``, ``width``.
    """

    dict_observations = False

    @staticmethod
    def reading_space(height: int = 8, width: int = 8) -> spaces.Discrete:
        """The raw reading these sizes decode (a config checks it against the environment's)."""
        height = check_int("ReadingCellFeatures: height", height, 2, error=ValueError)
        width = check_int("ReadingCellFeatures: width", width, 2, error=ValueError)
        return spaces.Discrete(height * width + 1)

    def __init__(self, observation_space: spaces.Box, height: int = 8, width: int = 8) -> None:
        cells = int(self.reading_space(height, width).n) - 1
        n = get_flattened_obs_dim(observation_space)
        if n < cells + 1:
            raise ValueError(f"ReadingCellFeatures: a {height}x{width} grid's reading needs {cells + 1} leading "
                             f"entries, but the observation {observation_space} has {n}")
        super().__init__(observation_space, features_dim=n + 3)
        coords = torch.zeros(cells + 1, 3)
        k = torch.arange(cells)
        coords[:cells, 0] = (k // width).float() / (height - 1)
        coords[:cells, 1] = (k % width).float() / (width - 1)
        coords[cells, 2] = 1.0
        self.cells = cells
        self.register_buffer("coords", coords)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        obs = obs.flatten(1).float()
        return torch.cat([obs, obs[:, : self.cells + 1] @ self.coords], dim=1)


#: Features extractors a config may name.
EXTRACTORS = {"belief_map_cnn": BeliefMapCNN, "pose_pool_cnn": PosePoolCNN, "cell_pool_cnn": CellPoolCNN,
              "belief_log": BeliefLogFeatures, "reading_cell": ReadingCellFeatures, "candidate_views": CandidateViews}
