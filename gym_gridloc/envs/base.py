"""The generic environment: a hidden robot on a :class:`GridModel`, seen only through readings."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from gym_gridloc.core.model import GridModel
from gym_gridloc.core.validation import check_threshold
from gym_gridloc.filter import ForwardFilter


def belief_summary(position_belief: np.ndarray) -> tuple[tuple[int, int], float, float]:
    """``(estimate, confidence, entropy in bits)`` of an (H, W) position belief."""
    flat = position_belief.ravel()
    k = int(np.argmax(flat))
    p = flat[flat > 0]
    entropy = float(-(p * np.log2(p)).sum())
    return divmod(k, position_belief.shape[1]), float(flat[k]), max(entropy, 0.0)


class GridLocEnv(gym.Env):
    """Active localisation on a grid model (see the subclasses for the documented models).

    The environment simulates the hidden robot with ``model`` and keeps the exact posterior as the
    referee of the termination rule; the observation is only the reading.
    """

    metadata = {"render_modes": ["ansi", "rgb_array", "human"], "render_fps": 4}

    def __init__(self, model: GridModel, *, localise_threshold: float = 0.9, render_mode: str | None = None) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}"
            )
        self.model = model
        self.localise_threshold = check_threshold("localise_threshold", localise_threshold)
        self.render_mode = render_mode
        self.observation_space = model.sensor.observation_space
        self.action_space = spaces.Discrete(model.n_actions)
        self._referee = ForwardFilter(model)
        #: ``rng -> GridModel`` when a new map is drawn at every reset (see ``new_map_each_reset``).
        self._map_factory = None
        self._state: tuple[int, int, int] | None = None
        self._last_reading: int | None = None
        self._last_action: int | None = None
        self._renderer = None

    # -- Gymnasium API ---------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if self._map_factory is not None:  # a new map from np_random: same seed, same map
            self._set_model(self._map_factory(self.np_random))
        if options:
            unknown = set(options) - {"state"}
            if unknown:
                raise ValueError(f"unknown reset option(s) {sorted(unknown)}; allowed: 'state' (row, col) or (layer, row, col)")
        self._state = self._start_state(options)
        self._last_action = None
        return self._observe(first=True), self._info()

    def step(self, action):
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        if not self.action_space.contains(action):
            raise ValueError(f"action {action!r} is not in the action space {self.action_space} (0=N, 1=E, 2=S, 3=W)")
        a = int(action)
        self._state = self.model.sample_next_state(self._state, a, self.np_random)
        self._last_action = a
        obs = self._observe(first=False, action=a)
        info = self._info()
        terminated = bool(info["localised"])
        if self.render_mode == "human":
            self.render()
        return obs, -1.0, terminated, False, info

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode=... to gym.make")
            return None
        if self._state is None:
            raise RuntimeError("call reset() before render()")
        from gym_gridloc import rendering

        if self.render_mode == "ansi":
            return rendering.ansi(self)
        frame = rendering.rgb_frame(self)
        if self.render_mode == "rgb_array":
            return frame
        if self._renderer is None:
            self._renderer = rendering.Window(f"gym_gridloc: {self.model.name}", self.metadata["render_fps"])
        self._renderer.show(frame)
        return None

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # -- helpers ---------------------------------------------------------------------------------
    def _set_model(self, model: GridModel) -> None:
        """Replace the model (a redrawn map of the same size and sensor)."""
        if model.sensor.observation_space != self.observation_space or model.n_actions != self.action_space.n:
            raise ValueError("a redrawn map must keep the observation and action spaces")
        self.model = model
        self._referee = ForwardFilter(model)

    def _start_state(self, options) -> tuple[int, int, int]:
        if options and "state" in options:
            st = tuple(int(v) for v in options["state"])
            if len(st) == 2:
                st = (int(self.np_random.integers(self.model.n_layers)), *st)
            if len(st) != 3 or not (0 <= st[0] < self.model.n_layers) or not self.model.grid.is_free(st[1], st[2]):
                raise ValueError(f"reset option 'state' must name a free cell, got {options['state']!r}")
            return st  # type: ignore[return-value]
        return self.model.sample_initial_state(self.np_random)

    def _observe(self, first: bool, action: int | None = None):
        reading = self.model.sample_reading(self._state, self.np_random)
        self._last_reading = reading
        obs = self.model.sensor.to_observation(reading)
        if first:
            self._referee.reset(obs)
        else:
            self._referee.step(action, obs)
        return obs

    def _info(self) -> dict[str, Any]:
        pb = self._referee.position_belief
        estimate, confidence, entropy = belief_summary(pb)
        position = (self._state[1], self._state[2])
        localised = confidence >= self.localise_threshold
        error = abs(estimate[0] - position[0]) + abs(estimate[1] - position[1])
        info = {
            "position": position,
            "estimate": estimate,
            "confidence": confidence,
            "error": int(error),
            "localised": bool(localised),
            "success": bool(localised and error == 0),
            "entropy": entropy,
        }
        if self.model.n_layers > 1:
            info["heading"] = self._state[0]
        return info

    # Exposed for renderers and tests: the true hidden state and the referee's posterior.
    @property
    def state(self) -> tuple[int, int, int] | None:
        return self._state

    @property
    def posterior(self) -> np.ndarray:
        """The referee's exact position posterior (H, W); not part of the observation."""
        return self._referee.position_belief

    @property
    def last_reading(self) -> int | None:
        return self._last_reading
