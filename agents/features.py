"""Features extractors for stable-baselines3 policies that read the map.

stable-baselines3's ``NatureCNN`` needs images of at least 36 x 36; the maps here are 5 x 5 to
21 x 21.  :class:`BeliefMapCNN` stacks the belief's channels (one per heading with
``full_state``) and the map's channels (``HMMBeliefWrapper(map=True)``) into one image, runs a
few 3 x 3 convolutions that keep the size (padding 1), flattens, and appends the reading
(stable-baselines3 one-hot encodes a ``Discrete`` reading before it gets here).

Configs name it (never evaluate it): ``policy_kwargs: {features_extractor: belief_map_cnn,
features_extractor_kwargs: {channels: 32, layers: 3, features: 256}}``.
"""

from __future__ import annotations

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


#: Features extractors a config may name.
EXTRACTORS = {"belief_map_cnn": BeliefMapCNN}
