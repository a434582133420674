"""Wrappers: :class:`HMMBeliefWrapper` appends the exact forward-filter belief to observations."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from gym_gridloc.core.errors import ImpossibleObservationError
from gym_gridloc.core.model import GridModel
from gym_gridloc.core.validation import check_choice
from gym_gridloc.filter import ForwardFilter


_RESET_HINT = "pass on_impossible='reset' to HMMBeliefWrapper to restart the belief from the prior instead"


def _encode(space: spaces.Space, obs: Any) -> np.ndarray:
    """An observation as a float32 vector in [0, 1] (one-hot for Discrete)."""
    if isinstance(space, spaces.Discrete):
        out = np.zeros(space.n, dtype=np.float32)
        out[int(obs) - int(space.start)] = 1.0
        return out
    if isinstance(space, spaces.MultiBinary):
        return np.asarray(obs, dtype=np.float32).reshape(-1)
    raise TypeError(f"flatten=True cannot encode an observation space {space}")


def _encoded_size(space: spaces.Space) -> int:
    if isinstance(space, spaces.Discrete):
        return int(space.n)
    if isinstance(space, spaces.MultiBinary):
        return int(np.prod(space.shape))
    raise TypeError(f"flatten=True needs a Discrete or MultiBinary observation space, got {space}")


class HMMBeliefWrapper(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Append the exact forward-filter (HMM) belief over positions to each observation.

    The belief is computed from the actions this wrapper passes on and the observations it
    receives, nothing else: the wrapped environment's hidden state is never read.

    Parameters
    ----------
    env:
        A gym_gridloc environment (or any environment with a compatible ``model``).
    model:
        The filter's model; by default the environment's own (``env.unwrapped.model``).  A
        different model gives model mismatch.
    flatten:
        If True, the observation is one ``Box(0, 1, (n,), float32)`` vector: the original
        observation (one-hot for ``Discrete``, the bits for ``MultiBinary``) followed by the
        flattened belief.  For MLP policies.
    full_state:
        If True, the belief is over the full hidden state, shape (L, H, W) (e.g. heading x H x W
        for the ring sensor's seed dynamics), instead of positions (H, W).
    key:
        The key of the belief in the Dict observation (default ``"belief"``).
    on_impossible:
        What to do with an observation the model calls impossible: ``"raise"`` (default) raises
        :class:`ImpossibleObservationError`; ``"reset"`` restarts the belief from the prior
        (updated with the observation when that is possible) and sets ``info["belief_reset"]``.
    belief:
        ``"exact"`` (default): the forward filter.  ``"particles"``: the weighted histogram of a
        :class:`gym_gridloc.ParticleFilter` with ``n_particles`` particles and
        ``resample_threshold``, in place of the exact belief (same shapes).  Its random generator
        is reseeded from the seed passed to ``reset``.
    """

    def __init__(
        self,
        env: gym.Env,
        model: GridModel | None = None,
        *,
        flatten: bool = False,
        full_state: bool = False,
        key: str = "belief",
        on_impossible: str = "raise",
        belief: str = "exact",
        n_particles: int = 1000,
        resample_threshold: float = 0.5,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self, model=model, flatten=flatten, full_state=full_state, key=key, on_impossible=on_impossible,
            belief=belief, n_particles=n_particles, resample_threshold=resample_threshold,
        )
        gym.ObservationWrapper.__init__(self, env)
        #: No model given: follow the environment's, also when it redraws its map at reset.
        self._follows_env = model is None
        self._filter_args = (n_particles, resample_threshold)
        if model is None:
            model = getattr(env.unwrapped, "model", None)
            if not isinstance(model, GridModel):
                raise TypeError(
                    "HMMBeliefWrapper needs a model: the environment has no GridModel at "
                    "env.unwrapped.model, so pass model=..."
                )
        elif not isinstance(model, GridModel):
            raise TypeError(f"model must be a GridModel, got {type(model).__name__}")
        self.on_impossible = check_choice("on_impossible", on_impossible, ("raise", "reset"))
        self.model = model
        self.belief = check_choice("belief", belief, ("exact", "particles"))
        self.filter = self._make_filter(model)
        self.flatten = bool(flatten)
        self.full_state = bool(full_state)
        self.key = key
        inner = env.observation_space
        if isinstance(env.action_space, spaces.Discrete) and env.action_space.n != model.n_actions:
            raise ValueError(
                f"the model has {model.n_actions} actions but the environment's action space is {env.action_space}"
            )
        sensor_space = model.sensor.observation_space
        if not isinstance(inner, spaces.Dict) and inner != sensor_space:
            raise ValueError(
                f"the model's sensor emits {sensor_space} but the environment's observation space is {inner}"
            )
        shape = model.belief_shape if self.full_state else model.shape
        belief_space = spaces.Box(0.0, 1.0, shape=shape, dtype=np.float32)
        if self.flatten:
            if isinstance(inner, spaces.Dict):
                raise ValueError("flatten=True needs a non-Dict observation space")
            n = _encoded_size(inner) + int(np.prod(shape))
            self.observation_space = spaces.Box(0.0, 1.0, shape=(n,), dtype=np.float32)
        elif isinstance(inner, spaces.Dict):
            if key in inner.spaces:
                raise ValueError(f"the observation space already has a key {key!r}; pass key=... to choose another")
            self.observation_space = spaces.Dict({**inner.spaces, key: belief_space})
        else:
            self.observation_space = spaces.Dict({"observation": inner, key: belief_space})
        self._reset_flag = False

    # -- filtering -------------------------------------------------------------------------------
    def _make_filter(self, model: GridModel):
        if self.belief == "particles":
            from gym_gridloc.particles import ParticleFilter

            n, threshold = self._filter_args
            return ParticleFilter(model, n, resample_threshold=threshold)
        return ForwardFilter(model)

    def _sensor_obs(self, observation):
        if isinstance(observation, dict):
            return observation["observation"]
        return observation

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        env_model = getattr(self.env.unwrapped, "model", None) if self._follows_env else None
        if env_model is not None and env_model is not self.model:  # the map was redrawn at reset
            self.model = env_model
            self.filter = self._make_filter(env_model)
        self._reset_flag = False
        if seed is not None and self.belief == "particles":  # a stream of its own, fixed by the seed
            self.filter.seed(np.random.SeedSequence(seed, spawn_key=(1,)))
        try:
            self.filter.reset(self._sensor_obs(obs))
        except ImpossibleObservationError as exc:
            if self.on_impossible == "raise":
                raise ImpossibleObservationError(f"{exc}; {_RESET_HINT}") from exc
            self.filter.reset()
            self._reset_flag = True
        if self.on_impossible == "reset":
            info = {**info, "belief_reset": self._reset_flag}
        return self.observation(obs), info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._reset_flag = False
        try:
            self.filter.step(action, self._sensor_obs(obs))
        except ImpossibleObservationError as exc:
            if self.on_impossible == "raise":
                raise ImpossibleObservationError(f"{exc}; {_RESET_HINT}") from exc
            try:
                self.filter.reset(self._sensor_obs(obs))
            except ImpossibleObservationError:
                self.filter.reset()
            self._reset_flag = True
        if self.on_impossible == "reset":
            info = {**info, "belief_reset": self._reset_flag}
        return self.observation(obs), reward, terminated, truncated, info

    # -- the observation -------------------------------------------------------------------------
    def belief_array(self) -> np.ndarray:
        """The current belief as float32, (H, W) or (L, H, W) with ``full_state``."""
        b = self.filter.full_belief if self.full_state else self.filter.position_belief
        b = b.astype(np.float32)
        np.clip(b, 0.0, 1.0, out=b)
        return b

    def observation(self, observation):
        belief = self.belief_array()
        if self.flatten:
            return np.concatenate([_encode(self.env.observation_space, observation), belief.ravel()])
        if isinstance(observation, dict):
            return {**observation, self.key: belief}
        return {"observation": observation, self.key: belief}
