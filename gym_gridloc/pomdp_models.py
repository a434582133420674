"""pomdp_py's classes of :mod:`gym_gridloc.interop`'s adapter (:func:`classes`): its states, actions
and observations, the plain POMDP's transition, observation, reward and policy models, the planning
model that ends at the referee's test, and the particle belief.  pomdp_py's base classes exist only
once it is imported, so these are defined inside a function, once, when the adapter is first made;
:func:`import_pomdp_py` imports it or says how to install it.
"""

from __future__ import annotations

import functools
import numpy as np

from gym_gridloc import engine

__all__ = ["INSTALL_HINT", "classes", "import_pomdp_py"]

#: How to get the optional dependency.
INSTALL_HINT = "pip install 'gym_gridloc[planning]'"


def import_pomdp_py():
    """The optional ``pomdp_py`` module, or an ImportError that says how to install it (the POMCP
    planner of the agents package imports it the same way)."""
    try:
        import pomdp_py
    except ImportError as exc:  # pragma: no cover - exercised without the extra
        raise ImportError(
            f"gym_gridloc.interop.to_pomdp_py needs the optional dependency pomdp_py ({exc}); install it with: {INSTALL_HINT}"
        ) from exc
    return pomdp_py


class _Served:
    """A mixin of pomdp_py's models below: each serves the adapter
    (:class:`gym_gridloc.interop.PomdpPy`) it is made with."""

    __slots__ = ()

    def __init__(self, pp: "gym_gridloc.interop.PomdpPy") -> None:
        self.pp = pp


class _Immutable:
    """A mixin of the value classes below: hashed and compared (with objects of the same class) by
    the attribute ``KEY`` names; immutable, so a deep copy is the object itself."""

    __slots__ = ()
    KEY = ""

    def __hash__(self) -> int:
        return hash(getattr(self, self.KEY))

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and getattr(self, self.KEY) == getattr(other, self.KEY)

    def __deepcopy__(self, memo: dict) -> _Immutable:
        return self


@functools.cache
def classes() -> dict[str, type]:
    """pomdp_py's subclasses for the adapter's models (by class name), defined once pomdp_py is
    importable."""
    pomdp_py = import_pomdp_py()

    class State(_Immutable, pomdp_py.State):
        """A hidden state ``(layer, row, col)`` (hashable, immutable)."""

        __slots__ = ("col", "layer", "row")
        KEY = "tuple"

        def __init__(self, layer: int, row: int, col: int) -> None:
            self.layer, self.row, self.col = int(layer), int(row), int(col)

        @property
        def tuple(self) -> tuple[int, int, int]:
            return (self.layer, self.row, self.col)

        def __repr__(self) -> str:
            return f"State{self.tuple}"

    class PlanState(State):
        """A hidden state and the node of the simulated history (its exact belief): the state of
        the planning model (see the module docstring).  Equal when both agree."""

        __slots__ = ("node",)
        KEY = "key"

        def __init__(self, layer: int, row: int, col: int, node: "gym_gridloc.interop._Node") -> None:
            State.__init__(self, layer, row, col)
            self.node = node

        @property
        def key(self) -> tuple[int, int, int, int]:
            return (self.layer, self.row, self.col, id(self.node))

        def __repr__(self) -> str:
            return f"PlanState{self.tuple}{' done' if self.node.done else ''}"

    class Action(_Immutable, pomdp_py.Action):
        """An action index; ``name`` is the model's name for it."""

        KEY = "index"

        def __init__(self, index: int, name: str) -> None:
            self.index = int(index)
            self.name = str(name)

        def __repr__(self) -> str:
            return f"Action({self.index}={self.name})"

    class Observation(_Immutable, pomdp_py.Observation):
        """A reading index (``-1``: the planning model's "the episode is over")."""

        __slots__ = ("reading",)
        KEY = "reading"

        def __init__(self, reading: int) -> None:
            self.reading = int(reading)

        def __repr__(self) -> str:
            return f"Observation({self.reading})"

    class TransitionModel(_Served, pomdp_py.TransitionModel):
        """``P(s' | s, a)`` exactly from :meth:`GridModel.outcomes` (kidnapping mixed in);
        ``sample`` through :func:`gym_gridloc.engine.sample_next` with the adapter's generator."""

        def probability(self, next_state, state, action) -> float:
            m = self.pp.model
            target = next_state.tuple
            p = 0.0
            for s2, q in m.outcomes(state.tuple, action.index):
                if s2 == target:
                    p += q
            return engine.kidnapped(m, p)

        def sample(self, state, action):
            return self.pp.to_state(self.pp.sample_next(state.tuple, action.index))

        def get_all_states(self) -> list:
            """Every hidden state (a list of ``n_states``: small models only)."""
            return [State(*self.pp.model.state_of_index(i)) for i in range(self.pp.model.n_states)]

        def argmax(self, state, action):
            return self.pp.to_state(max(self.pp.model.outcomes(state.tuple, action.index), key=lambda o: o[1])[0])

    class ObservationModel(_Served, pomdp_py.ObservationModel):
        """``P(o | s', a)`` exactly from the sensor's likelihood (the action plays no part);
        ``sample`` through :func:`gym_gridloc.engine.sample_readings` with the adapter's generator."""

        def probability(self, observation, next_state, action) -> float:
            z = observation.reading
            if not 0 <= z < self.pp.model.sensor.n_readings:
                return 0.0
            return float(self.pp.likelihood_table[z, self.pp.model.state_index(next_state.tuple)])

        def sample(self, next_state, action):
            return self.pp.observations[self.pp.sample_reading(next_state.tuple)]

        def get_all_observations(self) -> list:
            return list(self.pp.observations)

        def argmax(self, next_state, action):
            col = self.pp.likelihood_table[:, self.pp.model.state_index(next_state.tuple)]
            return self.pp.observations[int(np.argmax(col))]

    class RewardModel(pomdp_py.RewardModel):
        """-1 per step (see the module docstring for how this relates to the referee)."""

        def sample(self, state, action, next_state) -> float:
            return -1.0

        argmax = sample

        def probability(self, reward, state, action, next_state) -> float:
            return 1.0 if reward == -1.0 else 0.0

    class PolicyModel(_Served, pomdp_py.RolloutPolicy):
        """Uniform over the actions (every action is possible everywhere); also POMCP's rollout
        policy, drawing with the adapter's generator (not Python's ``random``)."""

        def get_all_actions(self, state=None, history=None) -> list:
            return list(self.pp.actions)

        def probability(self, action, state) -> float:
            return 1.0 / len(self.pp.actions)

        def sample(self, state):
            return self.pp.actions[self.pp.random_action()]

        def rollout(self, state, history=None):
            node = getattr(state, "node", None)
            if node is not None and node.done:  # the episode is over: every action is the same
                return self.pp.actions[0]
            return self.sample(state)

    class LocalisationModel(_Served, pomdp_py.BlackboxModel):
        """The planning model ``(s', o, r, 1) ~ G(s, a)`` on :class:`PlanState`: the plain POMDP's
        step, ending (absorbing, reward 0, observation ``done``) once the exact belief of the
        simulated history passes the referee's test (see the module docstring)."""

        def sample(self, state, action):
            if state.node.done:
                return state, self.pp.done, 0.0, 1
            nxt = self.pp.sample_next(state.tuple, action.index)
            z = self.pp.sample_reading(nxt)
            return PlanState(*nxt, state.node.child(action.index, z)), self.pp.observations[z], -1.0, 1

    class ParticleBelief(pomdp_py.Particles):
        """Unweighted particles that draw with the adapter's generator (pomdp_py's draw with
        Python's global ``random``); a deep copy copies the list only (states are immutable)."""

        def __init__(self, particles: list, pp: "gym_gridloc.interop.PomdpPy") -> None:
            super().__init__(particles)
            self._list = particles
            self._pp = pp

        def random(self):
            return self._list[int(self._pp.rng.integers(len(self._list)))] if self._list else None

        def __deepcopy__(self, memo: dict) -> ParticleBelief:
            return ParticleBelief(list(self._list), self._pp)

    return {k: v for k, v in locals().items() if isinstance(v, type)}
