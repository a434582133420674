"""The policy interface every agent implements: ``reset(seed, model)`` then
``act(observation, belief) -> action`` (see :mod:`gym_gridloc_agents.policies`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from gym_gridloc.core.model import GridModel

#: Values within this relative tolerance of the best are ties.
TIE_TOL = 1e-9


class Policy:
    """Base class.  ``act`` returns an ``int`` action in ``0..n_actions-1``."""

    name = "policy"

    def __init__(self, model: GridModel, *, seed: int | None = None) -> None:
        if not isinstance(model, GridModel):
            raise TypeError(f"a policy needs the environment's GridModel, got {type(model).__name__}")
        Policy.set_model(self, model)  # (not a subclass's: it may need what its __init__ sets next)
        self.rng = np.random.default_rng(seed)

    @classmethod
    def build(cls, model: GridModel, context, **options: Any) -> "Policy":
        """The policy for ``model`` as the policy table builds it: from what
        :func:`~gym_gridloc_agents.policies.make_policy` knows of the environment (``context``, a
        :class:`~gym_gridloc_agents.registry.PolicyContext`) and the options (their names already
        checked against the table).  By default ``cls(model, seed=context.seed, **options)``."""
        return cls(model, seed=context.seed, **options)

    def reset(self, seed: int | None = None, model: GridModel | None = None) -> None:
        """Start an episode: reseed the policy's generator, forget any memory, and follow the
        episode's model when one is given (e.g. a map redrawn at reset)."""
        self.rng = np.random.default_rng(seed)
        if model is not None and model is not self.model:
            if not isinstance(model, GridModel):
                raise TypeError(f"model must be a GridModel, got {type(model).__name__}")
            self.set_model(model)

    def set_model(self, model: GridModel) -> None:
        """Plan on ``model`` from now on (subclasses rebuild what they derived from the model)."""
        self.model = model
        self.n_actions = model.n_actions

    def act(self, observation: Any, belief: np.ndarray) -> int:  # pragma: no cover - abstract
        raise NotImplementedError

    def probabilities(self, observation: Any, belief: np.ndarray) -> np.ndarray:
        """The policy's action distribution here, ``(n_actions,)`` (a step, like :meth:`act`):
        by default all mass on the action :meth:`act` takes; planners spread it evenly over
        their tied best actions (soft labels for imitation)."""
        out = np.zeros(self.n_actions)
        out[self.act(observation, belief)] = 1.0
        return out

    def _full_belief(self, belief: np.ndarray) -> np.ndarray:
        b = np.asarray(belief, dtype=np.float64)
        shape = self.model.belief_shape
        if b.shape == shape:
            return b
        if b.shape == shape[1:] and shape[0] == 1:
            return b[None]
        raise ValueError(
            f"belief must be the hidden-state belief of shape {shape}"
            + (f" or the position belief {shape[1:]}" if shape[0] == 1 else "")
            + f", got shape {b.shape} (use HMMBeliefWrapper(..., full_state=True) or wrapper.filter.full_belief)"
        )

    def choose(self, probabilities: np.ndarray) -> int:
        """An action from an even distribution over tied best actions: the only one without a
        draw, else one uniform choice with the policy's generator (as :meth:`_break_ties`)."""
        return self._one_of(np.flatnonzero(probabilities > 0))

    @staticmethod
    def best(values: np.ndarray) -> np.ndarray:
        """The actions whose value is the lowest within :data:`TIE_TOL` (relative)."""
        low = values.min()
        return np.flatnonzero(values <= low + TIE_TOL * max(1.0, abs(low)))

    def _break_ties(self, values: np.ndarray) -> int:
        return self._one_of(self.best(values))

    def _one_of(self, actions: np.ndarray) -> int:
        """The only action without a draw, else one uniform choice with the policy's generator."""
        return int(actions[0]) if len(actions) == 1 else int(self.rng.choice(actions))
