"""The belief observation: its space and its encoding, written once.

:class:`BeliefObservation` is the one builder of what a policy sees next to the sensor reading:
the belief (over positions, or the full hidden state with ``full_state``), the map's channels
(``map``) and the expected entropies per action (``lookahead``), as a Dict or one flat float32
vector (``flatten``).  :class:`~gym_gridloc.HMMBeliefWrapper` (one observation), the native vector
environment (N at once) and the learned policies of ``gym_gridloc_agents`` (the observation their
model was trained on) all build it here.
"""

from __future__ import annotations

import warnings
import weakref
from typing import Any, Sequence

import numpy as np
from gymnasium import spaces

from gym_gridloc import kernels
from gym_gridloc.core.model import GridModel
from gym_gridloc.core.validation import check_choice, check_int
from gym_gridloc.lookahead import lookahead_features

__all__ = ["BeliefObservation", "observed_belief", "belief_observation_space", "batch_observation", "check_lookahead",
           "check_belief_option", "map_channels"]


def map_channels(model: GridModel) -> np.ndarray:
    """The map as image channels ``(C, H, W)`` float32 in {0, 1}: the free cells, then (for maps
    whose cells carry labels, such as colours) one channel per label."""
    grid = model.grid
    k = len(grid.symbols)
    return np.stack([grid.free, *(grid.labels == i for i in range(k if k > 1 else 0))]).astype(np.float32)


_CHANNELS: "weakref.WeakKeyDictionary[GridModel, np.ndarray]" = weakref.WeakKeyDictionary()


def _channels(model: GridModel) -> np.ndarray:
    """:func:`map_channels`, computed once per model (read-only: callers copy what they hand out)."""
    ch = _CHANNELS.get(model)
    if ch is None:
        ch = _CHANNELS[model] = map_channels(model)
        ch.flags.writeable = False
    return ch


def check_belief_option(belief: Any, allowed: Sequence[Any]) -> Any:
    """The ``belief=`` keyword (which belief goes into the observation) of
    :class:`~gym_gridloc.HMMBeliefWrapper` and the native vector environment, one of ``allowed``.
    ``True``/``False`` are deprecated spellings of ``"exact"``/``None``."""
    if isinstance(belief, bool):
        warnings.warn(f"belief={belief} is deprecated: use belief={'exact' if belief else None!r}",
                      DeprecationWarning, stacklevel=3)
        belief = "exact" if belief else None
    return check_choice("belief", belief, allowed)


def check_lookahead(lookahead: Any) -> int:
    """The ``lookahead=`` keyword: 0 (none), 1 or 2 (rows of :func:`lookahead_features`)."""
    return check_int("lookahead", lookahead, 0, 2, what="0, 1 or 2 (the rows of expected entropies per action)", error=ValueError)


def belief_observation_space(model: GridModel, inner: spaces.Space, *, flatten: bool = False,
                             full_state: bool = False, key: str = "belief", map: bool = False,
                             lookahead: int = 0) -> spaces.Space:
    """The observation space of ``inner`` with the belief of ``model`` appended (and the map, with
    ``map``; the expected entropies per action, with ``lookahead``), as :class:`BeliefObservation`
    lays it out."""
    shape = model.belief_shape if full_state else model.shape
    map_shape = _channels(model).shape
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


def observed_belief(full: np.ndarray, full_state: bool) -> np.ndarray:
    """The observed belief of hidden-state beliefs ``(..., L, H, W)``: float32 in [0, 1], over
    positions (``(..., H, W)``) unless ``full_state``."""
    if full.ndim == 3 and full.dtype.char == "d":  # one small belief: one compiled pass, the same numbers
        fast = kernels.compiled(full.size)
        if fast is not None:
            out = np.empty(full.shape if full_state else full.shape[1:], dtype=np.float32)
            fast.observed32(full.reshape(-1), 1 if full_state else full.shape[0], out.reshape(-1))
            return out
    b = full if full_state else full[..., 0, :, :] if full.shape[-3] == 1 else full.sum(axis=-3)
    # beliefs are never negative: clip(0, 1) as min(float32, 1), cast and clipped in one pass
    return np.minimum(b, np.float32(1.0), dtype=np.float32)


class BeliefObservation:
    """The belief observation of a sensor space ``inner`` on ``model``'s family of maps, with
    :class:`~gym_gridloc.HMMBeliefWrapper`'s options (``flatten``, ``full_state``, ``key``,
    ``map``, ``lookahead``; checked here).  ``space`` is the observation space;
    :meth:`encode` builds N observations from N hidden-state beliefs, :meth:`one` one.

    Two builders with equal :attr:`options` build the same observation from the same belief."""

    def __init__(self, model: GridModel, inner: spaces.Space | None = None, *, flatten: bool = False,
                 full_state: bool = False, key: str = "belief", map: bool = False, lookahead: int = 0) -> None:
        for name, value in (("flatten", flatten), ("full_state", full_state), ("map", map)):
            if not isinstance(value, (bool, np.bool_)):
                raise TypeError(f"{name} must be True or False, got {value!r}")
        if not isinstance(key, str) or not key:
            raise TypeError(f"key must be a non-empty string, got {key!r}")
        self.flatten, self.full_state, self.map = bool(flatten), bool(full_state), bool(map)
        self.key = key
        self.lookahead = check_lookahead(lookahead)
        self.inner = model.sensor.observation_space if inner is None else inner
        self.space = belief_observation_space(model, self.inner, flatten=self.flatten, full_state=self.full_state,
                                              key=key, map=self.map, lookahead=self.lookahead)
        self._plain = not (self.flatten or self.map or self.lookahead)  # the belief beside the reading, nothing else
        #: The observation is the reading and the observed position belief, nothing else: a batch
        #: can take that belief already made (:meth:`encode`'s ``observed``).
        self.plain_positions = self._plain and not self.full_state

    @property
    def options(self) -> dict[str, Any]:
        """The options, as :class:`~gym_gridloc.HMMBeliefWrapper` takes them."""
        return {"flatten": self.flatten, "full_state": self.full_state, "key": self.key, "map": self.map,
                "lookahead": self.lookahead}

    def one(self, model: GridModel, observation: Any, full_belief: np.ndarray, *, reading: int | None = None,
            position: np.ndarray | None = None):
        """The observation of one sensor ``observation`` (as the environment emitted it; a Dict
        observation keeps its keys) and the hidden-state belief ``(L, H, W)`` on ``model``.
        ``reading``: the observation's reading index, when the caller knows it (flat only);
        ``position``: the position belief ``(H, W)``, when the caller holds its own (particles)."""
        if self._plain and position is None and not isinstance(observation, dict):  # the common case, shortest
            return {"observation": observation, self.key: observed_belief(full_belief, self.full_state)}
        belief = observed_belief(full_belief if self.full_state or position is None else position[None], self.full_state)
        look = lookahead_features(model, full_belief, self.lookahead, pose=self.full_state) if self.lookahead else None
        if not self.flatten:
            out = dict(observation) if isinstance(observation, dict) else {"observation": observation}
            out[self.key] = belief
            if self.map:
                out["map"] = _channels(model).copy()
            if look is not None:
                out["lookahead"] = look
            return out
        sensor = model.sensor
        r = sensor.to_reading(observation) if reading is None else reading
        parts = [sensor.encode(np.array([r]))[0], belief.reshape(-1)]
        if self.map:
            parts.append(_channels(model).reshape(-1))
        if look is not None:
            parts.append(look.reshape(-1))
        return np.concatenate(parts)

    def encode(self, models: GridModel | list[GridModel], observations: Any, readings: np.ndarray,
               full_beliefs: np.ndarray, positions: np.ndarray | None = None, *, observed: np.ndarray | None = None):
        """N observations: the sensor ``observations`` batched (a vector env's batch, or a dict of
        batches), their ``readings`` (N,), the hidden-state beliefs ``(N, L, H, W)`` and the model
        of each (one model for all, or N).  ``positions``: the position beliefs ``(N, H*W)``
        when the caller has them (:func:`gym_gridloc.referee.readout`: the same sums);
        ``observed``: their observed form (float32 ``(N, H*W)``, as :func:`observed_belief`
        makes it), when the caller has it and :attr:`plain_positions`."""
        if observed is not None and self.plain_positions and not isinstance(observations, dict):
            n, _, h, w = full_beliefs.shape
            return {"observation": observations, self.key: observed.reshape(n, h, w)}
        if positions is not None and not self.full_state:
            n, _, h, w = full_beliefs.shape
            belief = observed_belief(positions.reshape(n, 1, h, w), False)
        else:
            belief = observed_belief(full_beliefs, self.full_state)
        if self._plain and not isinstance(observations, dict):  # the common case, shortest
            return {"observation": observations, self.key: belief}
        n = full_beliefs.shape[0]
        each = [models] * n if isinstance(models, GridModel) else list(models)
        model = each[0]
        maps = look = None
        if self.map:
            channels = {id(m): _channels(m) for m in each}  # once per distinct map
            maps = np.stack([channels[id(m)] for m in each])
        if self.lookahead:  # (N, lookahead, A) expected entropies per action
            look = np.stack([lookahead_features(m, f, self.lookahead, pose=self.full_state)
                             for m, f in zip(each, full_beliefs)])
        return batch_observation(model, observations, readings, belief, flatten=self.flatten, key=self.key,
                                 maps=maps, lookahead=look)
