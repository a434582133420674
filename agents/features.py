"""Features extractors for stable-baselines3 policies that read the map.

stable-baselines3's ``NatureCNN`` needs images of at least 36 x 36; the maps here are 5 x 5 to
21 x 21.  :class:`BeliefMapCNN` stacks the belief's channels (one per heading with
``full_state``) and the map's channels (``HMMBeliefWrapper(map=True)``) into one image, runs a
few 3 x 3 convolutions that keep the size (padding 1), flattens, and appends the reading
(stable-baselines3 one-hot encodes a ``Discrete`` reading before it gets here).

Configs name it (never evaluate it): ``policy_kwargs: {features_extractor: belief_map_cnn,
features_extractor_kwargs: {channels: 32, layers: 3, features: 256}}``.

:class:`BeliefLogFeatures` is for flat belief observations (``wrapper.flatten: true``, policy
``MlpPolicy``): an MLP on raw probabilities hardly tells 1e-4 from 1e-2, yet a planner's choice
often turns on such small probabilities; it appends ``log(belief + eps)``, scaled to [0, 1], to
the raw observation (``policy_kwargs: {features_extractor: belief_log,
features_extractor_kwargs: {readings: 4}}``: the first ``readings`` entries, the encoded sensor
reading, are passed on raw only).
"""

from __future__ import annotations

import math

import torch
from gymnasium import spaces
from stable_baselines3.common.preprocessing import get_flattened_obs_dim
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn


class BeliefMapCNN(BaseFeaturesExtractor):
    """3 x 3 convolutions over belief + map channels, then a linear layer; the reading beside.

    Parameters: ``channels`` per convolution (32), ``layers`` of convolution (3), ``features``
    out of the linear layer (256).
    """

    #: Reads Dict observations (``MultiInputPolicy``).
    dict_observations = True

    def __init__(self, observation_space: spaces.Dict, channels: int = 32, layers: int = 3, features: int = 256) -> None:
        for key in ("observation", "belief"):
            if key not in observation_space.spaces:
                raise ValueError(f"BeliefMapCNN reads Dict observations with 'observation', 'belief' (and 'map'); got {observation_space}")
        belief = observation_space["belief"].shape
        image = belief if len(belief) == 3 else (1, *belief)
        maps = observation_space.spaces.get("map")
        c_in = image[0] + (maps.shape[0] if maps is not None else 0)
        reading = get_flattened_obs_dim(observation_space["observation"])
        super().__init__(observation_space, features_dim=features + reading)
        convs: list[nn.Module] = []
        for k in range(layers):
            convs += [nn.Conv2d(c_in if k == 0 else channels, channels, 3, padding=1), nn.ReLU()]
        h, w = image[1:]
        self.cnn = nn.Sequential(*convs, nn.Flatten(), nn.Linear(channels * h * w, features), nn.ReLU())
        self.has_map = maps is not None

    def forward(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        belief = obs["belief"]
        if belief.dim() == 3:
            belief = belief.unsqueeze(1)
        image = torch.cat([belief, obs["map"]], dim=1) if self.has_map else belief
        return torch.cat([self.cnn(image), obs["observation"].flatten(1)], dim=1)


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
        if eps_exponent < 1:
            raise ValueError(f"BeliefLogFeatures: eps_exponent must be >= 1, got {eps_exponent}")
        super().__init__(observation_space, features_dim=2 * n - readings)
        self.readings = int(readings)
        self.eps = 10.0 ** -int(eps_exponent)
        self.scale = 1.0 / (int(eps_exponent) * math.log(10.0))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        obs = obs.flatten(1).float()
        logs = 1.0 + torch.log(obs[:, self.readings :].clamp(min=0.0) + self.eps) * self.scale
        return torch.cat([obs, logs], dim=1)


#: Features extractors a config may name.
EXTRACTORS = {"belief_map_cnn": BeliefMapCNN, "belief_log": BeliefLogFeatures}
