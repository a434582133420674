"""A native vector environment: N robots and N exact beliefs stepped with array operations.

``gym.make_vec(ENV_ID, num_envs=N, vectorization_mode="vector_entry_point", belief=True)`` builds
a :class:`GridLocVectorEnv`.  One step samples the N moves (a gather of the N actions' stencil
weights at the N positions and one categorical draw each), the N readings, and updates the N
beliefs with one :class:`~gym_gridloc.BatchFilter` call: no Python loop over the environments
(except for the environments that reset, and a refill of each environment's block of random
numbers every few hundred steps).

Same seeds, same results
------------------------
Environment ``i`` has a random generator of its own, seeded exactly as the single environment
``i`` of ``gym.make_vec(ENV_ID, num_envs=N, vectorization_mode="sync", wrappers=[HMMBeliefWrapper])``
would be: ``reset(seed=s)`` seeds environment ``i`` with ``s + i`` (a list seeds each one), and
later resets continue each stream.  With the same seeds and the same actions the observations,
beliefs, rewards, terminations, truncations and infos equal those of ``SyncVectorEnv`` over
``HMMBeliefWrapper(gym.make(ENV_ID, ...))`` (beliefs within 1e-12; tests/test_vector.py).  The
64-bit outputs each environment consumes are drawn in blocks from its generator (a double consumes one
output, so block draws give the single environment's numbers in the same order), and ``integers``
(a reset, a kidnapping) is computed from the same outputs exactly as numpy does.

Autoreset: Gymnasium's default ``AutoresetMode.NEXT_STEP`` (the step after an episode ends
resets that environment, ignoring its action, with reward 0); ``autoreset_mode=SAME_STEP`` is
available too (``infos["final_obs"]``, ``infos["final_info"]``).  :class:`SB3VecEnv` adapts the
environment to stable-baselines3's ``VecEnv`` API.
"""

from __future__ import annotations

from typing import Any, Sequence

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from gym_gridloc.batch import BatchFilter
from gym_gridloc.core.sensors import ColourSensor, RingSensor, WallSensor
from gym_gridloc.envs.base import GridLocEnv
from gym_gridloc.wrappers import HMMBeliefWrapper

#: Uniforms drawn per refill of an environment's block.
BLOCK = 512


def _term_order(per_action: list[list[tuple[int, int, int, int]]]) -> list[tuple[int, int, int, int]]:
    """One order of all term keys that keeps every action's own order (a topological sort)."""
    keys: list[tuple[int, int, int, int]] = []
    for seq in per_action:
        for k in seq:
            if k not in keys:
                keys.append(k)
    after = {k: set() for k in keys}
    indeg = {k: 0 for k in keys}
    for seq in per_action:
        for a, b in zip(seq, seq[1:]):
            if b not in after[a]:
                after[a].add(b)
                indeg[b] += 1
    out = []
    ready = [k for k in keys if indeg[k] == 0]
    while ready:
        k = min(ready, key=keys.index)
        ready.remove(k)
        out.append(k)
        for b in after[k]:
            indeg[b] -= 1
            if indeg[b] == 0:
                ready.append(b)
    if len(out) != len(keys):
        raise NotImplementedError("the actions order their transition terms inconsistently; the vector env cannot match the single env's sampling")
    return out


class GridLocVectorEnv(gym.vector.VectorEnv):
    """N copies of a gym_gridloc environment with exact beliefs, stepped with array operations.

    Parameters
    ----------
    num_envs:
        N.
    env_class:
        The single environment's class (set by the registered subclasses).
    belief:
        True (default): Dict observations ``observation`` and ``belief`` batched as
        ``HMMBeliefWrapper`` would give them; False: the readings only.
    flatten, full_state:
        As for :class:`HMMBeliefWrapper` (``belief=True`` only).
    max_episode_steps:
        Truncation, as ``TimeLimit`` (``gym.make_vec`` passes the registered value).
    autoreset_mode:
        ``AutoresetMode.NEXT_STEP`` (default) or ``AutoresetMode.SAME_STEP``.
    **env_kwargs:
        The single environment's keyword arguments (map, size, slip, ...).  A map redrawn at every
        reset (``new_map_each_reset=True``) is not supported: all N share one model.
    """

    env_class: type[GridLocEnv] = GridLocEnv

    def __init__(
        self,
        num_envs: int = 1,
        *,
        belief: bool = True,
        flatten: bool = False,
        full_state: bool = False,
        max_episode_steps: int | None = None,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        render_mode: str | None = None,
        env_class: type[GridLocEnv] | None = None,
        **env_kwargs: Any,
    ) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        if render_mode is not None:
            raise ValueError(f"the native vector env does not render (render_mode must be None, got {render_mode!r}); use vectorization_mode='sync' to render")
        if env_kwargs.get("new_map_each_reset"):
            raise ValueError("new_map_each_reset=True is not supported by the native vector env (its N robots share one map); use vectorization_mode='sync'")
        for name, value in (("belief", belief), ("flatten", flatten), ("full_state", full_state)):
            if not isinstance(value, bool):
                raise TypeError(f"{name} must be True or False, got {value!r}")
        if max_episode_steps is not None and (isinstance(max_episode_steps, bool) or not isinstance(max_episode_steps, (int, np.integer)) or max_episode_steps < 1):
            raise ValueError(f"max_episode_steps must be a positive integer or None, got {max_episode_steps!r}")
        try:
            mode = AutoresetMode(autoreset_mode)
        except ValueError:
            raise ValueError(f"autoreset_mode must be AutoresetMode.NEXT_STEP or SAME_STEP, got {autoreset_mode!r}") from None
        if mode not in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP):
            raise ValueError(f"autoreset_mode must be AutoresetMode.NEXT_STEP or SAME_STEP, got {autoreset_mode!r}")
        cls = env_class or self.env_class
        template = cls(**env_kwargs)
        self.template = template
        self.model = model = template.model
        self.localise_threshold = template.localise_threshold
        self.num_envs = n = int(num_envs)
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        self.autoreset_mode = mode
        self.metadata = {"autoreset_mode": mode, "render_modes": []}
        self.render_mode = None
        self.belief_obs = belief
        self.flatten = flatten
        self.full_state = full_state
        sensor = model.sensor
        if not isinstance(sensor, (ColourSensor, WallSensor, RingSensor)):
            raise TypeError(f"the native vector env samples colour, wall and ring sensors, not {type(sensor).__name__}")
        self._sensor = sensor
        if belief:
            # The single wrapped env's observation space, exactly.
            self.single_observation_space = HMMBeliefWrapper(template, flatten=flatten, full_state=full_state).observation_space
        else:
            self.single_observation_space = template.observation_space
        self.single_action_space = template.action_space
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)

        # Sampling tables: every action's terms in one consistent order.
        per_action = [[(t.src, t.dst, t.dr, t.dc) for t in model.terms(a)] for a in range(model.n_actions)]
        keys = _term_order(per_action)
        h, w = model.shape
        self._K = len(keys)
        self._key_src = np.array([k[0] for k in keys])
        self._key_dst = np.array([k[1] for k in keys])
        self._key_dr = np.array([k[2] for k in keys])
        self._key_dc = np.array([k[3] for k in keys])
        self._weights = np.zeros((model.n_actions, h * w, self._K))  # [a, cell, k]
        for a in range(model.n_actions):
            for t in model.terms(a):
                self._weights[a, :, keys.index((t.src, t.dst, t.dr, t.dc))] = t.weight.reshape(-1)
        self._free_cells = model.grid.free_cells
        self.filter = BatchFilter(model, n)

        self._rngs: list[np.random.Generator | None] = [None] * n
        self._buf = np.zeros((n, BLOCK), dtype=np.uint64)
        self._pos = np.full(n, BLOCK, dtype=np.int64)
        self._half = np.zeros(n, dtype=np.uint64)  # the bit generator's buffered 32-bit half
        self._has_half = np.zeros(n, dtype=bool)
        self._layer = np.zeros(n, dtype=np.int64)
        self._row = np.zeros(n, dtype=np.int64)
        self._col = np.zeros(n, dtype=np.int64)
        self._readings = np.zeros(n, dtype=np.int64)
        self._elapsed = np.zeros(n, dtype=np.int64)
        self._autoreset = np.zeros(n, dtype=bool)
        self._started = False

    # -- random numbers: per-env streams, drawn in blocks -----------------------------------------
    # A single env draws with ``random()`` (one 64-bit output x per double: (x >> 11) * 2**-53)
    # and ``integers(n)`` (Lemire's method on 32-bit draws: the low half of an output, its high
    # half kept by the bit generator for the next 32-bit draw).  The vector env reads each env's
    # raw outputs in blocks (``random_raw``), keeps the buffered half itself, and computes the
    # same doubles and integers with array operations.
    def _rng(self, i: int) -> np.random.Generator:
        if self._rngs[i] is None:
            self._rngs[i], _ = seeding.np_random(None)
        return self._rngs[i]

    def _restart_stream(self, i: int) -> None:
        self._buf[i] = self._rng(i).bit_generator.random_raw(BLOCK)
        self._pos[i] = 0
        self._has_half[i] = False

    def _raw(self, idx: np.ndarray, k: int) -> np.ndarray:
        """(len(idx), k) uint64: each env's next k outputs."""
        pos = self._pos[idx]
        for j in np.flatnonzero(pos + k > BLOCK):  # refill: keep the unread tail, draw the rest
            i = int(idx[j])
            p = int(self._pos[i])
            self._buf[i] = np.concatenate([self._buf[i, p:], self._rng(i).bit_generator.random_raw(p)])
            self._pos[i] = 0
        pos = self._pos[idx]
        out = self._buf[idx[:, None], pos[:, None] + np.arange(k)]
        self._pos[idx] = pos + k
        return out

    def _uniforms(self, idx: np.ndarray, k: int) -> np.ndarray:
        """(len(idx), k) doubles in [0, 1), exactly ``Generator.random()``'s."""
        return (self._raw(idx, k) >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)

    def _next32(self, idx: np.ndarray) -> np.ndarray:
        """Each env's next 32-bit value as the bit generator's ``next_uint32`` gives it: the
        high half of the last output when one is buffered, else the low half of a new output
        (whose high half is then buffered)."""
        has = self._has_half[idx]
        out = np.empty(idx.size, dtype=np.uint64)
        if has.any():
            out[has] = self._half[idx[has]]
            self._has_half[idx[has]] = False
        need = idx[~has]
        if need.size:
            x = self._raw(need, 1)[:, 0]
            out[~has] = x & np.uint64(0xFFFFFFFF)
            self._half[need] = x >> np.uint64(32)
            self._has_half[need] = True
        return out

    def _integers(self, idx: np.ndarray, n: int) -> np.ndarray:
        """One ``Generator.integers(n)`` per env, exactly numpy's (Lemire's method on 32-bit draws)."""
        if n == 1 or idx.size == 0:
            return np.zeros(idx.size, dtype=np.int64)
        m = self._next32(idx) * np.uint64(n)
        out = (m >> np.uint64(32)).astype(np.int64)
        threshold = ((1 << 32) - n) % n
        for j in np.flatnonzero((m & np.uint64(0xFFFFFFFF)) < np.uint64(threshold)):  # rare: redraw
            one = idx[j : j + 1]
            mm = int(self._next32(one)[0]) * n
            while (mm & 0xFFFFFFFF) < threshold:
                mm = int(self._next32(one)[0]) * n
            out[j] = mm >> 32
        return out

    # -- sampling ---------------------------------------------------------------------------------
    def _sample_initial(self, idx: np.ndarray) -> None:
        s = self._integers(idx, self.model.n_states)
        layer, cell = np.divmod(s, self.model.grid.n_free)
        self._layer[idx] = layer
        self._row[idx] = self._free_cells[cell, 0]
        self._col[idx] = self._free_cells[cell, 1]

    def _sample_moves(self, idx: np.ndarray, actions: np.ndarray) -> None:
        if idx.size == 0:
            return
        kp = self.model.kidnap_prob
        if kp > 0.0:
            kidnapped = self._uniforms(idx, 1)[:, 0] < kp
            self._sample_initial(idx[kidnapped])
            idx, actions = idx[~kidnapped], actions[~kidnapped]
            if idx.size == 0:
                return
        w = self.model.shape[1]
        layer = self._layer[idx]
        p = self._weights[actions, self._row[idx] * w + self._col[idx]]  # (n, K)
        p = np.where(self._key_src[None, :] == layer[:, None], p, 0.0)
        cum = np.cumsum(p, axis=1)
        x = self._uniforms(idx, 1)[:, 0] * cum[:, -1]
        below = x[:, None] < cum
        k = np.argmax(below, axis=1)
        none = ~below.any(axis=1)
        if none.any():  # u * total rounded up to the total: the last possible outcome
            last = self._K - 1 - np.argmax((p[none] > 0)[:, ::-1], axis=1)
            k[none] = last
        self._layer[idx] = self._key_dst[k]
        self._row[idx] += self._key_dr[k]
        self._col[idx] += self._key_dc[k]

    def _sample_readings(self, idx: np.ndarray) -> None:
        if idx.size == 0:
            return
        sensor = self._sensor
        r, c = self._row[idx], self._col[idx]
        if isinstance(sensor, WallSensor):
            bits = self._uniforms(idx, 4) < sensor._p_bits[:, r, c].T
            self._readings[idx] = bits.astype(np.int64) @ np.array([8, 4, 2, 1])
            return
        if isinstance(sensor, ColourSensor):
            probs = np.ascontiguousarray(sensor._table[:, r, c].T)  # (n, k)
            cum = np.cumsum(probs, axis=1)
            x = self._uniforms(idx, 1)[:, 0] * probs.sum(axis=1)
            k = np.minimum((cum <= x[:, None]).sum(axis=1), probs.shape[1] - 1)
            self._readings[idx] = k
            return
        # Ring sensor: the 25 window cells in row-major order (zero off the grid), then nothing.
        h, w = self.model.shape
        di, dj = np.divmod(np.arange(25), 5)
        rr = r[:, None] + di[None, :] - 2
        cc = c[:, None] + dj[None, :] - 2
        inside = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
        probs = np.empty((idx.size, 26))
        probs[:, :25] = np.where(inside, sensor._kernel.reshape(-1)[None, :], 0.0)
        probs[:, 25] = sensor.nothing_probability[r, c]
        cum = np.cumsum(probs, axis=1)
        x = self._uniforms(idx, 1)[:, 0] * probs.sum(axis=1)
        k = np.minimum((cum <= x[:, None]).sum(axis=1), 25)
        cell = np.take_along_axis(rr * w + cc, np.minimum(k, 24)[:, None], axis=1)[:, 0]
        self._readings[idx] = np.where(k == 25, sensor.nothing, cell)

    # -- observations and infos -------------------------------------------------------------------
    def _sensor_obs(self) -> np.ndarray:
        if isinstance(self._sensor, WallSensor):
            shifts = np.array([3, 2, 1, 0])
            return ((self._readings[:, None] >> shifts) & 1).astype(np.int8)
        return self._readings.copy()

    def _observations(self):
        obs = self._sensor_obs()
        if not self.belief_obs:
            return obs
        b = self.filter.beliefs if self.full_state else self.filter.position_beliefs
        b = b.astype(np.float32)
        np.clip(b, 0.0, 1.0, out=b)
        if self.flatten:
            if isinstance(self._sensor, WallSensor):
                enc = obs.astype(np.float32)
            else:
                enc = np.zeros((self.num_envs, self._sensor.n_readings), dtype=np.float32)
                enc[np.arange(self.num_envs), obs] = 1.0
            return np.concatenate([enc, b.reshape(self.num_envs, -1)], axis=1)
        return {"observation": obs, "belief": b}

    def _infos(self) -> tuple[dict[str, np.ndarray], np.ndarray]:
        n = self.num_envs
        pb = self.filter.position_beliefs.reshape(n, -1)
        k = np.argmax(pb, axis=1)
        conf = pb[np.arange(n), k]
        ent = -np.einsum("ij,ij->i", pb, np.log2(np.where(pb > 0, pb, 1.0)))
        ent = np.maximum(ent, 0.0)
        w = self.model.shape[1]
        est = np.stack(np.divmod(k, w), axis=1)
        pos = np.stack([self._row, self._col], axis=1)
        err = np.abs(est - pos).sum(axis=1)
        localised = conf >= self.localise_threshold
        info = {
            "position": pos,
            "estimate": est,
            "confidence": conf,
            "error": err,
            "localised": localised,
            "success": localised & (err == 0),
            "entropy": ent,
        }
        if self.model.n_layers > 1:
            info["heading"] = self._layer.copy()
        return info, localised

    # -- Gymnasium API ----------------------------------------------------------------------------
    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict[str, Any] | None = None):
        n = self.num_envs
        mask = np.ones(n, dtype=bool)
        if options:
            unknown = set(options) - {"reset_mask"}
            if unknown:
                raise ValueError(f"unknown reset option(s) {sorted(unknown)}; allowed: 'reset_mask'")
            mask = np.asarray(options["reset_mask"])
            if mask.shape != (n,) or mask.dtype != bool:
                raise ValueError(f"options['reset_mask'] must be {n} booleans, got {options['reset_mask']!r}")
        if seed is None:
            seeds: list[int | None] = [None] * n
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(n)]
        else:
            seeds = list(seed)
            if len(seeds) != n:
                raise ValueError(f"seed must be an int, None or a list of {n} seeds, got {len(seeds)} seeds")
        for i, s in enumerate(seeds):
            if mask[i] and (s is not None or self._rngs[i] is None):
                self._rngs[i], _ = seeding.np_random(s)
                self._restart_stream(i)
        idx = np.flatnonzero(mask)
        self._reset_envs(idx)
        self._autoreset[idx] = False
        self._started = True
        info, _ = self._infos()
        return self._observations(), self._masked(info, mask)

    def _reset_envs(self, idx: np.ndarray) -> None:
        if idx.size == 0:
            return
        self._sample_initial(idx)
        self._sample_readings(idx)
        mask = np.zeros(self.num_envs, dtype=bool)
        mask[idx] = True
        self.filter.reset(mask=mask, readings=self._readings)
        self._elapsed[idx] = 0

    def step(self, actions):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        n = self.num_envs
        acts = np.asarray(actions)
        if acts.shape != (n,) or not np.issubdtype(acts.dtype, np.integer):
            raise ValueError(f"actions must be {n} integers in 0..{self.model.n_actions - 1}, got {actions!r}")
        acts = acts.astype(np.int64)
        resetting = self._autoreset.copy() if self.autoreset_mode == AutoresetMode.NEXT_STEP else np.zeros(n, dtype=bool)
        bad = ~resetting & ((acts < 0) | (acts >= self.model.n_actions))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"action {int(acts[i])} of env {i} is not in the action space {self.single_action_space} (0=N, 1=E, 2=S, 3=W)")
        moving = np.flatnonzero(~resetting)
        restarting = np.flatnonzero(resetting)
        # Each env draws in its single env's order: a move (or a start state), then a reading.
        self._sample_moves(moving, acts[moving])
        if restarting.size:
            self._sample_initial(restarting)
        self._sample_readings(np.arange(n))
        step_mask = ~resetting
        if moving.size:
            self.filter.step(np.where(resetting, 0, acts), mask=step_mask, readings=self._readings)
        self._elapsed[moving] += 1
        if restarting.size:
            self.filter.reset(mask=resetting, readings=self._readings)
            self._elapsed[restarting] = 0
        info, localised = self._infos()
        terminated = localised & step_mask
        truncated = step_mask & (self._elapsed >= self.max_episode_steps) if self.max_episode_steps else np.zeros(n, dtype=bool)
        rewards = np.where(step_mask, -1.0, 0.0)
        obs = self._observations()
        done = terminated | truncated
        if self.autoreset_mode == AutoresetMode.SAME_STEP and done.any():
            final_obs = np.full(n, None, dtype=object)
            final_info = np.full(n, None, dtype=object)
            for i in np.flatnonzero(done):
                final_obs[i] = self._single(obs, i)
                final_info[i] = {k: v[i] for k, v in info.items()}
            self._reset_envs(np.flatnonzero(done))
            info, _ = self._infos()
            obs = self._observations()
            info = dict(info)
            info["final_obs"], info["_final_obs"] = final_obs, done.copy()
            info["final_info"], info["_final_info"] = final_info, done.copy()
        else:
            self._autoreset = done
        info = self._masked(info, np.ones(n, dtype=bool))
        return obs, rewards, terminated, truncated, info

    @staticmethod
    def _single(obs, i: int):
        if isinstance(obs, dict):
            return {k: v[i].copy() for k, v in obs.items()}
        return obs[i].copy()

    @staticmethod
    def _masked(info: dict, mask: np.ndarray) -> dict:
        out = dict(info)
        for key in info:
            if not key.startswith("_") and f"_{key}" not in info:
                out[f"_{key}"] = mask.copy()
        return out

    # -- exposed for tests and tools ---------------------------------------------------------------
    @property
    def beliefs(self) -> np.ndarray:
        """The exact hidden-state beliefs, (N, L, H, W) float64 (a copy)."""
        return self.filter.beliefs.copy()

    @property
    def states(self) -> np.ndarray:
        """The true hidden states (N, 3): layer, row, col (not part of the observation)."""
        return np.stack([self._layer, self._row, self._col], axis=1)


class ColourGridVectorEnv(GridLocVectorEnv):
    """Native vector version of ``ColourGrid-v0`` (see :class:`GridLocVectorEnv`)."""

    from gym_gridloc.envs.colour_grid import ColourGridEnv as env_class  # noqa: N813


class RingSensorVectorEnv(GridLocVectorEnv):
    """Native vector version of ``RingSensor8x8-v0`` (see :class:`GridLocVectorEnv`)."""

    from gym_gridloc.envs.ring_sensor import RingSensorEnv as env_class  # noqa: N813


class WindyMazeVectorEnv(GridLocVectorEnv):
    """Native vector version of ``WindyMaze-v0`` (see :class:`GridLocVectorEnv`)."""

    from gym_gridloc.envs.windy_maze import WindyMazeEnv as env_class  # noqa: N813


def _sb3_vec_env_class():
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv

    class SB3VecEnv(VecEnv):
        """stable-baselines3 ``VecEnv`` over a :class:`GridLocVectorEnv` (SB3 takes its own VecEnv
        API, not Gymnasium's ``VectorEnv``).

        SB3 resets a finished environment in the same step: the returned observation is the new
        episode's first, ``infos[i]["terminal_observation"]`` the last one of the finished episode
        and ``infos[i]["TimeLimit.truncated"]`` says a time limit (not localisation) ended it.  The
        wrapped env is switched to ``AutoresetMode.SAME_STEP`` for this.

        >>> import gymnasium as gym, gym_gridloc
        >>> from gym_gridloc.vector import SB3VecEnv
        >>> venv = SB3VecEnv(gym.make_vec("WindyMaze-v0", num_envs=8, vectorization_mode="vector_entry_point"))
        >>> venv.num_envs
        8

        ``SB3VecEnv.make(env_id, num_envs, **kwargs)`` builds the native env and the adapter.
        """

        def __init__(self, venv: GridLocVectorEnv) -> None:
            env = getattr(venv, "unwrapped", venv)
            if not isinstance(env, GridLocVectorEnv):
                raise TypeError(f"SB3VecEnv needs a gym_gridloc native vector env (GridLocVectorEnv), got {type(venv).__name__}")
            if env._autoreset.any():
                raise ValueError("switch the vector env to SB3's same-step autoreset before an episode ends: wrap it right after creating it")
            env.autoreset_mode = AutoresetMode.SAME_STEP
            env.metadata = {**env.metadata, "autoreset_mode": AutoresetMode.SAME_STEP}
            self.venv = env
            super().__init__(env.num_envs, env.single_observation_space, env.single_action_space)
            self._actions: np.ndarray | None = None

        @classmethod
        def make(cls, env_id: str, num_envs: int, **kwargs: Any) -> "SB3VecEnv":
            return cls(gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs))

        def reset(self):
            seeds = self._seeds if any(s is not None for s in self._seeds) else None
            obs, info = self.venv.reset(seed=seeds)
            self._reset_seeds()
            self._reset_options()
            self.reset_infos = [{} for _ in range(self.num_envs)]
            return obs

        def step_async(self, actions: np.ndarray) -> None:
            self._actions = np.asarray(actions).reshape(self.num_envs).astype(np.int64)

        def step_wait(self):
            obs, rewards, terminated, truncated, info = self.venv.step(self._actions)
            dones = terminated | truncated
            infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
            for i in np.flatnonzero(dones):
                final = dict(info["final_info"][i])
                final["terminal_observation"] = info["final_obs"][i]
                final["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
                infos[i] = final
            return obs, rewards.astype(np.float32), dones, infos

        def close(self) -> None:
            self.venv.close()

        def get_attr(self, attr_name: str, indices=None) -> list[Any]:
            target = self.venv.template
            if attr_name == "render_mode":
                return [None for _ in self._get_indices(indices)]
            return [getattr(target, attr_name) for _ in self._get_indices(indices)]

        def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
            raise AttributeError(f"the native vector env's {self.num_envs} environments share one model; cannot set {attr_name!r} per environment")

        def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
            raise AttributeError(f"the native vector env has no per-environment objects to call {method_name!r} on")

        def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
            return [False for _ in self._get_indices(indices)]

    return SB3VecEnv


def __getattr__(name: str):
    # SB3VecEnv imports stable-baselines3 (and torch) only when it is asked for.
    if name == "SB3VecEnv":
        cls = _sb3_vec_env_class()
        globals()["SB3VecEnv"] = cls
        return cls
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
