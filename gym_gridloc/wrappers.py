"""Wrappers: :class:`HMMBeliefWrapper` appends the exact forward-filter belief to observations."""

from __future__ import annotations

import warnings
from typing import Any, Callable, Sequence, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from gym_gridloc.core.errors import ImpossibleObservationError
from gym_gridloc.core.model import GridModel
from gym_gridloc.core.validation import check_choice
from gym_gridloc.filter import ForwardFilter
from gym_gridloc.lookahead import lookahead_features
from gym_gridloc.particles import ParticleFilter


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


def map_channels(model: GridModel) -> np.ndarray:
    """The map as image channels ``(C, H, W)`` float32 in {0, 1}: the free cells, then (for maps
    whose cells carry labels, such as colours) one channel per label."""
    grid = model.grid
    k = len(grid.symbols)
    return np.stack([grid.free, *(grid.labels == i for i in range(k if k > 1 else 0))]).astype(np.float32)


def check_lookahead(lookahead: Any) -> int:
    """The ``lookahead=`` keyword: 0 (none), 1 or 2 (rows of :func:`lookahead_features`)."""
    if isinstance(lookahead, (bool, np.bool_)) or not isinstance(lookahead, (int, np.integer)) or lookahead not in (0, 1, 2):
        raise ValueError(f"lookahead must be 0, 1 or 2 (the rows of expected entropies per action), got {lookahead!r}")
    return int(lookahead)


def belief_observation_space(model: GridModel, inner: spaces.Space, *, flatten: bool = False,
                             full_state: bool = False, key: str = "belief", map: bool = False,
                             lookahead: int = 0) -> spaces.Space:
    """The observation space of ``inner`` with the belief of ``model`` appended (and the map, with
    ``map``; the expected entropies per action, with ``lookahead``), as :class:`HMMBeliefWrapper`
    and the native vector env give it."""
    shape = model.belief_shape if full_state else model.shape
    map_shape = map_channels(model).shape
    look_shape = (lookahead, model.n_actions)
    if flatten:
        if isinstance(inner, spaces.Dict):
            raise ValueError("flatten=True needs a non-Dict observation space")
        if inner != model.sensor.observation_space:
            raise ValueError(f"flatten=True encodes the sensor's {model.sensor.observation_space}, but the observations are {inner}")
        n = (model.sensor.encoded_size + int(np.prod(shape)) + (int(np.prod(map_shape)) if map else 0)
             + int(np.prod(look_shape)))
        return spaces.Box(0.0, 1.0, shape=(n,), dtype=np.float32)
    parts = ((key, shape, True), ("map", map_shape, map), ("lookahead", look_shape, lookahead))
    if not isinstance(key, str) or not key:
        raise TypeError(f"key must be a non-empty string, got {key!r}")
    if (key == "map" and map) or (key == "lookahead" and lookahead):  # one of them would be dropped
        raise ValueError(f"key={key!r} is also the key of the {key} observation ({key}=...): choose another key for the belief")
    extra = {name: spaces.Box(0.0, 1.0, shape=s, dtype=np.float32) for name, s, wanted in parts if wanted}
    if isinstance(inner, spaces.Dict):
        clash = sorted(set(extra) & set(inner.spaces))
        if clash:
            raise ValueError(f"the observation space already has the key(s) {clash}; pass key=... to choose another")
        return spaces.Dict({**inner.spaces, **extra})
    if "observation" in extra:
        raise ValueError("key='observation' would replace the sensor reading (the Dict keeps it under 'observation'); choose another key")
    return spaces.Dict({"observation": inner, **extra})


def batch_observation(model: GridModel, observations: Any, readings: np.ndarray, beliefs: np.ndarray, *,
                      flatten: bool, key: str = "belief", maps: np.ndarray | None = None,
                      lookahead: np.ndarray | None = None):
    """N observations with their beliefs appended, as :func:`belief_observation_space` lays
    them out: ``observations`` are the N sensor observations (a batch, or a dict of batches),
    ``readings`` their reading indices, ``beliefs`` float32 ``(N, ...)``, ``maps`` ``(N, C, H, W)``
    map channels or None, ``lookahead`` ``(N, depth, A)`` expected entropies or None.  Without
    ``flatten`` the layout does not depend on N: one observation, its belief, its map and its
    expected entropies (no batch axis) give the single observation (``readings`` unused)."""
    if flatten:
        n = readings.shape[0]
        parts = [model.sensor.encode(readings), beliefs.reshape(n, -1)]
        parts += [x.reshape(n, -1) for x in (maps, lookahead) if x is not None]
        return np.concatenate(parts, axis=1)
    extra = {key: beliefs}
    if maps is not None:
        extra["map"] = maps
    if lookahead is not None:
        extra["lookahead"] = lookahead
    if isinstance(observations, dict):
        return {**observations, **extra}
    return {"observation": observations, **extra}


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
    map:
        If True, the observation also carries the map of the episode (``"map"``: channels
        ``(C, H, W)`` of :func:`map_channels`: the free cells, and the colours as one channel each
        on a colour grid), for policies that must read the map (random maps); with ``flatten``
        they are appended to the vector.
    lookahead:
        0 (default), 1 or 2: the observation also carries ``"lookahead"``, ``(lookahead, A)``
        float32: the exact expected entropy of the position (of the full state with
        ``full_state``) after each first action, one step ahead (row 0, what ``greedy``
        minimises) and with the best second action (row 1, what ``greedy2`` minimises), as a
        fraction of ``log2`` of the grid's cell (state) count (:func:`gym_gridloc.lookahead.lookahead_features`).
        Information features for learned policies; with ``flatten`` they are appended to the vector.
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
        map: bool = False,
        lookahead: int = 0,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self, model=model, flatten=flatten, full_state=full_state, key=key, on_impossible=on_impossible,
            belief=belief, n_particles=n_particles, resample_threshold=resample_threshold, map=map,
            lookahead=lookahead,
        )
        gym.ObservationWrapper.__init__(self, env)
        #: No model given: follow the environment's, also when it redraws its map at reset.
        self._follows_env = model is None
        self._filter_args = {"n_particles": n_particles, "resample_threshold": resample_threshold}
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
        for name, value in (("flatten", flatten), ("full_state", full_state), ("map", map)):
            if not isinstance(value, (bool, np.bool_)):
                raise TypeError(f"{name} must be True or False, got {value!r}")
            setattr(self, name, bool(value))
        self.lookahead = check_lookahead(lookahead)
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
        self.observation_space = belief_observation_space(model, inner, flatten=self.flatten, full_state=self.full_state,
                                                          key=key, map=self.map, lookahead=self.lookahead)
        self._reset_flag = False

    # -- filtering -------------------------------------------------------------------------------
    def _make_filter(self, model: GridModel, rng: np.random.Generator | None = None):
        return (ParticleFilter(model, **self._filter_args, rng=rng) if self.belief == "particles"
                else ForwardFilter(model))

    def _sensor_obs(self, observation):
        return observation["observation"] if isinstance(observation, dict) else observation

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        env_model = getattr(self.env.unwrapped, "model", None) if self._follows_env else None
        if env_model is not None and env_model is not self.model:  # the map was redrawn at reset
            self.model = env_model
            # The particles' stream (with particles) goes on, seeded or not, across maps.
            self.filter = self._make_filter(env_model, rng=getattr(self.filter, "rng", None))
        if seed is not None and self.belief == "particles":  # a stream of its own, fixed by the seed
            self.filter.seed(np.random.SeedSequence(seed, spawn_key=(1,)))
        info = self._filtered(lambda: self.filter.reset(self._sensor_obs(obs)), info)
        return self.observation(obs), info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        reading = self._sensor_obs(obs)
        info = self._filtered(lambda: self.filter.step(action, reading), info, reading)
        return self.observation(obs), reward, terminated, truncated, info

    def _filtered(self, update: Callable[[], Any], info: dict[str, Any], retry: Any = None) -> dict[str, Any]:
        """Run ``update`` (the filter's reset or step with an observation).  When the model calls
        the observation impossible: raise, or (``on_impossible="reset"``) restart the belief from
        the prior, updated with ``retry`` when that is possible, and say so in ``info["belief_reset"]``."""
        self._reset_flag = False
        try:
            update()
        except ImpossibleObservationError as exc:
            if self.on_impossible == "raise":
                raise ImpossibleObservationError(f"{exc}; {_RESET_HINT}") from exc
            try:
                self.filter.reset(retry)
            except ImpossibleObservationError:
                self.filter.reset()
            self._reset_flag = True
        return {**info, "belief_reset": self._reset_flag} if self.on_impossible == "reset" else info

    # -- the observation -------------------------------------------------------------------------
    def belief_array(self) -> np.ndarray:
        """The current belief as float32, (H, W) or (L, H, W) with ``full_state``."""
        b = (self.filter.full_belief if self.full_state else self.filter.position_belief).astype(np.float32)
        return np.clip(b, 0.0, 1.0, out=b)

    def lookahead_array(self) -> np.ndarray | None:
        """The expected entropies per action of the current belief ``(lookahead, A)`` (None
        without ``lookahead``)."""
        if not self.lookahead:
            return None
        return lookahead_features(self.model, self.filter.full_belief, self.lookahead, pose=self.full_state)

    def observation(self, observation: Any) -> dict[str, Any] | np.ndarray:
        maps = map_channels(self.model) if self.map else None
        look = self.lookahead_array()
        if not self.flatten:
            return batch_observation(self.model, observation, None, self.belief_array(), flatten=False, key=self.key,
                                     maps=maps, lookahead=look)
        reading = np.array([self.model.sensor.to_reading(self._sensor_obs(observation))])
        return batch_observation(self.model, None, reading, self.belief_array()[None], flatten=True,
                                 maps=None if maps is None else maps[None],
                                 lookahead=None if look is None else look[None])[0]
