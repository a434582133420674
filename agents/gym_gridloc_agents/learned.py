"""The learned policies: each loads a model file (``agents/gym_gridloc_agents/models/`` by default,
:data:`POLICY_DIR`) and acts on what its model was trained on: ``ppo`` (:class:`PPOPolicy`, a PPO
model on the belief observation), ``distilled`` (:class:`DistilledPolicy`, a PPO network that
imitated a planner) and ``recurrent`` (:class:`RecurrentPolicy`, a RecurrentPPO model on the raw
readings); where the shipped models are found (:func:`default_model_path`).
:mod:`gym_gridloc_agents.policies` re-exports these names.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from gym_gridloc.core.model import GridModel
from gym_gridloc.observation import BeliefObservation
from gym_gridloc.wrappers import previous_action_space, with_previous_action
from gym_gridloc_agents.base import Policy
from gym_gridloc_agents.files import read_metadata
from gym_gridloc_agents.history import acting_history, with_history_space
from gym_gridloc_agents.loading import METHODS, load_model, model_kwargs, model_method, plain_id

#: Where the shipped models live: ``<env_id>[-size<N>]-<method>.zip``, method ``ppo``, ``distilled``
#: or ``recurrent`` (:data:`gym_gridloc_agents.loading.METHODS`).
POLICY_DIR = Path(__file__).resolve().parent / "models"


class PPOPolicy(Policy):
    """A stable-baselines3 PPO model trained on ``HMMBeliefWrapper`` observations from the
    environment's reward alone (:class:`DistilledPolicy`: one that imitated a planner).

    ``deterministic``: act with the most probable action (True) or sample from the policy
    (False; torch's generator is seeded from the episode's seed at ``reset``, so a seeded episode
    is the same every time); ``None`` (default): as the model's metadata says (``deterministic``,
    true when absent).

    ``break_cycles``: with the most probable action, sample the action instead whenever the belief
    is one the episode held before (a deterministic function of the belief would repeat what it
    did then, and could do so forever: turning on the spot between two poses, say); seeded as
    sampled actions are.  ``None`` (default): as the model's metadata says (``break_cycles``, false
    when absent).  Beliefs that never come back exactly (noisy sensors, mostly) leave it the most
    probable action at every step.

    ``path`` defaults to the shipped model for ``env_id`` (``agents/gym_gridloc_agents/models/<env_id>-ppo.zip``).  The
    observation is built as the wrapper the model was trained behind built it: its options
    (``flatten``, ``full_state``, ``map``) come from the metadata beside the model (or
    ``wrapper=``; default ``flatten=True``).  Model zip files are pickles: load only files from a
    trusted source.
    """

    name = "ppo"
    algo = "ppo"
    #: How the default (shipped) model was made: :func:`gym_gridloc_agents.loading.model_method`.
    method = "ppo"

    @classmethod
    def build(cls, model: GridModel, context, deterministic: bool | None = None, break_cycles: bool | None = None) -> "PPOPolicy":
        """As the policy table builds it: the model file ``context.path`` (default: the shipped
        one for the environment's id and keywords), the seed, ``deterministic`` and
        ``break_cycles`` (None: as the model's metadata says)."""
        return cls(model, env_id=context.env_id, env_kwargs=context.env_kwargs, path=context.path, seed=context.seed,
                   deterministic=deterministic, break_cycles=break_cycles)

    def __init__(
        self,
        model: GridModel,
        *,
        env_id: str | None = None,
        env_kwargs: dict[str, Any] | None = None,
        observation_space: spaces.Space | None = None,
        path: str | Path | None = None,
        sb3_model: Any = None,
        wrapper: dict[str, Any] | None = None,
        seed: int | None = None,
        deterministic: bool | None = None,
        break_cycles: bool | None = None,
    ) -> None:
        super().__init__(model, seed=seed)
        for key, value in (("deterministic", deterministic), ("break_cycles", break_cycles)):
            if value is not None and not isinstance(value, (bool, np.bool_)):
                raise ValueError(f"policy {self.name!r}: {key} must be true, false or None, got {value!r}")
        self.deterministic = True if deterministic is None else bool(deterministic)
        self.break_cycles = bool(break_cycles)
        self._seen: set[bytes] = set()  # the beliefs of this episode (break_cycles)
        if sb3_model is not None:  # a model in memory (e.g. evaluated during training)
            self.path, self.sb3, self.meta = None, sb3_model, {}
            self.trained_wrapper = dict(wrapper or {})
            self.wrapper = _wrapper_options(wrapper)
            self.history = acting_history(self.trained_wrapper, self.model.n_actions, env_id, env_kwargs)
            return
        if path is None:
            if env_id is None:
                raise ValueError(f"policy {self.name!r} needs env_id=... (for the shipped model) or path=...")
            path = default_model_path(env_id, self.method, env_kwargs)
        self.path = renamed_model(Path(path))
        if wrapper is None and self.path.is_file():
            wrapper = read_metadata(self.path).get("wrapper")
        #: the wrapper options of the model's training config, as given (``wrapper`` below: the belief observation's)
        self.trained_wrapper = dict(wrapper or {})
        self.wrapper = _wrapper_options(wrapper)
        expected = self.expected_space(model) if observation_space is None else observation_space
        self.sb3, self.meta = load_model(self.path, algo=self.algo, env_id=env_id, env_kwargs=env_kwargs,
                                         observation_space=expected)
        if deterministic is None:  # how the model was meant to act (its config's ``deterministic``)
            self.deterministic = bool(self.meta.get("deterministic", True))
        if break_cycles is None:
            self.break_cycles = bool(self.meta.get("break_cycles", False))
        #: the steps left and past actions the model sees (:mod:`gym_gridloc_agents.history`), or None
        self.history = acting_history(self.trained_wrapper, self.model.n_actions, env_id, env_kwargs, self.path)

    def reset(self, seed: int | None = None, model: GridModel | None = None) -> None:
        super().reset(seed, model)
        if getattr(self, "history", None) is not None:
            self.history.reset()
        self._seen.clear()
        if not self.deterministic or self.break_cycles:  # sampled actions: torch's generator seeded from the episode's seed
            import torch

            torch.manual_seed(int(self.rng.integers(2**63 - 1)))

    @property
    def builder(self) -> BeliefObservation:
        """The observation the model was trained on (:class:`gym_gridloc.observation.BeliefObservation`)."""
        if getattr(self, "_builder", None) is None:
            self._builder = BeliefObservation(self.model, **self.wrapper)
        return self._builder

    @property
    def observation_options(self) -> dict[str, Any]:
        """The options of that observation: an environment whose ``builder`` has the same ones
        emits it, and :func:`~gym_gridloc_agents.evaluation.rollout.rollout` passes it on (``encoded``)."""
        return self.builder.options

    def expected_space(self, model: GridModel) -> spaces.Space:
        return with_history_space(self.trained_wrapper, model.n_actions, BeliefObservation(model, **self.wrapper).space)

    def encode(self, observation: Any, belief: np.ndarray) -> Any:
        """The observation the model's ``HMMBeliefWrapper`` would give."""
        return self.builder.one(self.model, observation, self._full_belief(belief))

    def act(self, observation: Any, belief: np.ndarray, encoded: Any = None) -> int:
        """The model's action; ``encoded``: the observation it was trained on, when the caller
        holds it (an environment with the same wrapper options), else built here."""
        if encoded is None:
            encoded = self.encode(observation, belief)
        deterministic = self.deterministic and not (self.break_cycles and self._repeated(belief))
        if self.history is None:
            return int(self.sb3.predict(encoded, deterministic=deterministic)[0])
        action = int(self.sb3.predict(self.history.attach(encoded, batched=False), deterministic=deterministic)[0])
        self.history.record(np.array([action]))
        return action

    def _repeated(self, belief: np.ndarray) -> bool:
        """Whether the episode held this belief before (to 12 decimals: the same belief reached
        along two paths may differ in its last bits); remembered from now on."""
        key = np.round(np.asarray(belief, dtype=np.float64), 12).tobytes()
        seen = key in self._seen
        self._seen.add(key)
        return seen


def _wrapper_options(wrapper: dict[str, Any] | None) -> dict[str, Any]:
    w = dict(wrapper or {"flatten": True})
    return {"flatten": bool(w.get("flatten", False)), "full_state": bool(w.get("full_state", False)),
            "map": bool(w.get("map", False)), "lookahead": int(w.get("lookahead", 0))}


def wrapped_observation(model: GridModel, observation: Any, belief: np.ndarray, *, flatten: bool = True,
                        full_state: bool = False, map: bool = False, lookahead: int = 0) -> Any:
    """The observation ``HMMBeliefWrapper(flatten=..., full_state=..., map=..., lookahead=...)``
    gives for a sensor observation and the hidden-state belief ``(L, H, W)``."""
    builder = BeliefObservation(model, flatten=flatten, full_state=full_state, map=map, lookahead=lookahead)
    return builder.one(model, observation, np.asarray(belief, dtype=np.float64))


class RecurrentPolicy(PPOPolicy):
    """An sb3-contrib RecurrentPPO model on the raw observations (no belief), with LSTM memory.

    ``path`` defaults to ``agents/gym_gridloc_agents/models/<env_id>-recurrent.zip``.  The belief argument of
    ``act`` is ignored.
    """

    name = "recurrent"
    algo = "recurrent_ppo"
    method = "recurrent"

    def __init__(self, model: GridModel, **kwargs: Any) -> None:
        super().__init__(model, **kwargs)
        self._state = None  # the LSTM's memory, fresh at each episode's start
        self._start = np.ones((1,), dtype=bool)
        self._previous: int | None = None  # the action taken last (wrapper.previous_action models read it)

    observation_options = None  # the raw readings: nothing to pass on

    @classmethod
    def build(cls, model: GridModel, context, deterministic: bool | None = None) -> "RecurrentPolicy":
        """As the policy table builds it (no ``break_cycles``: its memory, not the belief, decides)."""
        return cls(model, env_id=context.env_id, env_kwargs=context.env_kwargs, path=context.path, seed=context.seed,
                   deterministic=deterministic)

    @property
    def previous_action(self) -> bool:
        """Whether the model reads :class:`gym_gridloc.PreviousActionWrapper`'s observation (its
        config's ``wrapper.previous_action``): the readings with the previous action beside them."""
        return bool(self.trained_wrapper.get("previous_action", False))

    def expected_space(self, model: GridModel) -> spaces.Space:
        if self.previous_action:
            return previous_action_space(model.sensor.observation_space, spaces.Discrete(model.n_actions))
        return model.sensor.observation_space

    def reset(self, seed: int | None = None, model: GridModel | None = None) -> None:
        super().reset(seed, model)
        self._state = None
        self._start = np.ones((1,), dtype=bool)
        self._previous = None

    def act(self, observation: Any, belief: np.ndarray | None = None, encoded: Any = None) -> int:
        if self.previous_action:
            observation = with_previous_action(self.model.sensor.observation_space, self.model.n_actions, observation,
                                               self._previous)
        action, self._state = self.sb3.predict(
            np.asarray(observation), state=self._state, episode_start=self._start, deterministic=self.deterministic
        )
        self._start = np.zeros((1,), dtype=bool)
        self._previous = int(np.asarray(action).reshape(-1)[0])
        return self._previous


class DistilledPolicy(PPOPolicy):
    """A PPO network that imitated a planner (behaviour cloning of its action distribution and
    DAgger rounds, then a short PPO phase): ``configs/distill_*.yml``.  ``path`` defaults to the
    shipped ``agents/gym_gridloc_agents/models/<env_id>-distilled.zip``."""

    name = "distilled"
    method = "distilled"


def renamed_model(path: Path) -> Path:
    """``path``, or the shipped model it was renamed to in 0.2 (``<env_id>[-size<N>].zip``, the
    planner-distilled models, became ``...-distilled.zip``), with a ``FutureWarning``."""
    if path.is_file() or path.parent.resolve() != POLICY_DIR or path.stem.endswith(tuple(f"-{m}" for m in METHODS)):
        return path
    new = path.with_name(f"{path.stem}-distilled{path.suffix}")
    if not new.is_file():
        return path
    import warnings

    warnings.warn(f"{path.name} is now {new.name} (a planner distilled into a network: policy 'distilled'); "
                  "the old name goes in a later release", FutureWarning, stacklevel=3)
    return new


def default_model_path(env_id: str, method: str = "ppo", env_kwargs: dict[str, Any] | None = None) -> Path:
    """The shipped model file for ``env_id``, ``method`` (``ppo``, ``distilled`` or ``recurrent``;
    the algorithm ``recurrent_ppo`` is read as ``recurrent``) and the environment's keyword
    arguments: ``<env_id>-<method>.zip`` when it was trained for them, else the model in
    :data:`POLICY_DIR` whose metadata names them (defaults filled in, so ``DepthMaze-v0`` with no
    keywords finds the model trained with ``size=7``; episode keywords such as ``episode_length``
    may differ)."""
    method = "recurrent" if method == "recurrent_ppo" else method
    env_id = plain_id(env_id)
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    plain = POLICY_DIR / f"{env_id}-{method}.zip"
    want = model_kwargs(env_id, env_kwargs or {})
    candidates = [plain] + [p.with_suffix(".zip") for p in sorted(POLICY_DIR.glob(f"{env_id}*.json")) if p.with_suffix(".zip") != plain]
    for path in candidates:
        meta = read_metadata(path) if path.with_suffix(".json").is_file() else {}
        if meta.get("env_id") == env_id and model_method(meta) == method and model_kwargs(env_id, meta.get("env_kwargs", {})) == want:
            return path
    if not env_kwargs:
        return plain  # (missing: the caller's load says how to make it)
    raise FileNotFoundError(f"no shipped {method} model for {env_id} with {dict(env_kwargs)} in {POLICY_DIR}; "
                            f"train one (gridloc train CONFIG) and pass --{method}-model PATH")


#: The learned policies' classes by name (each loads a model file; the name, a line of the policy
#: table, says how the model was made).
LEARNED_POLICIES = {cls.name: cls for cls in (PPOPolicy, DistilledPolicy, RecurrentPolicy)}
