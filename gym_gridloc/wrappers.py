"""Wrappers: :class:`HMMBeliefWrapper` appends the exact forward-filter belief to observations."""

from __future__ import annotations

import warnings
from typing import Any, Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from gym_gridloc.core.errors import ImpossibleObservationError
from gym_gridloc.core.model import GridModel
from gym_gridloc.core.validation import check_choice
from gym_gridloc.filter import ForwardFilter


_RESET_HINT = "pass on_impossible='reset' to HMMBeliefWrapper to restart the belief from the prior instead"


def check_belief_option(belief: Any, allowed: Sequence[Any]) -> Any:
    """The ``belief=`` keyword (which belief goes into the observation), shared with
    :class:`~gym_gridloc.HMMBeliefWrapper`.  ``True``/``False`` are deprecated spellings of
    ``"exact"``/``None``."""
    if isinstance(belief, bool):
        warnings.warn(f"belief={belief} is deprecated: use belief={'exact' if belief else None!r}",
                      DeprecationWarning, stacklevel=3)
        belief = "exact" if belief else None
    return check_choice("belief", belief, allowed)


def belief_observation_space(model: GridModel, inner: spaces.Space, *, flatten: bool = False,
                             full_state: bool = False, key: str = "belief") -> spaces.Space:
    """The observation space of ``inner`` with the belief of ``model`` appended, as
    :class:`HMMBeliefWrapper` (and the native vector env) give it."""
    shape = model.belief_shape if full_state else model.shape
    belief_space = spaces.Box(0.0, 1.0, shape=shape, dtype=np.float32)
    if flatten:
        if isinstance(inner, spaces.Dict):
            raise ValueError("flatten=True needs a non-Dict observation space")
        if inner != model.sensor.observation_space:
            raise ValueError(f"flatten=True encodes the sensor's {model.sensor.observation_space}, but the observations are {inner}")
        n = model.sensor.encoded_size + int(np.prod(shape))
        return spaces.Box(0.0, 1.0, shape=(n,), dtype=np.float32)
    if isinstance(inner, spaces.Dict):
        if key in inner.spaces:
            raise ValueError(f"the observation space already has a key {key!r}; pass key=... to choose another")
        return spaces.Dict({**inner.spaces, key: belief_space})
    if key == "observation":
        raise ValueError("key='observation' would replace the sensor reading (the Dict keeps it under 'observation'); choose another key")
    return spaces.Dict({"observation": inner, key: belief_space})


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
        self.belief = check_belief_option(belief, ("exact", "particles"))
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
        if not isinstance(key, str) or not key:
            raise TypeError(f"key must be a non-empty string, got {key!r}")
        self.observation_space = belief_observation_space(model, inner, flatten=self.flatten, full_state=self.full_state, key=key)
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
            reading = self.model.sensor.to_reading(observation)
            return np.concatenate([self.model.sensor.encode(np.array([reading]))[0], belief.ravel()])
        if isinstance(observation, dict):
            return {**observation, self.key: belief}
        return {"observation": observation, self.key: belief}
