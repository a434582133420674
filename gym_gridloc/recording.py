"""Recording episodes for offline inference (smoothing, Viterbi): :class:`RecordTrajectory`."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from gym_gridloc.core.validation import check_int

__all__ = ["RecordTrajectory", "Trajectory"]


def _copy(obs: Any) -> Any:
    if isinstance(obs, dict):
        return {k: _copy(v) for k, v in obs.items()}
    return obs.copy() if isinstance(obs, np.ndarray) else obs


@dataclass
class Trajectory:
    """One episode: ``observations[0]`` is the reading at reset and ``actions[k]`` was taken
    between ``observations[k]`` and ``observations[k+1]``; ``infos[k]`` came with
    ``observations[k]``.  This is the input :func:`gym_gridloc.smooth` and
    :func:`gym_gridloc.viterbi` take."""

    observations: list[Any] = field(default_factory=list)
    actions: list[int] = field(default_factory=list)
    rewards: list[float] = field(default_factory=list)
    infos: list[dict[str, Any]] = field(default_factory=list)
    terminated: bool = False
    truncated: bool = False

    def __len__(self) -> int:
        """The number of steps (actions)."""
        return len(self.actions)

    @property
    def positions(self) -> list[tuple[int, int]]:
        """The true positions ``info["position"]`` (when the environment reports them)."""
        return [tuple(i["position"]) for i in self.infos]

    @property
    def sensor_observations(self) -> list[Any]:
        """The sensor readings alone: ``obs["observation"]`` for Dict observations (e.g. when a
        belief wrapper sits underneath), the observation itself otherwise."""
        return [o["observation"] if isinstance(o, dict) else o for o in self.observations]


class RecordTrajectory(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Record every episode's observations, actions, rewards and infos, unchanged.

    ``trajectory`` is the episode in progress; ``episodes`` holds the last ``max_episodes``
    finished ones (an episode is finished when the next ``reset`` starts).

    >>> import gymnasium as gym, gym_gridloc
    >>> env = gym_gridloc.RecordTrajectory(gym.make("WindyMaze-v0"))
    >>> _ = env.reset(seed=0)
    >>> _ = env.step(1)
    >>> post = gym_gridloc.smooth(env.unwrapped.model, env.trajectory.actions, env.trajectory.observations)
    >>> post.shape
    (2, 6, 7)
    """

    def __init__(self, env: gym.Env, max_episodes: int = 100) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, max_episodes=max_episodes)
        gym.Wrapper.__init__(self, env)
        self.max_episodes = check_int("max_episodes", max_episodes, minimum=0)
        self.episodes: deque[Trajectory] = deque(maxlen=self.max_episodes)
        self.trajectory: Trajectory | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        if self.trajectory is not None and self.max_episodes > 0:
            self.episodes.append(self.trajectory)
        self.trajectory = Trajectory(observations=[_copy(obs)], infos=[dict(info)])
        return obs, info

    def step(self, action):
        if self.trajectory is None:
            raise RuntimeError("call reset() before step()")
        obs, reward, terminated, truncated, info = self.env.step(action)
        tr = self.trajectory
        tr.actions.append(int(action) if np.ndim(action) == 0 else _copy(action))
        tr.observations.append(_copy(obs))
        tr.rewards.append(float(reward))
        tr.infos.append(dict(info))
        tr.terminated, tr.truncated = bool(terminated), bool(truncated)
        return obs, reward, terminated, truncated, info
