"""What a memoryless policy of the belief lacks: a clock and its own last actions.

A deterministic policy of the belief alone repeats itself whenever a belief comes back: on a maze
where a turn and its reading change nothing, it turns forever.  :class:`History` keeps, for N
episodes, the last ``actions`` actions (one-hot, the newest first; zeros before the first step)
and one clock input, with a ``horizon`` H > 0:

* ``steps_left: H``: the steps left before the episode's end, ``min(L - t, H) / H`` for an episode
  of L steps at step t;
* ``time_step: H``: the time step, ``max(H - t, 0) / H`` (1 at the first step, 0 from step H on),
  whatever the episode's length.

A policy that sees them can leave a cycle.  Trained on episodes of H steps, both give the same
numbers, but they differ in a shorter episode: with the steps left, an episode of L < H steps
starts at ``L / H``, an input such a model saw only half-way through its training episodes; with
the time step, an episode of L steps is the first L steps of an episode of H, as in training, so
one model serves every length up to H.

The same encoding reaches the network in training (:class:`gym_gridloc_agents.envs.SB3VecEnv` with
``history=``, or :class:`HistoryWrapper` around one environment) and when the learned policy acts
(:class:`gym_gridloc_agents.policies.PPOPolicy` keeps a :class:`History` of its own).  A config
asks for it with ``wrapper: {past_actions: K, steps_left: H}`` (or ``time_step: H``).  The features are appended to a
flat observation, or under the key ``"history"`` of a Dict one.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from gym_gridloc.core.validation import check_int

__all__ = ["History", "HistoryOptions", "HistoryWrapper", "HISTORY_KEYS", "history_options", "episode_limit", "acting_history",
           "with_history_space"]

#: The most past actions and the longest horizon a history may have.
MAX_ACTIONS, MAX_HORIZON = 32, 10_000


class HistoryOptions(NamedTuple):
    """What a history holds: ``actions`` past actions, and a clock of ``horizon`` steps (0: none)
    that counts the steps left (``time_step`` False) or the time step (True)."""

    actions: int = 0
    horizon: int = 0
    time_step: bool = False

    @property
    def any(self) -> bool:
        """Whether there is anything to append."""
        return bool(self.actions or self.horizon)

    @property
    def needs_limit(self) -> bool:
        """Whether the clock counts the steps left, so it needs the episode's step limit."""
        return bool(self.horizon and not self.time_step)

    @property
    def wrapper(self) -> dict[str, int]:
        """The options as a wrapper section gives them (``past_actions``, and ``steps_left`` or ``time_step``)."""
        return {"past_actions": self.actions, "time_step" if self.time_step else "steps_left": self.horizon}


#: The wrapper keys of a history.
HISTORY_KEYS = ("past_actions", "steps_left", "time_step")


def history_options(wrapper: dict[str, Any] | None, *, error: type[Exception] = ValueError, source: str = "") -> HistoryOptions:
    """The :class:`HistoryOptions` of a wrapper's ``past_actions``, ``steps_left`` and
    ``time_step`` (0 when absent), checked (errors of class ``error``, the names prefixed with
    ``source``): one clock at most."""
    w = wrapper or {}
    k = check_int(f"{source}past_actions", w.get("past_actions", 0), 0, MAX_ACTIONS, what=f"an integer from 0 to {MAX_ACTIONS} (how many past actions are seen)",
                  error=error)
    left, time = (check_int(f"{source}{name}", w.get(name, 0), 0, MAX_HORIZON,
                            what=f"an integer from 0 (none) to {MAX_HORIZON} (the horizon that scales the {what})", error=error)
                  for name, what in (("steps_left", "steps left"), ("time_step", "time step")))
    if left and time:
        raise error(f"{source}steps_left and time_step are two clocks: give one of them")
    return HistoryOptions(k, left or time, bool(time))


def episode_limit(env: Any) -> int:
    """The number of steps after which an episode of ``env`` (one environment, or a native vector
    env) ends at the latest: its ``episode_length`` (the research protocol) or its step limit
    (``max_episode_steps``), the smaller."""
    inner = getattr(env, "unwrapped", env)
    length = getattr(inner, "episode_length", None) or getattr(getattr(inner, "template", None), "episode_length", None)
    spec = getattr(env, "spec", None) or getattr(inner, "spec", None)
    limit = getattr(inner, "max_episode_steps", None) or getattr(spec, "max_episode_steps", None)
    found = [int(x) for x in (length, limit) if x]
    if not found:
        raise ValueError("steps_left needs an episode that ends: give the environment an episode_length or a step limit")
    return min(found)


def acting_history(wrapper: dict[str, Any] | None, n_actions: int, env_id: str | None, env_kwargs: dict[str, Any] | None,
                   path: Any = None) -> "History | None":
    """The :class:`History` a learned policy keeps while it acts, for a model trained with the
    wrapper options ``wrapper`` (None when it sees none): its steps left count down from the
    episode length of the environment it acts in (``env_kwargs``' ``episode_length``, else the
    registered step limit of ``env_id``); its time step counts from the episode's start."""
    opts = history_options(wrapper)
    if not opts.any:
        return None
    limit = None
    if opts.needs_limit:
        limit = (env_kwargs or {}).get("episode_length") or (gym.spec(env_id).max_episode_steps if env_id else None)
        if not limit:
            raise ValueError(f"{path or 'this model'} sees the steps left: give env_id= or env_kwargs with an episode_length")
    return History(n_actions, options=opts, limit=limit)


def with_history_space(wrapper: dict[str, Any] | None, n_actions: int, space: spaces.Space) -> spaces.Space:
    """``space`` with the history of a model trained with ``wrapper`` appended (as it is, without one)."""
    opts = history_options(wrapper)
    return History(n_actions, options=opts, limit=1).space(space) if opts.any else space


class History:
    """The last ``actions`` actions and the clock of ``n`` episodes of at most ``limit`` steps:
    the steps left, or with ``time_step`` the time step (``limit`` then unused), scaled by ``horizon``;
    or all of these from ``options`` (:class:`HistoryOptions`).

    >>> h = History(n_actions=3, actions=2, horizon=10, limit=15)
    >>> h.record(np.array([2])); h.features()
    array([[0., 0., 1., 0., 0., 0., 1.]], dtype=float32)
    >>> h = History(n_actions=3, horizon=10, time_step=True)
    >>> h.record(np.array([2])); h.features()
    array([[0.9]], dtype=float32)
    """

    def __init__(self, n_actions: int, *, actions: int = 0, horizon: int = 0, limit: int | None = None, n: int = 1,
                 time_step: bool = False, options: HistoryOptions | None = None) -> None:
        if options is None:
            options = HistoryOptions(int(actions), int(horizon), bool(time_step))
        actions, horizon, time_step = options
        self.n_actions, self.actions, self.horizon, self.n = int(n_actions), int(actions), int(horizon), int(n)
        self.time_step = bool(time_step)
        if options.needs_limit and not limit:
            raise ValueError("steps_left needs the episodes' step limit")
        self.limit = int(limit or 0)
        self.size = self.actions * self.n_actions + (1 if self.horizon else 0)
        self._past = np.full((self.n, self.actions), -1, dtype=np.int64)  # -1: no action yet
        self._elapsed = np.zeros(self.n, dtype=np.int64)

    def reset(self, which: np.ndarray | None = None) -> None:
        """Start the episodes ``which`` (a bool mask or indices; default all) afresh."""
        idx = slice(None) if which is None else which
        self._past[idx] = -1
        self._elapsed[idx] = 0

    def record(self, actions: np.ndarray) -> None:
        """One step of every episode, with these actions."""
        if self.actions:
            self._past[:, 1:] = self._past[:, :-1]
            self._past[:, 0] = np.asarray(actions).reshape(self.n)
        self._elapsed += 1

    def features(self) -> np.ndarray:
        """``(n, size)`` float32: the past actions one-hot (newest first), then the clock."""
        out = np.zeros((self.n, self.size), dtype=np.float32)
        if self.actions:
            rows, slots = np.nonzero(self._past >= 0)
            out[rows, slots * self.n_actions + self._past[rows, slots]] = 1.0
        if self.horizon:
            left = np.clip((self.horizon if self.time_step else self.limit) - self._elapsed, 0, self.horizon)
            out[:, -1] = left / self.horizon
        return out

    def space(self, inner: spaces.Space) -> spaces.Space:
        """``inner`` with the features appended (flat Box) or under ``"history"`` (Dict)."""
        if isinstance(inner, spaces.Dict):
            if "history" in inner.spaces:
                raise ValueError("the observation already has a 'history' key")
            return spaces.Dict({**inner.spaces, "history": spaces.Box(0.0, 1.0, shape=(self.size,), dtype=np.float32)})
        if isinstance(inner, spaces.Box) and len(inner.shape) == 1 and inner.dtype == np.float32:
            return spaces.Box(np.concatenate([inner.low, np.zeros(self.size, np.float32)]),
                              np.concatenate([inner.high, np.ones(self.size, np.float32)]), dtype=np.float32)
        raise ValueError(f"a history is appended to a flat float32 Box or a Dict observation, not {inner}")

    def attach(self, obs: Any, features: np.ndarray | None = None, *, batched: bool = True) -> Any:
        """``obs`` (a batch of ``n``, or one with ``batched=False``) with ``features`` (default: now's)."""
        f = self.features() if features is None else features
        if not batched:
            f = f[0]
        if isinstance(obs, dict):
            return {**obs, "history": f}
        return np.concatenate([np.asarray(obs, dtype=np.float32), f], axis=-1)


class HistoryWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """One environment's observations with its :class:`History` appended (see the module)."""

    def __init__(self, env: gym.Env, *, past_actions: int = 0, steps_left: int = 0, time_step: int = 0) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, past_actions=past_actions, steps_left=steps_left, time_step=time_step)
        gym.Wrapper.__init__(self, env)
        if not isinstance(env.action_space, spaces.Discrete):
            raise ValueError(f"HistoryWrapper needs a Discrete action space, got {env.action_space}")
        opts = history_options({"past_actions": past_actions, "steps_left": steps_left, "time_step": time_step})
        self.history = History(int(env.action_space.n), options=opts,
                               limit=episode_limit(env) if opts.needs_limit else None)
        self.observation_space = self.history.space(env.observation_space)

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.history.reset()
        return self.history.attach(obs, batched=False), info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.history.record(np.array([int(action)]))
        return self.history.attach(obs, batched=False), reward, terminated, truncated, info
