"""The generic environment: a hidden robot on a :class:`GridModel`, seen only through readings."""

from __future__ import annotations

import collections
import functools
import threading
import weakref
from typing import Any, Callable

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from gym_gridloc import referee
from gym_gridloc.batch import START, START_AT, STEP, Batch
from gym_gridloc.core.grid import GridMap
from gym_gridloc.core.model import GridModel
from gym_gridloc.core.validation import check_choice, check_int, check_threshold, is_int
from gym_gridloc.filter import ForwardFilter


# SDL2's key codes of the arrow keys (pygame.K_UP etc.), fixed by SDL.
_SDLK_RIGHT, _SDLK_LEFT, _SDLK_DOWN, _SDLK_UP = 0x4000004F, 0x40000050, 0x40000051, 0x40000052


class GridLocEnv(gym.Env):
    """Active localisation on a grid model (see the subclasses for the documented models).

    The environment simulates the hidden robot with ``model`` and keeps the exact posterior as the
    referee of the termination rule (:mod:`gym_gridloc.referee`); the observation is only the
    reading.  It is the N = 1 view of the step of N robots (:class:`gym_gridloc.batch.Batch`), of
    which the native vector environment is the N view: the same draws and numbers.

    Keyword arguments the subclasses pass on: ``localise_threshold``; ``builder`` (``GridMap ->
    GridModel``: the family's model on another map, for the ``map`` reset option); ``map_factory``
    (a :class:`MapFactory`: ``rng -> GridModel``, a new map at every reset); ``referee_pose`` (the referee tests the most
    probable hidden state rather than position); ``episode_length`` (a fixed number of steps:
    truncated there, never terminated early); ``reward`` (``"step"``: -1 per step, or
    ``"belief"``: the referee's confidence); ``render_shading`` (how ``rgb_array`` and ``human``
    frames shade the belief, ``gym_gridloc.rendering.Frame.shading``: ``"relative"``, the
    default, darkens each free cell towards navy by its probability relative to the most probable
    cell's, so a belief spread thin is still seen (under ``"absolute"`` a uniform belief over 60
    cells is nearly white); ``"absolute"`` draws each cell in its own colour, the map colour on
    a colour map, with opacity equal to its probability: on ColourGrid the belief is then never
    mistaken for a blue cell).  Frames of a model with a heading (DepthMaze) draw the true heading
    and the belief's headings; docs/environments.md has the key of a frame.

    Reset options: ``state`` (``(row, col)`` or ``(layer, row, col)``: the start), ``map`` (a
    :class:`~gym_gridloc.GridMap` or a layout of this family: the map of this episode only, e.g.
    a held-out test map).
    """

    metadata = {"render_modes": ["ansi", "rgb_array", "human"], "render_fps": 4}

    def __init__(self, model: GridModel, *, localise_threshold: float = referee.LOCALISE_THRESHOLD, render_mode: str | None = None,
                 builder: Callable[[Any], GridModel] | None = None,
                 map_factory: "MapFactory | None" = None,
                 referee_pose: bool = False, episode_length: int | None = None, reward: str = "step",
                 render_shading: str = "relative") -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}"
            )
        self.render_shading = check_choice("render_shading", render_shading, ("relative", "absolute"))
        self.model = model
        self.localise_threshold = check_threshold("localise_threshold", localise_threshold)
        self.episode_length = None if episode_length is None else check_int("episode_length", episode_length, 1)
        self.reward_kind = check_choice("reward", reward, referee.REWARDS)
        self.referee_pose = bool(referee_pose)
        self.render_mode = render_mode
        self.observation_space = model.sensor.observation_space
        self.action_space = spaces.Discrete(model.n_actions)
        self._n_actions = model.n_actions
        self._fixed_model = model
        self._builder = builder
        self._map_factory = map_factory
        #: The robot, its belief, its step count and its map, and the step (N = 1).
        self._batch = Batch(model, 1, threshold=self.localise_threshold, pose=self.referee_pose, reward=self.reward_kind,
                            limit=self.episode_length, fixed_length=self.episode_length is not None, map_factory=map_factory,
                            reuse=True)
        self._bind()
        self._state: tuple[int, int, int] | None = None  # layer, row, col
        self._last_reading: int | None = None
        self._last_action: int | None = None
        self._window = None

    def _bind(self) -> None:
        """The step's per-call arrays and the views of the belief's two buffers (rebuilt on load)."""
        rows = self._batch.rows
        self._actions, self._stepping = np.zeros(1, dtype=np.int64), np.full(1, STEP, dtype=np.int8)
        shape = self._batch.shape
        self._views = (rows.beliefs[0, 0].reshape(shape), rows.beliefs[1, 0].reshape(shape))
        self._referee = ForwardFilter(self.model, read_every_step=True)
        self._to_observation = self.model.sensor.to_observation

    # -- Gymnasium API ---------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - {"state", "map"}
        if unknown:
            raise ValueError(f"unknown reset option(s) {sorted(unknown)}; allowed: 'state' (row, col) or (layer, row, col), 'map'")
        batch, rng, maps = self._batch, self.np_random, False
        if "map" in options:  # this episode's map, given: the family's model on it
            if self._builder is None:
                raise ValueError(
                    f"{type(self).__name__} takes no 'map' reset option (it has no builder for other maps)")
            model = self._builder(options["map"])
            if model.belief_shape != self._fixed_model.belief_shape:  # the declared spaces are of that size
                raise ValueError(f"reset option 'map': a {'x'.join(map(str, model.shape))} map, but this environment's maps are "
                                 f"{'x'.join(map(str, self._fixed_model.shape))} (its spaces are declared for that size)")
            self._set_model(model)
        elif self._map_factory is not None:  # a new map from np_random: same seed, same map
            if "state" in options:  # (drawn first: the state is checked on it)
                self._set_model(self._map_factory(rng))
            else:
                maps = True  # (drawn by the step, as the factory draws it)
        elif self.model is not self._fixed_model:
            self._set_model(self._fixed_model)
        start = self._start_state(options)
        if start is not None:
            batch.rows.states[0] = start
        self._last_action = None
        out = batch.advance(None, np.full(1, START if start is None else START_AT, dtype=np.int8), rng, maps=maps, one=True)
        if maps and batch.models[0] is not self.model:
            self._set_model(batch.models[0])
        return self._to_observation(self._read()), out.info

    def step(self, action):
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        if type(action) is int and 0 <= action < self._n_actions:  # the common case, without the space's checks
            a = action
        elif self.action_space.contains(action):
            a = int(action)
        else:
            raise ValueError(f"action {action!r} is not in the action space {self.action_space} ({self.model.action_legend})")
        self._actions[0] = a
        info, _, _, reward, terminated, truncated, _ = self._batch.advance(self._actions, self._stepping, self._np_random, one=True)
        self._last_action = a
        obs = self._to_observation(self._read())
        if self.render_mode == "human":
            self.render()
        return obs, reward, terminated, truncated, info

    def _read(self) -> int:
        """After a step of the batch: the state, the reading and the referee's belief of row 0."""
        rows = self._batch.rows
        self._state = tuple(rows.states[0].tolist())
        self._last_reading = reading = rows.readings.item(0)
        self._referee._show(self._views[rows.current.item(0)])
        return reading

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode=... to gym.make")
            return None
        if self._state is None:
            raise RuntimeError("call reset() before render()")
        from gym_gridloc import rendering

        heading = self.model.n_layers == 4  # the layers are headings (N, E, S, W)
        frame = rendering.Frame(self.model, self._referee.position_belief, self.state, self._last_reading, self._last_action,
                                heading=heading, shading=self.render_shading,
                                headings=self._referee.full_belief if heading else None)
        if self.render_mode == "ansi":
            return rendering.ansi(frame)
        image = rendering.rgb_frame(frame)
        if self.render_mode == "rgb_array":
            return image
        if self._window is None:
            self._window = rendering.Window(f"gym_gridloc: {self.model.name}", self.metadata["render_fps"])
        self._window.show(image)
        return None

    def get_keys_to_action(self) -> dict[tuple[int | str, ...], int]:
        """Keys for :func:`gymnasium.utils.play.play`: the arrow keys and WASD.

        Moves N / E / S / W: up / right / down / left (``w`` / ``d`` / ``s`` / ``a``); a model with
        actions ``left, right, forward`` (DepthMaze): left / right turn (``a`` / ``d``), up moves
        forward (``w``); any other model: the digit keys ``0``..``9``.  Keys are SDL key codes (the
        arrows' fixed values, so pygame need not be imported) or one-character strings.  ``play``
        steps every frame with ``noop`` when no key is held: pass ``wait_on_player=True``.
        """
        names = tuple(self.model.action_names)
        arrows = {"up": _SDLK_UP, "right": _SDLK_RIGHT, "down": _SDLK_DOWN, "left": _SDLK_LEFT}
        letters = {"up": "w", "right": "d", "down": "s", "left": "a"}
        if names == ("N", "E", "S", "W"):
            keys = {"up": 0, "right": 1, "down": 2, "left": 3}
        elif names == ("left", "right", "forward"):
            keys = {"left": 0, "right": 1, "up": 2}
        else:
            return {(str(a),): a for a in range(min(self.model.n_actions, 10))}
        return {(key,): a for name, a in keys.items() for key in (arrows[name], letters[name])}

    def close(self):
        if self._window is not None:
            self._window.close()
            self._window = None

    # -- helpers ---------------------------------------------------------------------------------
    def _set_model(self, model: GridModel) -> None:
        """Replace the model (another map of the same family and spaces)."""
        if model.sensor.observation_space != self.observation_space or model.n_actions != self.action_space.n:
            raise ValueError(
                f"the map of this episode must keep the observation space {self.observation_space} and "
                f"{self.action_space.n} actions; its model has {model.sensor.observation_space} and {model.n_actions}"
            )
        if self._batch.models[0] is not model:
            self._batch.set_models(np.zeros(1, dtype=np.int64), [model])
        if model is not self.model:
            self.model = model
            self._referee = ForwardFilter(model, read_every_step=True)
            self._to_observation = model.sensor.to_observation

    def _start_state(self, options) -> np.ndarray | None:
        """The start state a reset option asks for, as (1, 3), or None (draw it)."""
        if "state" not in options:
            return None
        given = options["state"]
        st = _int_tuple(given)
        if st is not None and len(st) == 2:
            st = (int(self.np_random.integers(self.model.n_layers)), *st)
        if st is None or len(st) != 3 or not (0 <= st[0] < self.model.n_layers) or not self.model.grid.is_free(st[1], st[2]):
            raise ValueError(
                f"reset option 'state' must name a free cell, got {given!r}: give (row, col) or (layer, row, col) "
                f"as integers (layer in 0..{self.model.n_layers - 1})"
            )
        return np.array([st], dtype=np.int64)

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k not in ("_to_observation", "_views", "_referee")}  # (rebuilt on load)

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._bind()
        if self._state is not None:
            self._referee._show(self._views[self._batch.rows.current.item(0)])

    # Exposed for renderers and tests: the true hidden state and the referee's posterior.
    @property
    def state(self) -> tuple[int, int, int] | None:
        """The true hidden state ``(layer, row, col)`` (not part of the observation)."""
        return self._state

    @property
    def map_factory(self) -> "MapFactory | None":
        """What draws a new map's model at every reset (``new_map_each_reset``), or None: the
        native vector env draws its environments' maps with it."""
        return self._map_factory

    @property
    def exact_filter(self) -> ForwardFilter:
        """The referee: the exact forward filter of the episode's model, whose belief is the
        environment's posterior after every step (not part of the observation).  Read its belief
        (``full_belief``, ``position_belief``); :class:`~gym_gridloc.HMMBeliefWrapper` serves it
        as the observation's belief.  Stepping it yourself moves it off the environment's
        posterior (until the environment's next step or reset) and never changes the referee."""
        return self._referee

    @property
    def posterior(self) -> np.ndarray:
        """The referee's exact position posterior (H, W); not part of the observation."""
        return self._referee.position_belief

    @property
    def last_reading(self) -> int | None:
        return self._last_reading


class MapFactory:
    """The map factory of an environment with a new map at every reset: ``factory(rng)`` is
    ``build(draw(rng))``, the model on a newly drawn map.  Made of module-level functions (or
    ``functools.partial`` of them), a factory pickles with its environment.

    A family whose maps have integer codes also gives ``codes(rng, count)`` (``count`` maps drawn
    at once, as ``count`` calls of ``draw`` draw them, as their codes) and ``of_code(code)`` (the
    map): the native vector env draws its resets' maps so, one call for all of them.  Perfect
    mazes give ``graph`` too (:func:`~gym_gridloc.generators.perfect_maze_graph`: the codes are
    its random spanning trees): the native vector env's compiled step then draws them itself.

    A small map drawn again is not built again: a map (of at most :data:`REDRAWN_CELLS` cells)
    drawn for the second time among the last :data:`REDRAWN_SEEN` keeps its model, the last
    :data:`REDRAWN_MODELS` of them, keyed by the map and ``build``'s function and keywords, shared
    by every environment of this process (a model is frozen data); until then it is held weakly
    (reused while something else holds it).  A 7x7 ``DepthMaze`` has only 192 mazes: after a
    few hundred resets a new episode's model, and the engine's tables for it, are already there (a
    build costs about 0.5 ms, a maze's draw about 5 µs); mazes that do not come again (15x15: more
    than 10^20 of them) keep nothing."""

    def __init__(self, build: Callable[[Any], GridModel], draw: Callable[[np.random.Generator], Any], *,
                 codes: Callable[[np.random.Generator, int], np.ndarray | None] | None = None,
                 of_code: Callable[[int], Any] | None = None, graph: tuple[np.ndarray, int] | None = None) -> None:
        if (codes is None) != (of_code is None):
            raise ValueError("give both codes= and of_code= (a map's code and the map it stands for), or neither")
        if graph is not None and codes is None:
            raise ValueError("graph= describes how the codes are drawn: give codes= and of_code= too")
        self.build, self.draw, self._codes, self._of_code = build, draw, codes, of_code
        #: ``(walls, rooms)`` when the codes are perfect mazes on that graph (see :func:`~gym_gridloc.generators.perfect_maze_graph`), else None.
        self.graph = graph

    def __call__(self, rng: np.random.Generator) -> GridModel:
        return _kept_model(self.build, self.draw(rng))

    def codes(self, rng: np.random.Generator, count: int) -> np.ndarray | None:
        """``count`` maps drawn as ``count`` calls of the factory draw them, as int64 codes
        (:meth:`model_of_code` gives each one's model); None when the family has no codes."""
        return None if self._codes is None else self._codes(rng, count)

    def model_of_code(self, code: int) -> GridModel:
        """The model on the map of ``code`` (the model ``factory(rng)`` gives for that map)."""
        return _kept_model(self.build, self._of_code(code))

    def models(self, rng: np.random.Generator, count: int, memo: dict | None = None, limit: int | None = None) -> list[GridModel]:
        """``count`` models on newly drawn maps, as ``count`` calls of the factory draw them: at
        once where the family has codes, each code's model then looked up first in ``memo`` (the
        caller's: code -> model, the last ``limit``, default :data:`REDRAWN_MODELS`; quicker
        than finding it among the kept ones)."""
        codes = self.codes(rng, count)
        if codes is None:
            return [self(rng) for _ in range(count)]
        memo = {} if memo is None else memo
        out = []
        for c in codes.tolist():
            model = memo.get(c)
            if model is None:
                model = memo[c] = self.model_of_code(c)
                if len(memo) > (REDRAWN_MODELS if limit is None else limit):
                    del memo[next(iter(memo))]  # the oldest
            out.append(model)
        return out


def _kept_model(build: Callable[[Any], GridModel], grid: Any) -> GridModel:
    """``build(grid)``, or the model kept for that map (see :class:`MapFactory`)."""
    key = _redraw_key(build, grid)
    if key is None:
        return build(grid)
    with _REDRAWN_LOCK:
        model = _REDRAWN.get(key)
        if model is not None:
            _REDRAWN.move_to_end(key)
            return model
        seen = _SEEN.pop(key, None)
        model = None if seen is None else seen()
    if model is None:
        model = build(grid)
    with _REDRAWN_LOCK:
        if seen is None:  # the first time: held weakly
            _SEEN[key] = weakref.ref(model)
            while len(_SEEN) > REDRAWN_SEEN:
                _SEEN.popitem(last=False)
        else:  # drawn again: kept
            _REDRAWN[key] = model
            while len(_REDRAWN) > REDRAWN_MODELS:
                _REDRAWN.popitem(last=False)
    return model


#: :class:`MapFactory` keeps the models of this many maps (the most recently drawn) ...
REDRAWN_MODELS = 256
#: ... of at most this many cells each, drawn at least twice among the last ``REDRAWN_SEEN`` maps.
REDRAWN_CELLS = 256
REDRAWN_SEEN = 1024
_REDRAWN: "collections.OrderedDict[tuple, GridModel]" = collections.OrderedDict()
_SEEN: "collections.OrderedDict[tuple, weakref.ref]" = collections.OrderedDict()  # maps drawn once, their models weakly
_REDRAWN_LOCK = threading.Lock()


def _redraw_key(build: Any, grid: Any) -> tuple | None:
    """The key of ``build(grid)`` among the kept models, or None when it is not kept: a map that
    is not a small :class:`GridMap`, or a ``build`` that is not a ``functools.partial`` with
    hashable keywords (its function and keywords say which model the map gives)."""
    if not isinstance(grid, GridMap) or grid.labels.size > REDRAWN_CELLS or not isinstance(build, functools.partial):
        return None
    key = (build.func, build.args, tuple(build.keywords.items()), grid.symbols, grid.labels.shape, grid.labels.tobytes())
    try:
        hash(key)
    except TypeError:
        return None
    return key


def _int_tuple(value: Any) -> tuple[int, ...] | None:
    """``value`` as a tuple of ints if it is a sequence of whole numbers (not strings or bools)."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or not all(is_int(v) for v in value):
        return None
    return tuple(int(v) for v in value)
