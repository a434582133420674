"""The step of an episode, written once: N robots, their exact beliefs, their step counts and
their maps, stepped together (as Gymnasium's functional environments write ``initial``,
``transition``, ``observation``, ``reward`` and ``terminal`` once, and adapt them to one
environment or a batch).  :class:`Batch` holds the N by name (:class:`~gym_gridloc.bank.Rows`:
states, readings, beliefs, step counts, each one's model); :meth:`Batch.advance` is the one step:
moves, new episodes (and their maps), readings, beliefs, the referee's ``info``, rewards and ends.
The single environment (:class:`~gym_gridloc.GridLocEnv`) is its N = 1 view, the native vector
environment (:class:`~gym_gridloc.GridLocVectorEnv`) its N view: a vector environment of one is the
single environment by construction.

Behind :meth:`Batch.advance`, one of two implementations, the same draws and numbers (a test holds
them equal): the compiled step (:class:`~gym_gridloc.bank.VectorBank`: one call for the N, each
robot on its model's tables), for the models that have one; else the numpy reference, the
engine's functions (:func:`~gym_gridloc.engine.sample_next`, :func:`~gym_gridloc.engine.sample_readings`,
:func:`~gym_gridloc.engine.step`, :func:`~gym_gridloc.engine.sample_initial`,
:func:`~gym_gridloc.engine.first_posterior`) once per distinct model, then the referee's
:func:`~gym_gridloc.referee.readout` and :func:`~gym_gridloc.referee.outcomes`.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from gym_gridloc import engine, referee
from gym_gridloc.bank import KEEP, START, START_AT, STEP, Rows
from gym_gridloc.core.model import GridModel

__all__ = ["Batch", "Outcome", "STEP", "START", "KEEP", "START_AT"]


class Outcome(NamedTuple):
    """What a step of N rows gives: the referee's ``info`` (arrays of N rows), the ``positions``
    beliefs it read (N, H*W), the observation's float32 position beliefs when the batch makes
    them (``observed``, else None), and the ``rewards``, ``terminated``, ``truncated`` and
    ``done`` of each row (a row that started an episode: reward 0.0, not terminated)."""

    info: dict[str, np.ndarray]
    positions: np.ndarray
    observed: np.ndarray | None
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    done: np.ndarray


class Batch:
    """N robots on ``model`` (or, with ``map_factory``, each on its own map, drawn at each new
    episode), their exact beliefs and step counts, and the referee's rules: ``threshold`` and
    ``pose`` (:func:`~gym_gridloc.referee.summarise`), ``reward`` (:data:`~gym_gridloc.referee.REWARDS`),
    ``limit`` (the step count that truncates; None: never) and ``fixed_length`` (episodes end by
    truncation only).  ``observed``: the steps also make the observation's float32 position
    beliefs.  ``reuse``: the referee's arrays are given as they are, filled again at every step
    (the caller reads them before the next; else they are copies, the caller's to keep), and the
    compiled step
    keeps the tables of N + 1 models, not of as many as its bytes allow (the single environment:
    the maps of past episodes are let go)."""

    def __init__(self, model: GridModel, n: int, *, threshold: float, pose: bool = False, reward: str = "step",
                 limit: int | None = None, fixed_length: bool = False, observed: bool = False,
                 map_factory: Any = None, reuse: bool = False) -> None:
        model = engine.checked_model(model, "the step of N robots needs a GridModel")
        self.n, self.shape, self.map_factory, self.reuse = n, model.belief_shape, map_factory, reuse
        self.rows = Rows(n, int(np.prod(model.belief_shape)))
        self.rules = dict(threshold=threshold, pose=pose, kind=reward, limit=limit, fixed_length=fixed_length)
        self.blocks = referee.Blocks(n, model.shape[0] * model.shape[1], threshold, pose, kind=reward, limit=limit,
                                     fixed_length=fixed_length, observed=observed, states=self.rows.beliefs.shape[2])
        self._models, self._stale = [model] * n, False  # (stale: the bank's slots say which, see models)
        self._groups = [np.arange(n)]  # row indices per distinct model, in index order
        #: The compiled step of the rows' models (None: the numpy reference, once per distinct model).
        self.bank = engine.vector_bank(model, n, n + 1 if reuse else None)
        self._coded: dict[int, GridModel] = {}  # map code -> model: the last codes' (MapFactory.models), as many as the bank holds
        graph = None if map_factory is None else map_factory.graph  # perfect mazes: the compiled step draws them in its call
        self._maps_in_call = bool(self.bank is not None and graph is not None and self.bank.draw_maps(*graph, map_factory.model_of_code))
        self._no_actions = np.zeros(n, dtype=np.int64)

    @property
    def models(self) -> list[GridModel]:
        """Each row's model (on its current map)."""
        if self._stale:  # (the compiled step drew maps: each row's model is its slot's)
            self._models, self._stale = [self.bank.models[s] for s in self.rows.slots.tolist()], False
        return self._models

    @property
    def beliefs(self) -> np.ndarray:
        """The current hidden-state beliefs, (N, L, H, W) (a view: the next step writes the other buffer)."""
        return self.rows.belief.reshape(self.n, *self.shape)

    # -- the one step ----------------------------------------------------------------------------
    def advance(self, actions: np.ndarray | None, modes: np.ndarray, rng: np.random.Generator, *, maps: bool = False,
                one: bool = False) -> Outcome:
        """One step of the N rows: row ``i`` with ``modes[i]`` (int8) ``STEP`` moves under
        ``actions[i]`` (N int64 in ``0..A-1``, checked by the caller; only the moving rows' are
        read; None: no row moves), reads and filters; ``START`` starts an episode at a state
        drawn uniformly (and, with ``maps``, on a newly drawn map); ``START_AT`` starts one at
        the state ``rows.states[i]`` holds; ``KEEP`` keeps the row (its step count too).  All
        draws from ``rng``: with ``maps`` the new maps first where the compiled step draws them
        (after the moves in the numpy reference), the moves, the readings of the moving rows, the
        drawn starts, the readings of the starting rows.  Returns the :class:`Outcome`; ``one``
        (the N = 1 view): of row 0 as the single environment reports it, the ``info`` of
        :func:`~gym_gridloc.referee.scalars`, the reward a ``float``, the ends ``bool`` (the same
        numbers; no ``positions``)."""
        acts = self._no_actions if actions is None else actions
        redrawn = maps and self.bank is not None and not self._maps_in_call
        if redrawn:  # (the maps first; placing them may leave the numpy reference to step)
            self._redraw(np.flatnonzero(modes == START), rng)
        if self.bank is not None:  # one compiled call
            return self._compiled(acts, modes, rng, maps and self._maps_in_call, one)
        out = self._reference(acts, modes, rng, maps and not redrawn)
        return Outcome(referee.scalars(out.info, 0), None, None, *(x.item(0) for x in out[3:])) if one else out

    def _compiled(self, actions: np.ndarray, modes: np.ndarray, rng: np.random.Generator, maps: bool, one: bool) -> Outcome:
        blocks = self.blocks
        self.bank.advance(self.rows, actions, modes, rng, blocks, maps)
        self._stale |= maps
        if one:
            ends = blocks.ends
            return Outcome(blocks.one(self.shape[0]), None, None, blocks.rewards.item(0), ends.item(0, 0), ends.item(1, 0), ends.item(2, 0))
        keep = not self.reuse  # (the infos are the caller's: copies of the blocks, which the next step fills)
        info, positions = blocks.infos(self.shape[0], copy=keep)
        observed = None if not blocks.observed.shape[0] else blocks.observed.copy() if keep else blocks.observed
        return Outcome(info, positions, observed, *blocks.outcomes(copy=keep))

    def _reference(self, actions: np.ndarray, modes: np.ndarray, rng: np.random.Generator, maps: bool) -> Outcome:
        """The numpy reference of the compiled step: the engine's functions once per distinct model."""
        rows, shape = self.rows, (-1, *self.shape)
        moving, starting = np.flatnonzero(modes == STEP), np.flatnonzero((modes == START) | (modes == START_AT))
        belief, spare = rows.belief, rows.spare
        for model, sub in self._by_model(moving):
            rows.states[sub] = engine.sample_next(model, rows.states[sub], actions[sub], rng)
        for model, sub in self._by_model(moving):
            rows.readings[sub] = engine.sample_readings(model, rows.states[sub], rng)
            if sub.size == self.n:
                engine.step(model, belief.reshape(shape), actions, rows.readings, out=spare.reshape(shape))
            else:
                spare[sub] = engine.step(model, belief[sub].reshape(shape), actions[sub], rows.readings[sub])[0].reshape(sub.size, -1)
        if starting.size:
            if maps:
                self._redraw(np.flatnonzero(modes == START), rng)
            for model, sub in self._by_model(np.flatnonzero(modes == START)):
                rows.states[sub] = engine.sample_initial(model, sub.size, rng)
            for model, sub in self._by_model(starting):  # each group's beliefs after its readings (they draw nothing)
                rows.readings[sub] = engine.sample_readings(model, rows.states[sub], rng)
                spare[sub] = engine.first_posterior(model, rows.readings[sub]).reshape(sub.size, -1)
        kept = np.flatnonzero(modes == KEEP)
        spare[kept] = belief[kept]
        rows.flip()
        info, positions = referee.readout(self.beliefs, rows.states, self.rules["threshold"], pose=self.rules["pose"])
        active = modes != KEEP
        restarted = modes != STEP
        outcomes = referee.outcomes(self.rules["kind"], info, restarted, rows.elapsed, self.rules["limit"], self.rules["fixed_length"]) \
            if active.all() else self._kept_outcomes(info, restarted, active)
        return Outcome(info, positions, None, *outcomes)

    def _kept_outcomes(self, info: dict[str, np.ndarray], restarted: np.ndarray, active: np.ndarray):
        """:func:`referee.outcomes` of the rows that are not kept (the kept rows: reward 0.0, not
        ended, step counts as they were)."""
        elapsed = self.rows.elapsed[active]
        part = {"localised": info["localised"][active], "confidence": info["confidence"][active]}
        got = referee.outcomes(self.rules["kind"], part, restarted[active], elapsed, self.rules["limit"], self.rules["fixed_length"])
        self.rows.elapsed[active] = elapsed
        out = (np.zeros(self.n), np.zeros(self.n, dtype=bool), np.zeros(self.n, dtype=bool), np.zeros(self.n, dtype=bool))
        for whole, values in zip(out, got):
            whole[active] = values
        return out

    # -- maps ------------------------------------------------------------------------------------
    def set_models(self, idx: np.ndarray, models: list[GridModel]) -> None:
        """Put the rows ``idx`` on ``models`` (each placed in the bank; the bank dropped, for the
        numpy reference, when it cannot hold one)."""
        current, bank = self.models, self.bank
        for i, model in zip(idx.tolist(), models):
            current[i] = model
            slot = None if bank is None else bank.slot(model, self.rows.slots)
            if slot is None:
                bank = self.bank = None
            else:
                self.rows.slots[i] = slot
        if bank is None:
            self._regroup()

    def _redraw(self, idx: np.ndarray, rng: np.random.Generator) -> None:
        """New maps for the rows ``idx`` (in index order, from ``rng``)."""
        if idx.size:
            bank = self.bank
            self.set_models(idx, self.map_factory.models(rng, idx.size, self._coded, None if bank is None else bank.limit))

    def _regroup(self) -> None:
        groups: dict[int, list[int]] = {}
        for i, m in enumerate(self.models):
            groups.setdefault(id(m), []).append(i)
        self._groups = [np.array(g) for g in groups.values()]
        self._group_of = np.empty(self.n, dtype=np.int64)  # each row's group, groups in order
        for k, g in enumerate(self._groups):
            self._group_of[g] = k

    def _by_model(self, idx: np.ndarray):
        """``(model, indices)`` of ``idx`` per distinct model, in group order, indices ascending."""
        if idx.size == 0:
            return
        if len(self._groups) == 1:
            yield self.models[0], idx
            return
        gid = self._group_of[idx]
        order = np.argsort(gid, kind="stable")
        cuts = np.flatnonzero(np.diff(gid[order])) + 1
        for sub in np.split(idx[order], cuts):
            yield self.models[sub[0]], sub
