"""A native vector environment: N robots and N exact beliefs stepped by the engine in batches.

``gym.make_vec(ENV_ID, num_envs=N, vectorization_mode="vector_entry_point")`` builds a
:class:`GridLocVectorEnv`.  On small maps a step is one compiled call of the engine
(:class:`engine.VectorBank`, each robot on its own model where maps are redrawn at reset): the N
moves, readings and beliefs, the referee's readout and how each step ends; elsewhere, the engine
once per distinct model, then :mod:`gym_gridloc.referee`.  The numbers of the single environment.

Random numbers: like Gymnasium's own vector environments (``CartPoleVectorEnv``), ONE generator
serves the whole batch (``reset(seed=s)`` seeds it), and each step draws for all N at once.  A
vector environment of one therefore equals the single environment exactly (same seed, same
actions: same observations, beliefs, rewards and infos); N environments are the same process as N
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

from gym_gridloc import engine, kernels, referee
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

        self._models, self._stale = [model] * n, False  # (stale: the bank's slots say which, see models)
        self._groups = [np.arange(n)]  # env indices per distinct model, in index order
        self._beliefs, self._spare = np.zeros((n, *model.belief_shape)), np.zeros((n, *model.belief_shape))
        self._states, self._readings = np.zeros((n, 3), dtype=np.int64), np.zeros(n, dtype=np.int64)
        self._elapsed, self._autoreset = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=bool)
        self._started = False
        #: engine.VectorBank of the environments' models (None: no compiled step; one engine call per model)
        self._bank = engine.vector_bank(model, n)
        self._slots = np.zeros(n, dtype=np.int64)  # each environment's slot in the bank
        self._observed = self.builder is not None and self.builder.plain_positions  # (the engine's step writes it)
        self._coded: dict[int, Any] = {}  # map code -> model: the last codes' (MapFactory.models), as many as the bank holds
        factory = template.map_factory  # perfect mazes: the engine's step draws the new ones itself, in its one call
        self._maps_in_call = bool(self._bank is not None and factory is not None and factory.graph is not None
                                  and self._bank.draw_maps(*factory.graph, factory.model_of_code))
        self._below = getattr(kernels.compiled(self._beliefs[0].size), "all_below", None)  # the actions' check (None: numpy)
        if (length := template.episode_length) is not None and length > (self.max_episode_steps or length):  # cut short
            raise ValueError(f"episode_length={length} is above max_episode_steps={self.max_episode_steps}: give at most that")
        self._limit = length or self.max_episode_steps  # the step count that truncates an episode (None: never)

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
        if self._stale:  # (the engine's step drew maps: each row's model is its slot's)
            self._models, self._stale = [self._bank.models[s] for s in self._slots.tolist()], False
        return self._models

    # -- the batch through the engine --------------------------------------------------------------
    def _regroup(self) -> None:
        groups: dict[int, list[int]] = {}
        for i, m in enumerate(self.models):
            groups.setdefault(id(m), []).append(i)
        self._groups = [np.array(g) for g in groups.values()]
        self._group_of = np.empty(self.num_envs, dtype=np.int64)  # each env's group, groups in order
        for k, g in enumerate(self._groups):
            self._group_of[g] = k

    def _by_model(self, idx: np.ndarray):
        """``(model, indices)`` of ``idx`` per distinct model, in group order, indices ascending."""
        if len(self._groups) == 1:
            yield self.models[0], idx
            return
        gid = self._group_of[idx]
        order = np.argsort(gid, kind="stable")
        cuts = np.flatnonzero(np.diff(gid[order])) + 1
        for sub in np.split(idx[order], cuts):
            yield self.models[sub[0]], sub

    def _redraw(self, idx: np.ndarray) -> None:
        """New maps for the environments ``idx`` (in index order, from the batch's generator), each
        placed in the bank (dropped, for one engine call per model, when it cannot hold one)."""
        models, bank = self.models, self._bank
        drawn = self.template.map_factory.models(self.np_random, idx.size, self._coded, None if bank is None else bank.limit)
        for i, model in zip(idx.tolist(), drawn):
            models[i] = model
            slot = None if bank is None else bank.slot(model, self._slots)
            if slot is None:
                bank = self._bank = None
            else:
                self._slots[i] = slot
        if bank is None:
            self._regroup()

    def _restart(self, idx: np.ndarray, *, redrawn: bool = False) -> None:
        """Start new episodes in the environments ``idx``: maps (if redrawn, and not ``redrawn``
        already), states, readings, beliefs, drawn in the single environment's order."""
        rng = self.np_random
        drawing = self.template.map_factory is not None and not redrawn
        if drawing and not self._maps_in_call:
            self._redraw(idx)
        if self._bank is not None:  # one compiled call; the other rows keep their beliefs
            modes = np.full(self.num_envs, 2, dtype=np.int8)
            modes[idx] = 1
            self._advance(np.zeros_like(self._readings), modes, maps=drawing and self._maps_in_call)
            self._elapsed[idx] = 0
            return
        for model, sub in self._by_model(idx):
            self._states[sub] = engine.sample_initial(model, sub.size, rng)
        for model, sub in self._by_model(idx):  # each group's beliefs after its readings (they draw nothing)
            self._readings[sub] = engine.sample_readings(model, self._states[sub], rng)
            self._beliefs[sub] = engine.first_posterior(model, self._readings[sub])
        self._elapsed[idx] = 0

    def _advance(self, actions: np.ndarray, modes: np.ndarray, restarted: np.ndarray | None = None, maps: bool = False):
        """Every environment in one engine call (:class:`engine.VectorBank`; ``modes`` as :func:`engine.vector_advancer`'s;
        ``maps``: the call draws the starting rows' maps). A step (``restarted``: the rows that started an episode)
        reads in the same call, and returns :meth:`_infos`'s infos and position beliefs, :func:`referee.outcomes`'s,
        and the plain observation's belief (else None)."""
        n, t, blocks, ending = self.num_envs, self.template, None, None
        if restarted is not None:
            blocks = referee.readout_blocks(n, self._beliefs.shape[2] * self._beliefs.shape[3], t.localise_threshold,
                                            t.referee_pose, observed=self._observed)
            ending = referee.ending_blocks(t.reward_kind, restarted, self._elapsed, self._limit, t.episode_length is not None)
        self._bank.advance(self._states, self._readings, actions, self._beliefs.reshape(n, -1), self._spare.reshape(n, -1),
                           modes, self.np_random, self._slots, blocks, ending, maps)
        self._beliefs, self._spare = self._spare, self._beliefs
        self._stale |= maps
        if blocks is None:  # (a restart: the caller reads the infos)
            return None
        info, positions = referee.read_blocks(blocks, self._beliefs.shape[1])
        return info, positions, referee.ended(ending), blocks[8] if self._observed else None

    def _move(self, idx: np.ndarray, actions: np.ndarray) -> None:
        """One step of the environments ``idx``: moves, readings, beliefs."""
        rng = self.np_random
        if len(self._groups) == 1:  # one model: one engine call for all (engine.advancer)
            advance = engine.advancer(self.models[0])
            n = self.num_envs
            if idx.size == n:
                beliefs, out = self._beliefs.reshape(n, -1), self._spare.reshape(n, -1)
                self._states, self._readings = advance(self._states, actions, beliefs, out, rng)
                self._beliefs, self._spare = self._spare, self._beliefs
            else:
                beliefs = self._beliefs.reshape(n, -1)[idx]
                out = np.empty_like(beliefs)
                self._states[idx], self._readings[idx] = advance(self._states[idx], actions[idx], beliefs, out, rng)
                self._beliefs.reshape(n, -1)[idx] = out
            return
        for model, sub in self._by_model(idx):
            self._states[sub] = engine.sample_next(model, self._states[sub], actions[sub], rng)
        for model, sub in self._by_model(idx):
            self._readings[sub] = engine.sample_readings(model, self._states[sub], rng)
            self._beliefs[sub] = engine.step(model, self._beliefs[sub], actions[sub], self._readings[sub])[0]

    # -- observations and infos -------------------------------------------------------------------
    def _observations(self, positions: np.ndarray | None = None, observed: np.ndarray | None = None):
        """The N observations (``positions``, ``observed``: what :meth:`_infos` or :meth:`_advance` read)."""
        model = self.template.model  # (the family's sensor; the plain observation made in the step needs no other)
        obs = model.sensor.observations(self._readings)
        models = model if self.template.map_factory is None or observed is not None else self.models
        return obs if self.builder is None else self.builder.encode(models, obs, self._readings, self._beliefs, positions,
                                                                    observed=observed)

    def _infos(self) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """The referee's infos and the position beliefs it read (:func:`referee.readout`)."""
        t = self.template
        return referee.readout(self._beliefs, self._states, t.localise_threshold, pose=t.referee_pose)

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
        self._restart(idx)
        self._autoreset[idx] = False
        self._started = True
        info, positions = self._infos()
        return self._observations(positions), referee.masked(info, mask)

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
        in_call = self._maps_in_call
        starting = resetting.nonzero()[0] if self._bank is not None and self.template.map_factory is not None and not in_call else ()
        if redrawn := len(starting) > 0:  # maps first, then the one call's draws (moves, starts, readings)
            self._redraw(starting)
        if self._bank is not None:  # (new maps,) moves, new episodes, the referee's readout and outcomes in one engine call
            info, positions, (rewards, terminated, truncated, done), observed = self._advance(acts, resetting.view(np.int8), resetting, in_call)
        else:
            observed = None
            moving = np.flatnonzero(~resetting)
            if moving.size:
                self._move(moving, acts)
            if resetting.any():
                self._restart(np.flatnonzero(resetting), redrawn=redrawn)
            info, positions = self._infos()
            rewards, terminated, truncated, done = referee.outcomes(
                self.template.reward_kind, info, resetting, self._elapsed, self._limit, self.template.episode_length is not None,
                cells=self._beliefs[0].size)  # (and the step counts: +1, or 0 where restarted)
        obs = self._observations(positions, observed)
        if same_step and done.any():
            ended = np.flatnonzero(done)
            final_obs = np.full(n, None, dtype=object)
            final_info = np.full(n, None, dtype=object)
            for i in ended:
                final_obs[i] = {k: v[i].copy() for k, v in obs.items()} if isinstance(obs, dict) else obs[i].copy()
                final_info[i] = {k: v[i] for k, v in info.items()}
            self._restart(ended)
            info, positions = self._infos()
            obs = self._observations(positions)
            info = {**info, "final_obs": final_obs, "_final_obs": done.copy(),
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
        return self._beliefs.copy()

    @property
    def position_beliefs(self) -> np.ndarray:
        """The exact position beliefs, (N, H, W) float64."""
        b = self._beliefs
        return b[:, 0].copy() if b.shape[1] == 1 else b.sum(axis=1)

    @property
    def beliefs(self) -> np.ndarray:
        """Deprecated name of :attr:`full_beliefs`."""
        warnings.warn("GridLocVectorEnv.beliefs is deprecated: use full_beliefs", DeprecationWarning, stacklevel=2)
        return self.full_beliefs

    @property
    def states(self) -> np.ndarray:
        """The true hidden states (N, 3): layer, row, col (not part of the observation)."""
        return self._states.copy()


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
