"""Wrappers: :class:`HMMBeliefWrapper` appends the exact forward-filter belief to observations.

The observation's space and encoding are :mod:`gym_gridloc.observation`'s (``map_channels``,
``belief_observation_space``, ``batch_observation``, ``check_lookahead`` and ``check_belief_option``
are importable from here too)."""

from __future__ import annotations

from typing import Any, Callable, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from gym_gridloc.core.errors import ImpossibleObservationError
from gym_gridloc.core.model import GridModel
from gym_gridloc.core.validation import check_choice
from gym_gridloc.filter import ForwardFilter
from gym_gridloc.lookahead import lookahead_features
from gym_gridloc.observation import (BeliefObservation, batch_observation, belief_observation_space,  # noqa: F401
                                     check_belief_option, check_lookahead, map_channels, observed_belief)
from gym_gridloc.particles import ParticleFilter


_RESET_HINT = "pass on_impossible='reset' to HMMBeliefWrapper to restart the belief from the prior instead"


class HMMBeliefWrapper(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Append the exact forward-filter (HMM) belief over positions to each observation.

    The belief is computed from the actions this wrapper passes on and the observations it
    receives, nothing else: the wrapped environment's hidden state is never read.  When the
    wrapper's model is the environment's (the default) and the belief is exact, that belief is
    the environment's own posterior (its referee, :attr:`GridLocEnv.exact_filter
    <gym_gridloc.GridLocEnv.exact_filter>`), served as it is: the filter steps once per step.  The
    wrapper keeps a filter of its own only for another model (mismatch studies), for particles,
    or for an environment without one; :attr:`filter` is the one in use.

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
        self._inner = env.unwrapped
        if model is None:
            model = getattr(self._inner, "model", None)
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
        #: The observation's space and encoding (:class:`gym_gridloc.observation.BeliefObservation`).
        self.builder = BeliefObservation(model, inner, flatten=self.flatten, full_state=self.full_state, key=key,
                                         map=self.map, lookahead=self.lookahead)
        self.observation_space = self.builder.space
        self._shared = self._shares()
        self._filter = None if self._shared else self._make_filter(model)
        self._reset_flag = False

    # -- filtering -------------------------------------------------------------------------------
    def _shares(self) -> bool:
        """True when the belief is the environment's exact posterior: an exact belief on the
        environment's own model, and an environment that keeps one."""
        return (self.belief == "exact" and self.model is getattr(self._inner, "model", None)
                and isinstance(getattr(self._inner, "exact_filter", None), ForwardFilter))

    @property
    def filter(self) -> ForwardFilter | ParticleFilter:
        """The filter whose belief the observations carry: the environment's exact posterior
        (read it; stepping it is the environment's business) when the wrapper's model is the
        environment's, else the wrapper's own (another model, particles)."""
        return self._inner.exact_filter if self._shared else self._filter

    def _make_filter(self, model: GridModel, rng: np.random.Generator | None = None):
        return (ParticleFilter(model, **self._filter_args, rng=rng) if self.belief == "particles"
                else ForwardFilter(model))

    def _sensor_obs(self, observation):
        return observation["observation"] if isinstance(observation, dict) else observation

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        env_model = getattr(self._inner, "model", None) if self._follows_env else None
        if env_model is not None and env_model is not self.model:  # the map was redrawn at reset
            self.model = env_model
        self._shared = self._shares()
        if not self._shared and (self._filter is None or self._filter.model is not self.model):
            # The particles' stream (with particles) goes on, seeded or not, across maps.
            self._filter = self._make_filter(self.model, rng=getattr(self._filter, "rng", None))
        if self._shared:
            self._reset_flag = False
            return self._served(obs), (info if self.on_impossible == "raise" else {**info, "belief_reset": False})
        if seed is not None and self.belief == "particles":  # a stream of its own, fixed by the seed
            self._filter.seed(np.random.SeedSequence(seed, spawn_key=(1,)))
        info = self._filtered(lambda: self._filter.reset(self._sensor_obs(obs)), info)
        return self.observation(obs), info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self._shared:  # the environment's posterior has taken this step already
            if self.on_impossible == "reset":
                info = {**info, "belief_reset": False}
            return self._served(obs), reward, terminated, truncated, info
        reading = self._sensor_obs(obs)
        info = self._filtered(lambda: self._filter.step(action, reading), info, reading)
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
                self._filter.reset(retry)
            except ImpossibleObservationError:
                self._filter.reset()
            self._reset_flag = True
        return {**info, "belief_reset": self._reset_flag} if self.on_impossible == "reset" else info

    # -- the observation -------------------------------------------------------------------------
    def _served(self, observation: Any):
        """The observation with the environment's posterior (its reading index known: no round trip)."""
        inner = self._inner
        return self.builder.one(self.model, observation, inner.exact_filter.belief_view, reading=inner.last_reading)

    def belief_array(self) -> np.ndarray:
        """The current belief as float32, (H, W) or (L, H, W) with ``full_state``."""
        f = self.filter
        return observed_belief(f.full_belief if self.full_state else f.position_belief[None], self.full_state)

    def lookahead_array(self) -> np.ndarray | None:
        """The expected entropies per action of the current belief ``(lookahead, A)`` (None
        without ``lookahead``)."""
        if not self.lookahead:
            return None
        return lookahead_features(self.model, self.filter.full_belief, self.lookahead, pose=self.full_state)

    def observation(self, observation: Any) -> dict[str, Any] | np.ndarray:
        f = self.filter
        position = None if self._shared or self.full_state else f.position_belief
        return self.builder.one(self.model, observation, f.full_belief, position=position)


class PreviousActionWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """The environment's observation, flattened, with the previous action beside it, one-hot.

    For memory-based agents that read the raw readings (no belief), e.g. RecurrentPPO: with
    noisy moves and sampled actions, a recurrent policy cannot tell from the readings alone which
    action it took, so the standard practice is to feed it back.  The observation is one
    ``Box(0, 1, (n + A + 1,), float32)`` vector: the original observation as
    :func:`gymnasium.spaces.flatten` gives it (one-hot for ``Discrete``, the bits for
    ``MultiBinary``), then the previous action one-hot over ``A + 1`` slots, the last slot meaning
    "no action yet" (the first observation of an episode).  The action space must be ``Discrete``.

    >>> import gymnasium as gym, gym_gridloc
    >>> env = gym_gridloc.PreviousActionWrapper(gym.make("ColourGrid-v0"))
    >>> env.observation_space.shape   # 4 colours + 4 actions + "none yet"
    (9,)
    """

    def __init__(self, env: gym.Env) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        self.observation_space = previous_action_space(env.observation_space, env.action_space)
        self._raw_space = env.observation_space
        self._n_actions = int(env.action_space.n)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        return with_previous_action(self._raw_space, self._n_actions, obs, None), info

    def step(self, action: Any) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return with_previous_action(self._raw_space, self._n_actions, obs, action), reward, terminated, truncated, info


def previous_action_space(observation_space: spaces.Space, action_space: spaces.Space) -> spaces.Box:
    """The observation space of :class:`PreviousActionWrapper` over these spaces."""
    if not isinstance(action_space, spaces.Discrete):
        raise TypeError(f"PreviousActionWrapper needs a Discrete action space, got {action_space}")
    n = spaces.flatdim(observation_space) + int(action_space.n) + 1
    return spaces.Box(0.0, 1.0, (n,), np.float32)


def with_previous_action(observation_space: spaces.Space, n_actions: int, observation: Any, previous: Any) -> np.ndarray:
    """:class:`PreviousActionWrapper`'s observation: ``observation`` flattened, then ``previous``
    (an action in ``0..n_actions-1``, or ``None`` at an episode's start) one-hot over
    ``n_actions + 1`` slots.  The one encoding of the wrapper and of the policies that act on it."""
    flat = spaces.flatten(observation_space, observation)
    out = np.zeros(flat.shape[0] + n_actions + 1, dtype=np.float32)
    out[: flat.shape[0]] = flat
    slot = n_actions if previous is None else int(previous)  # the last slot: no action yet
    if previous is not None and not 0 <= slot < n_actions:
        raise ValueError(f"previous action must be in 0..{n_actions - 1} or None, got {previous!r}")
    out[flat.shape[0] + slot] = 1.0
    return out
