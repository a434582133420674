"""Recording episodes for offline inference (smoothing, Viterbi): :class:`RecordTrajectory`; and
the measurement of recovery from kidnapping on recorded true states (:func:`kidnap_steps`,
:func:`steps_to_recover`)."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from gym_gridloc.core.validation import check_int

__all__ = ["RecordTrajectory", "Trajectory", "kidnap_steps", "steps_to_recover"]


def _copy(obs: Any) -> Any:
    if isinstance(obs, dict):
        return {k: _copy(v) for k, v in obs.items()}
    return obs.copy() if isinstance(obs, np.ndarray) else obs


@dataclass
class Trajectory:
    """One episode: ``observations[0]`` is the reading at reset and ``actions[k]`` was taken
    between ``observations[k]`` and ``observations[k+1]``; ``infos[k]`` came with
    ``observations[k]``.  This is the input :func:`gym_gridloc.smooth` and
    :func:`gym_gridloc.viterbi` take; ``model`` is the episode's own model (its map: a map redrawn
    at the next reset does not change it), and :meth:`smooth` / :meth:`viterbi` use it."""

    observations: list[Any] = field(default_factory=list)
    actions: list[int] = field(default_factory=list)
    rewards: list[float] = field(default_factory=list)
    infos: list[dict[str, Any]] = field(default_factory=list)
    terminated: bool = False
    truncated: bool = False
    model: Any = None

    def _model(self):
        if self.model is None:
            raise ValueError("this trajectory has no model (it was not recorded by RecordTrajectory): pass one to "
                             "gym_gridloc.smooth / viterbi")
        return self.model

    def smooth(self, **kwargs: Any) -> np.ndarray:
        """:func:`gym_gridloc.smooth` of this episode on its own model."""
        from gym_gridloc.inference import smooth

        return smooth(self._model(), self.actions, self.sensor_observations, **kwargs)

    def viterbi(self, **kwargs: Any):
        """:func:`gym_gridloc.viterbi` of this episode on its own model."""
        from gym_gridloc.inference import viterbi

        return viterbi(self._model(), self.actions, self.sensor_observations, **kwargs)

    def __len__(self) -> int:
        """The number of steps (actions)."""
        return len(self.actions)

    @property
    def positions(self) -> list[tuple[int, int]]:
        """The true positions ``info["position"]`` (when the environment reports them)."""
        return [tuple(i["position"]) for i in self.infos]

    @property
    def states(self) -> list[tuple[int, int, int]]:
        """The true hidden states ``(layer, row, col)``: ``info["heading"]`` (0 when absent) and
        ``info["position"]``."""
        return [(int(i.get("heading", 0)), *map(int, i["position"])) for i in self.infos]

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

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        if self.trajectory is not None and self.max_episodes > 0:
            self.episodes.append(self.trajectory)
        self.trajectory = Trajectory(observations=[_copy(obs)], infos=[dict(info)],
                                     model=getattr(self.env.unwrapped, "model", None))  # the episode's map, kept
        return obs, info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
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


# -- the kidnapped robot ---------------------------------------------------------------------------
def kidnap_steps(model, states, actions) -> list[int]:
    """The steps k (1..t) at which the robot was kidnapped: ``states[k]`` cannot be reached from
    ``states[k-1]`` under ``actions[k-1]`` by the model's motion alone.  (A teleport that lands on
    a state the move could have reached is indistinguishable from that move and is not counted.)
    ``states`` are ``(layer, row, col)`` tuples, e.g. :attr:`Trajectory.states`."""
    if len(actions) != len(states) - 1:
        raise ValueError(f"actions must have one element fewer than states; got {len(actions)} and {len(states)}")
    return [k for k in range(1, len(states))
            if tuple(states[k]) not in {s for s, _ in model.outcomes(tuple(states[k - 1]), actions[k - 1])}]


def steps_to_recover(
    estimates,
    confidences,
    positions,
    kidnaps,
    *,
    cap: int = 50,
    min_confidence: float = 0.5,
    localised_before: bool = True,
) -> list[int | None]:
    """For each kidnap step k, the number of steps ``j >= 0`` until the estimate is right again:
    the first ``k + j`` at which ``estimates[k + j] == positions[k + j]`` and
    ``confidences[k + j] >= min_confidence`` ("localised").

    Returns one entry per kidnap: ``j``; ``cap + 1`` when the filter has not recovered within
    ``cap`` steps (counted as a failure); or ``None`` when the event says nothing about the
    filter and is left out: the next kidnap or the end of the episode comes before recovery and
    before ``cap`` steps, or (with ``localised_before``, the default: the classic kidnapped robot
    is a localised robot carried off) the filter was not localised at step ``k - 1``.
    """
    cap = check_int("cap", cap, minimum=0)

    def localised(step: int) -> bool:
        return tuple(estimates[step]) == tuple(positions[step]) and confidences[step] >= min_confidence

    def recovery(i: int, k: int) -> int | None:
        if localised_before and (k < 1 or not localised(k - 1)):
            return None
        # Look up to ``cap`` steps ahead, not past the next kidnap (or the end of the episode).
        horizon = min(cap + 1, (kidnaps[i + 1] if i + 1 < len(kidnaps) else len(positions)) - k)
        j = next((j for j in range(horizon) if localised(k + j)), None)
        return cap + 1 if j is None and horizon == cap + 1 else j

    return [recovery(i, k) for i, k in enumerate(kidnaps)]
