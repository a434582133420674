"""A :class:`~gym_gridloc.core.model.GridModel` as a `pomdp_py <https://h2r.github.io/pomdp-py/>`_
POMDP, for its planners (POMCP, POUCT) and its tools.

:func:`to_pomdp_py` builds pomdp_py's models from the model's numbers: probabilities exactly from
:meth:`GridModel.outcomes` (kidnapping mixed in) and the sensor's likelihoods, samples through
:func:`gym_gridloc.engine.sample_next` and :func:`~gym_gridloc.engine.sample_readings` with a numpy
generator the adapter owns (seedable, so a planner on it is reproducible).  pomdp_py is an optional
dependency (``pip install 'gym_gridloc[planning]'``); it is imported only when
:func:`to_pomdp_py` is called (pomdp_py's classes of the adapter: :mod:`gym_gridloc.pomdp_models`).

Reward and the referee
----------------------
Our objective is the number of steps until the referee's test holds: the largest posterior
probability of a position (of a pose, where the referee tests poses) reaches ``threshold``.  That is
a property of the *belief*, not of the hidden state, so no state-based POMDP expresses it by itself:

* The plain POMDP (``transition_model``, ``observation_model``, ``reward_model``) gives -1 per step
  in every state and has no terminal state.  Every policy then has the same value (the same sum of
  -1s up to the planner's depth): a planner on these models alone sees no difference between actions
  (POMCP on them picks by tie-breaking, in practice the first action).  It is the faithful
  translation of the model (for exact probabilities, value iteration on a fixed horizon, export to
  ``.pomdp`` files), not something to plan localisation with.
* The planning model (``blackbox_model``, a :class:`pomdp_py.BlackboxModel`) is the same POMDP with
  the referee inside: its state is a hidden state together with the node of the simulated history,
  which holds the exact belief after that history (the root belief stepped by
  :func:`gym_gridloc.engine.stepper` with each simulated action and reading, computed once per node).
  A step from a history whose belief does not pass the referee's test costs -1; once it passes, the
  episode is over: the state is absorbing, the reward 0 and the observation :attr:`PomdpPy.done`.
  With ``discount=1`` the return of a simulation is minus the number of steps until the referee's
  test holds, cut at the planner's depth; POMCP maximising it minimises the expected number of steps
  the benchmark counts (the benchmark applies the same test outside pomdp_py, to the environment's
  own exact posterior, and ends the real episode there).  :meth:`PomdpPy.agent` builds an agent on
  this model by default.

>>> from gym_gridloc import windy_maze_model
>>> from gym_gridloc.interop import to_pomdp_py
>>> pp = to_pomdp_py(windy_maze_model(), seed=0)          # doctest: +SKIP
>>> agent = pp.agent(windy_maze_model().prior())          # doctest: +SKIP
>>> import pomdp_py; pomdp_py.POMCP(num_sims=300, max_depth=30, discount_factor=1.0,
...     rollout_policy=pp.policy_model).plan(agent)        # doctest: +SKIP
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gym_gridloc import engine, referee
from gym_gridloc.core.model import GridModel
from gym_gridloc.pomdp_models import INSTALL_HINT, classes, import_pomdp_py
from gym_gridloc.core.validation import check_int, check_threshold, whole_numbers

__all__ = ["INSTALL_HINT", "PomdpPy", "to_pomdp_py"]


class _Node:
    """A simulated history's exact belief, whether it passes the referee's test, and its children
    by ``(action, reading)`` (made on first use)."""

    __slots__ = ("belief", "children", "done", "pp")

    def __init__(self, pp: PomdpPy, belief: np.ndarray) -> None:
        self.pp = pp
        self.belief = belief
        self.done = pp.localised(belief)
        self.children: dict[int, _Node] = {}

    def child(self, action: int, reading: int) -> _Node:
        key = action * self.pp.n_readings + reading
        node = self.children.get(key)
        if node is None:
            out = np.empty_like(self.belief)
            self.pp._step(self.belief, action, reading, out)
            node = self.children[key] = _Node(self.pp, out)
        return node


@dataclass(eq=False)
class PomdpPy:
    """What :func:`to_pomdp_py` returns: pomdp_py's models of a :class:`GridModel`, the classes
    they use, and conversions.

    Models: ``transition_model``, ``observation_model``, ``reward_model`` (the plain POMDP, -1 per
    step), ``policy_model`` (uniform; POMCP's rollout policy), ``blackbox_model`` (the planning
    model, which ends at the referee's test: see the module docstring).  Classes: ``State``,
    ``PlanState``, ``Action``, ``Observation``, ``ParticleBelief``.  Every sample is drawn with
    :attr:`rng` (:meth:`seed` replaces it).
    """

    model: GridModel
    threshold: float
    pose: bool
    discount: float
    rng: np.random.Generator
    classes: dict[str, type] = field(repr=False)
    actions: tuple = field(init=False, repr=False)
    observations: tuple = field(init=False, repr=False)
    done: Any = field(init=False, repr=False)

    def __post_init__(self) -> None:
        c = self.classes
        self.State, self.PlanState, self.Action, self.Observation = c["State"], c["PlanState"], c["Action"], c["Observation"]
        self.ParticleBelief = c["ParticleBelief"]
        self.n_readings = int(self.model.sensor.n_readings)
        self.actions = tuple(self.Action(i, n) for i, n in enumerate(self.model.action_names))
        self.observations = tuple(self.Observation(z) for z in range(self.n_readings))
        self.done = self.Observation(-1)
        self.transition_model = c["TransitionModel"](self)
        self.observation_model = c["ObservationModel"](self)
        self.reward_model = c["RewardModel"]()
        self.policy_model = c["PolicyModel"](self)
        self.blackbox_model = c["LocalisationModel"](self)
        self._step = engine.stepper(self.model)
        self.seed(self.rng)

    # -- randomness ------------------------------------------------------------------------------
    def seed(self, seed: Any = None) -> None:
        """Draw from ``np.random.default_rng(seed)`` from now on (a Generator is used as given)."""
        self.rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        self._actions_drawn, self._next_drawn = [], 0

    def random_action(self) -> int:
        """A uniform action index (drawn from :attr:`rng` 1024 at a time)."""
        i = self._next_drawn
        if i >= len(self._actions_drawn):
            self._actions_drawn, i = self.rng.integers(len(self.actions), size=1024).tolist(), 0
        self._next_drawn = i + 1
        return self._actions_drawn[i]

    def sample_next(self, state: tuple[int, int, int], action: int) -> tuple[int, int, int]:
        """One draw of :func:`gym_gridloc.engine.sample_next` for one state."""
        nxt = engine.sample_next(self.model, np.array([state], dtype=np.int64), int(action), self.rng)[0]
        return int(nxt[0]), int(nxt[1]), int(nxt[2])

    def sample_reading(self, state: tuple[int, int, int]) -> int:
        """One draw of :func:`gym_gridloc.engine.sample_readings` for one state."""
        return int(engine.sample_readings(self.model, np.array([state], dtype=np.int64), self.rng)[0])

    # -- numbers ---------------------------------------------------------------------------------
    @functools.cached_property
    def likelihood_table(self) -> np.ndarray:
        """``P(reading | state)`` as a ``(n_readings, n_states)`` array (built on first use)."""
        table = np.stack([self.model.likelihood_vector(z) for z in range(self.n_readings)])
        table.setflags(write=False)
        return table

    def confidence(self, belief: np.ndarray) -> float:
        """The referee's confidence in an exact belief ``(L, H, W)``: the largest position (pose,
        with ``pose``) probability (:func:`gym_gridloc.referee.confidences`)."""
        return float(referee.confidences(np.asarray(belief)[None], pose=self.pose)[0])

    def localised(self, belief: np.ndarray) -> bool:
        """The referee's test (:func:`gym_gridloc.referee.localised`): :meth:`confidence` reaches
        ``threshold``."""
        return bool(referee.localised(np.asarray(belief)[None], self.threshold, pose=self.pose)[0])

    # -- conversions -----------------------------------------------------------------------------
    def to_state(self, state: Any):
        """``(layer, row, col)`` (a tuple or an array) of a free state as a :class:`State`."""
        arr = np.asarray(state)
        if arr.size != 3 or not whole_numbers(arr):
            raise ValueError(f"state must be three whole numbers (layer, row, col), got {state!r}")
        layer, r, c = (int(v) for v in arr.reshape(3))
        if not (all(0 <= v < n for v, n in zip((layer, r, c), self.model.belief_shape)) and self.model.grid.free[r, c]):
            raise ValueError(f"{(layer, r, c)} is not a free state (layer, row, col) of {self.model!r}")
        return self.State(layer, r, c)

    @staticmethod
    def from_state(state) -> tuple[int, int, int]:
        """A :class:`State` (or :class:`PlanState`) as ``(layer, row, col)``."""
        return state.tuple

    def to_action(self, action: Any):
        return self.actions[self.model.check_action(action)]

    @staticmethod
    def from_action(action) -> int:
        return action.index

    def to_observation(self, observation: Any):
        """An observation as the environment emits it as an :class:`Observation`."""
        return self.observations[self.model.sensor.to_reading(observation)]

    def from_observation(self, observation) -> Any:
        """An :class:`Observation` as the environment would emit it."""
        if observation.reading < 0:
            raise ValueError("the planning model's 'done' observation has no environment observation")
        return self.model.sensor.to_observation(observation.reading)

    # -- beliefs and agents ----------------------------------------------------------------------
    def _belief(self, belief: np.ndarray) -> np.ndarray:
        b = np.asarray(belief, dtype=np.float64)
        shape = self.model.belief_shape
        if b.shape == shape[1:] and shape[0] == 1:
            b = b[None]
        if b.shape != shape:
            raise ValueError(f"belief must have shape {shape}, got {b.shape}")
        if (b < 0).any() or not np.isfinite(b).all() or (b[~self.model.state_mask] != 0).any() or not b.sum() > 0:
            raise ValueError("belief must be non-negative, finite, zero on obstacles and not all zero")
        return np.ascontiguousarray(b / b.sum())

    def draw_states(self, belief: np.ndarray, n: int) -> list[tuple[int, int, int]]:
        """``n`` hidden states drawn independently from an exact belief ``(L, H, W)``."""
        n = check_int("n", n, whole=True, what="a whole number >= 1", error=ValueError)  # (never int(1.5) = 1)
        vec = self.model.to_vector(self._belief(belief))
        idx = self.rng.choice(vec.size, size=n, p=vec / vec.sum())
        return [self.model.state_of_index(int(i)) for i in idx]

    def particles(self, belief: np.ndarray, n: int = 1000, *, plan: bool = True):
        """A :class:`ParticleBelief` of ``n`` states drawn from an exact belief: :class:`PlanState`
        at the root of a new history tree (``plan``) or plain :class:`State`."""
        b = self._belief(belief)
        make = functools.partial(self.PlanState, node=_Node(self, b)) if plan else self.State
        return self.ParticleBelief([make(*s) for s in self.draw_states(b, n)], self)

    def agent(self, belief: np.ndarray, *, n_particles: int = 1000, plan: bool = True):
        """A ``pomdp_py.Agent`` whose belief is ``n_particles`` particles drawn from the exact
        belief ``(L, H, W)``.  ``plan`` (default): on the planning model (the blackbox that ends at
        the referee's test); ``plan=False``: on the plain POMDP's explicit models."""
        pomdp_py = import_pomdp_py()
        check_int("n_particles", n_particles, what="a whole number >= 1", error=ValueError)
        init = self.particles(belief, n_particles, plan=plan)
        models = ({"blackbox_model": self.blackbox_model} if plan
                  else {"transition_model": self.transition_model, "reward_model": self.reward_model})
        return pomdp_py.Agent(init, policy_model=self.policy_model, observation_model=self.observation_model, **models)


def to_pomdp_py(model: GridModel, *, threshold: float = referee.LOCALISE_THRESHOLD, discount: float = 1.0, pose: bool = False,
                seed: Any = None) -> PomdpPy:
    """pomdp_py's models of ``model`` (see :class:`PomdpPy` and the module docstring).

    ``threshold`` and ``pose`` are the referee's (``localise_threshold``, ``referee_pose``): the
    planning model ends where the referee would.  ``discount`` is the discount a planner on these
    models should use (1: the return is minus the number of steps; kept on the adapter for
    planners, pomdp_py's models do not discount).  ``seed``: the adapter's generator (an int, a
    Generator or None).  Needs pomdp_py (``pip install 'gym_gridloc[planning]'``).
    """
    made = classes()
    if not isinstance(model, GridModel):
        raise TypeError(f"to_pomdp_py needs a GridModel, got {type(model).__name__}")
    thr = check_threshold("threshold", threshold)
    d = check_threshold("discount", discount)
    if not isinstance(pose, (bool, np.bool_)):  # bool("no") is True
        raise TypeError(f"pose must be True or False, got {pose!r}")
    return PomdpPy(model=model, threshold=thr, pose=bool(pose), discount=d, rng=seed, classes=made)