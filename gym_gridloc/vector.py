"""A native vector environment: N robots and N exact beliefs stepped by the engine in batches.

``gym.make_vec(ENV_ID, num_envs=N, vectorization_mode="vector_entry_point")`` builds a
:class:`GridLocVectorEnv`: the N view of the step of N robots (:class:`gym_gridloc.batch.Batch`),
of which the single environment is the N = 1 view.  On small maps a step is one compiled call (each
robot on its own model where maps are redrawn at reset): the N moves, readings and beliefs, the
referee's readout and how each step ends; elsewhere, the engine once per distinct model, then
:mod:`gym_gridloc.referee`.

Random numbers: like Gymnasium's own vector environments (``CartPoleVectorEnv``), ONE generator
serves the whole batch (``reset(seed=s)`` seeds it), and each step draws for all N at once.  A
vector environment of one therefore equals the single environment exactly (same seed, same
actions: same observations, beliefs, rewards and infos: the same step); N environments are the same process as N
single ones, but not their random streams (the tests compare them statistically).

Autoreset: Gymnasium's default ``AutoresetMode.NEXT_STEP`` (the step after an episode ends resets
that environment, ignoring its action, with reward 0); ``autoreset_mode=SAME_STEP`` is available
too (``infos["final_obs"]``, ``infos["final_info"]``).
"""

from __future__ import annotations

import warnings
from typing import Any, Sequence

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from gym_gridloc import kernels, referee
from gym_gridloc.batch import KEEP, START, Batch
from gym_gridloc.core.validation import check_int, is_int, whole_numbers
from gym_gridloc.envs.base import GridLocEnv
from gym_gridloc.observation import BeliefObservation, check_belief_option, check_lookahead


class GridLocVectorEnv(gym.vector.VectorEnv):
    """N copies of a gym_gridloc environment with exact beliefs, stepped in batches.

    Parameters
    ----------
    num_envs:
        N.
    env_class:
        The single environment's class (set by the registered subclasses).
    belief:
        ``"exact"`` (default): Dict observations ``observation`` and ``belief`` batched as
        ``HMMBeliefWrapper`` would give them; ``None``: the readings only.
    flatten, full_state, map, lookahead:
        As for :class:`HMMBeliefWrapper` (with a belief only).
    max_episode_steps:
        Truncation, as ``TimeLimit`` (``gym.make_vec`` passes the registered value; refused below ``episode_length``).
    autoreset_mode:
        ``AutoresetMode.NEXT_STEP`` (default) or ``AutoresetMode.SAME_STEP``.
    **env_kwargs:
        The single environment's keyword arguments (map, size, slip, new_map_each_reset, ...).
    """

    env_class: type[GridLocEnv] = GridLocEnv

    def __init__(
        self,
        num_envs: int = 1,
        *,
        belief: Any = "exact",
        flatten: bool = False,
        full_state: bool = False,
        map: bool = False,
        lookahead: int = 0,
        max_episode_steps: int | None = None,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        render_mode: str | None = None,
        env_class: type[GridLocEnv] | None = None,
        **env_kwargs: Any,
    ) -> None:
        num_envs = check_int("num_envs", num_envs, what="a positive integer", error=ValueError)
        if render_mode is not None:
            raise ValueError(f"the native vector env does not render (render_mode must be None, got {render_mode!r}); use vectorization_mode='sync' to render")
        self.belief = check_belief_option(belief, ("exact", None))
        for name, value in (("flatten", flatten), ("full_state", full_state), ("map", map)):
            if not isinstance(value, (bool, np.bool_)):  # (np.bool_ as the wrapper takes it)
                raise TypeError(f"{name} must be True or False, got {value!r}")
            setattr(self, name, bool(value))
        self.lookahead = check_lookahead(lookahead)
        if self.lookahead and self.belief is None:
            raise ValueError("lookahead needs a belief (belief='exact')")
        if max_episode_steps is not None:
            max_episode_steps = check_int("max_episode_steps", max_episode_steps, what="a positive integer or None", error=ValueError)
        self.autoreset_mode = self._mode(autoreset_mode)
        #: The single environment the N share the parameters of (and, without map redraws, the model).
        self.template = template = (env_class or self.env_class)(**env_kwargs)
        model = template.model
        self.num_envs = n = int(num_envs)
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        self.metadata = {"autoreset_mode": self.autoreset_mode, "render_modes": []}
        self.render_mode = None
        inner = template.observation_space
        #: The observation's space and encoding, as :class:`HMMBeliefWrapper`'s (None: readings only).
        self.builder = None if self.belief is None else BeliefObservation(
            model, inner, flatten=flatten, full_state=full_state, map=map, lookahead=self.lookahead)
        self.single_observation_space = inner if self.builder is None else self.builder.space
        self.single_action_space = template.action_space
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)

        if (length := template.episode_length) is not None and length > (self.max_episode_steps or length):  # cut short
            raise ValueError(f"episode_length={length} is above max_episode_steps={self.max_episode_steps}: give at most that")
        self._limit = length or self.max_episode_steps  # the step count that truncates an episode (None: never)
        #: The N robots, their beliefs, step counts and maps, and the one step of them all.
        self.batch = Batch(model, n, threshold=template.localise_threshold, pose=template.referee_pose,
                           reward=template.reward_kind, limit=self._limit, fixed_length=length is not None,
                           observed=self.builder is not None and self.builder.plain_positions, map_factory=template.map_factory)
        self._redrawn = template.map_factory is not None
        self._autoreset = np.zeros(n, dtype=bool)
        self._started = False
        self._below = getattr(kernels.compiled(self.batch.rows.belief[0].size), "all_below", None)  # the actions' check (None: numpy)

    @staticmethod
    def _mode(mode: Any) -> AutoresetMode:
        try:
            m = AutoresetMode(mode)
        except ValueError:
            m = None
        if m not in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP):
            raise ValueError(f"autoreset_mode must be AutoresetMode.NEXT_STEP or SAME_STEP, got {mode!r}")
        return m

    def set_autoreset_mode(self, mode: AutoresetMode | str) -> None:
        """Switch the autoreset mode while no environment waits to be reset (e.g. for an adapter
        that needs same-step resets)."""
        if self._autoreset.any():
            raise ValueError("cannot switch the autoreset mode while an environment waits for its reset")
        self.autoreset_mode = self._mode(mode)
        self.metadata = {**self.metadata, "autoreset_mode": self.autoreset_mode}

    @property
    def models(self) -> list:
        """Each environment's model (on its current map)."""
        return self.batch.models

    def _observations(self, positions: np.ndarray, observed: np.ndarray | None):
        """The N observations (``positions``, ``observed``: what the step read)."""
        model = self.template.model  # (the family's sensor; the plain observation made in the step needs no other)
        readings = self.batch.rows.readings
        obs = model.sensor.observations(readings)
        models = model if not self._redrawn or observed is not None else self.models
        return obs if self.builder is None else self.builder.encode(models, obs, readings, self.batch.beliefs, positions,
                                                                    observed=observed)

    def _start(self, idx: np.ndarray):
        """New episodes in the environments ``idx`` (the others kept)."""
        modes = np.full(self.num_envs, KEEP, dtype=np.int8)
        modes[idx] = START
        return self.batch.advance(None, modes, self.np_random, maps=self._redrawn)

    # -- Gymnasium API ----------------------------------------------------------------------------
    def reset(self, *, seed: int | Sequence[int] | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        """Reset every environment (or those of ``options["reset_mask"]``).  ``seed``: an int
        seeds the batch's generator; a list of ints seeds it from all of them."""
        n = self.num_envs
        mask = np.ones(n, dtype=bool)
        if options:
            if unknown := set(options) - {"reset_mask"}:
                raise ValueError(f"unknown reset option(s) {sorted(unknown)}; allowed: 'reset_mask'")
            mask = np.asarray(options["reset_mask"])
            if mask.shape != (n,) or mask.dtype != bool:
                raise ValueError(f"options['reset_mask'] must be {n} booleans, got {options['reset_mask']!r}")
            if not self._started and not mask.all():
                raise ValueError(f"the first reset must reset every environment: options['reset_mask'] leaves "
                                 f"environment(s) {np.flatnonzero(~mask).tolist()} without a state")
        if seed is not None:
            self._np_random, self._np_random_seed = self._seeded(seed)
        idx = np.flatnonzero(mask)
        out = self._start(idx)
        self._autoreset[idx] = False
        self._started = True
        return self._observations(out.positions, out.observed), referee.masked(out.info, mask)

    @staticmethod
    def _seeded(seed: Any) -> tuple[np.random.Generator, int]:
        if is_int(seed):
            return seeding.np_random(check_int("seed", seed, 0, what="a non-negative integer", error=ValueError))
        if isinstance(seed, (list, tuple)) and seed and all(is_int(s) and s >= 0 for s in seed):
            words = [int(s) for s in seed]
            rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(words[0] if len(words) == 1 else words)))
            return rng, words[0]
        raise ValueError(f"seed must be a non-negative integer, a list of them, or None; got {seed!r}")

    def step(self, actions: Any) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if not self._started:
            raise RuntimeError("call reset() before step()")
        n = self.num_envs
        same_step = self.autoreset_mode == AutoresetMode.SAME_STEP
        # (NEXT_STEP: the environments that ended last step start again, ignoring their actions;
        # self._autoreset is replaced, never changed in place, so no copy)
        resetting = np.zeros(n, dtype=bool) if same_step else self._autoreset
        acts = self._actions(actions, resetting)
        # moves, new episodes (and their maps), the referee's readout and outcomes: the one step
        info, positions, observed, rewards, terminated, truncated, done = self.batch.advance(
            acts, resetting.view(np.int8), self.np_random, maps=self._redrawn)
        obs = self._observations(positions, observed)
        if same_step and done.any():
            ended = np.flatnonzero(done)
            final_obs = np.full(n, None, dtype=object)
            final_info = np.full(n, None, dtype=object)
            for i in ended:
                final_obs[i] = {k: v[i].copy() for k, v in obs.items()} if isinstance(obs, dict) else obs[i].copy()
                final_info[i] = {k: v[i] for k, v in info.items()}
            out = self._start(ended)
            obs = self._observations(out.positions, out.observed)
            info = {**out.info, "final_obs": final_obs, "_final_obs": done.copy(),
                    "final_info": final_info, "_final_info": done.copy()}
        else:
            self._autoreset = done
        return obs, rewards, terminated, truncated, referee.masked(info, None)

    def _actions(self, actions: Any, resetting: np.ndarray) -> np.ndarray:
        n, k = self.num_envs, self.single_action_space.n
        if (type(actions) is np.ndarray and actions.dtype == np.int64 and actions.shape == (n,)
                and actions.flags.c_contiguous and (self._below(actions, k) if self._below else actions.view(np.uint64).max() < k)):
            # the common case, one pass (a negative action is a huge unsigned one); the engine
            # never writes the actions and ignores those of restarting environments
            return actions
        acts = np.asarray(actions)
        if acts.shape != (n,) or not whole_numbers(acts):
            raise ValueError(f"actions must be {n} integers in 0..{k - 1}, got {actions!r}")
        bad = ~resetting & ((acts < 0) | (acts >= k))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"action {int(acts[i])} of env {i} is not in the action space {self.single_action_space} ({self.models[i].action_legend})")
        return np.where(resetting, 0, acts).astype(np.int64)

    # -- exposed for tests and tools ---------------------------------------------------------------
    @property
    def full_beliefs(self) -> np.ndarray:
        """The exact hidden-state beliefs, (N, L, H, W) float64 (a copy)."""
        return self.batch.beliefs.copy()

    @property
    def position_beliefs(self) -> np.ndarray:
        """The exact position beliefs, (N, H, W) float64."""
        b = self.batch.beliefs
        return b[:, 0].copy() if b.shape[1] == 1 else b.sum(axis=1)

    @property
    def beliefs(self) -> np.ndarray:
        """Deprecated name of :attr:`full_beliefs`."""
        warnings.warn("GridLocVectorEnv.beliefs is deprecated: use full_beliefs", DeprecationWarning, stacklevel=2)
        return self.full_beliefs

    @property
    def states(self) -> np.ndarray:
        """The true hidden states (N, 3): layer, row, col (not part of the observation)."""
        return self.batch.rows.states.copy()


class ColourGridVectorEnv(GridLocVectorEnv):
    """Native vector version of ``ColourGrid-v0`` (see :class:`GridLocVectorEnv`)."""

    from gym_gridloc.envs.colour_grid import ColourGridEnv as env_class  # noqa: N813


class RingSensorVectorEnv(GridLocVectorEnv):
    """Native vector version of ``RingSensor8x8-v0`` (see :class:`GridLocVectorEnv`)."""

    from gym_gridloc.envs.ring_sensor import RingSensorEnv as env_class  # noqa: N813


class WindyMazeVectorEnv(GridLocVectorEnv):
    """Native vector version of ``WindyMaze-v0`` (see :class:`GridLocVectorEnv`)."""

    from gym_gridloc.envs.windy_maze import WindyMazeEnv as env_class  # noqa: N813


class DepthMazeVectorEnv(GridLocVectorEnv):
    """Native vector version of ``DepthMaze-v0`` (see :class:`GridLocVectorEnv`)."""

    from gym_gridloc.envs.depth_maze import DepthMazeEnv as env_class  # noqa: N813
