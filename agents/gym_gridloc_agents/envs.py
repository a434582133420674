"""Environment factories for training, evaluation and the benchmark, and the stable-baselines3
adapter of the native vector environment (:class:`SB3VecEnv`)."""

from __future__ import annotations

import functools
import inspect
from typing import Any, Callable

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import load_env_creator
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

import gym_gridloc
from gym_gridloc.core.validation import unknown_names, whole_numbers
from gym_gridloc.envs.base import GridLocEnv
from gym_gridloc.vector import GridLocVectorEnv
from gym_gridloc_agents.history import HISTORY_KEYS, History, HistoryWrapper, episode_limit, history_options


def check_environment(env_id: str, env_kwargs: dict[str, Any], *, what: str, error: type[Exception]) -> gym.Space:
    """Build ``gym.make(env_id, **env_kwargs)`` once: a gym_gridloc environment, or ``error``
    naming ``what`` and the reason (an unknown keyword, a bad value, another package's env).
    Returns its (raw) observation space."""
    if not isinstance(env_id, str) or env_id not in gym.registry:
        raise error(f"{what}: {env_id!r} is not a registered environment (gym_gridloc's: {', '.join(gym_gridloc.ENV_IDS)})")
    known = _keywords(env_id)
    unknown = sorted(set(env_kwargs) - known) if known else []
    if unknown:
        raise error(f"{what}: {env_id} has no keyword {unknown_names(unknown, sorted(known))} (its keywords: {', '.join(sorted(known))})")
    try:
        env = gym.make(env_id, **env_kwargs)
    except (TypeError, ValueError, gym.error.Error) as exc:
        raise error(f"{what}: {env_id} does not build with {env_kwargs}: {exc}") from None
    ok, space = isinstance(env.unwrapped, GridLocEnv), env.observation_space
    length, limit = getattr(env.unwrapped, "episode_length", None), env.spec.max_episode_steps if env.spec else None
    env.close()
    if not ok:
        raise error(f"{what}: {env_id} is not a gym_gridloc environment (allowed: {', '.join(gym_gridloc.ENV_IDS)})")
    if length and limit and length > limit:  # the time limit would cut the protocol's episodes short
        raise error(f"{what}: episode_length {length} exceeds {env_id}'s max_episode_steps {limit}: the episodes "
                    f"would be truncated at step {limit}; give episode_length <= {limit}")
    return space


def default_kwargs(env_id: str) -> dict[str, Any]:
    """The keyword arguments a gym_gridloc environment is built with when none are given: its
    class's defaults, then its registration's (empty for another package's environment)."""
    params = _parameters(env_id)
    if params is None:
        return {}
    # (a class's DEFAULTS: what a None default stands for, e.g. DepthMaze's size 7)
    stands = getattr(load_env_creator(gym.registry[env_id].entry_point), "DEFAULTS", {})
    out = {p.name: stands.get(p.name, p.default) for p in params if p.default is not p.empty and p.name != "render_mode"}
    return {**out, **dict(gym.registry[env_id].kwargs or {})}


def _keywords(env_id: str) -> set[str]:
    """The keyword arguments a gym_gridloc environment's class takes (empty: not one of ours, or
    it takes ``**kwargs``)."""
    params = _parameters(env_id)
    if params is None or any(p.kind is p.VAR_KEYWORD for p in params):
        return set()
    return {p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)} - {"self"}


def _parameters(env_id: str) -> list | None:
    """The parameters of a gym_gridloc environment's class (``None`` for another package's environment)."""
    entry = gym.registry[env_id].entry_point
    if not isinstance(entry, str) or not entry.startswith("gym_gridloc."):
        return None
    return list(inspect.signature(load_env_creator(entry)).parameters.values())


def make_env(env_id: str, env_kwargs: dict[str, Any] | None = None, wrapper: dict[str, Any] | None = None) -> gym.Env:
    """``gym.make(env_id, **env_kwargs)``, behind ``HMMBeliefWrapper(**wrapper)`` unless
    ``wrapper["belief"]`` is false (raw readings; behind :class:`gym_gridloc.PreviousActionWrapper`
    with ``wrapper["previous_action"]``), and behind :class:`~gym_gridloc_agents.history.HistoryWrapper`
    with ``wrapper["past_actions"]``, ``wrapper["steps_left"]`` or ``wrapper["time_step"]``.  ``wrapper=None``: the Dict
    belief observation every policy of the benchmark reads."""
    env = gym.make(env_id, **dict(env_kwargs or {}))
    opts = {"belief": True} if wrapper is None else dict(wrapper)
    history = history_options(opts)
    for key in HISTORY_KEYS:
        opts.pop(key, None)
    previous = opts.pop("previous_action", False)
    if opts.pop("belief", True) is False:
        env = gym_gridloc.PreviousActionWrapper(env) if previous else env
    else:
        env = gym_gridloc.HMMBeliefWrapper(env, **opts)
    return HistoryWrapper(env, **history.wrapper) if history.any else env


def served_env(env: gym.Env, policy: Any) -> gym.Env:
    """``env`` (a :func:`make_env` environment), behind the belief wrapper whose observation
    ``policy`` was trained on when it has one (``policy.observation_options``) and ``env``
    gives another: the rollout then hands the policy the wrapper's observation, built once."""
    options = getattr(policy, "observation_options", None)
    builder = getattr(env, "builder", None)
    if options is None or builder is None or builder.options == options or not isinstance(env, gym_gridloc.HMMBeliefWrapper):
        return env
    return gym_gridloc.HMMBeliefWrapper(env.env, **options, belief=env.belief, on_impossible=env.on_impossible)


def env_thunk(cfg: dict[str, Any]) -> Callable[[], gym.Env]:
    """A picklable thunk building one (wrapped) training environment from a validated config."""
    return functools.partial(make_env, cfg["env_id"], dict(cfg["env_kwargs"]), dict(cfg["wrapper"]))


def make_training_env(cfg: dict[str, Any]):
    """The SB3 ``VecEnv`` a config trains on: ``cfg["vec_env"]`` ``"dummy"`` (SB3's DummyVecEnv
    of wrapped environments, seeded ``seed + i``) or ``"native"`` (gym_gridloc's vector env
    through :class:`SB3VecEnv`)."""
    if cfg.get("vec_env", "dummy") == "native":
        wrapper = dict(cfg["wrapper"])
        history = history_options(wrapper)
        for key in HISTORY_KEYS:
            wrapper.pop(key, None)
        venv = SB3VecEnv.make(cfg["env_id"], cfg["n_envs"], belief="exact" if wrapper.pop("belief", True) else None,
                              history=history.wrapper, **wrapper, **cfg["env_kwargs"])
        venv.seed(cfg["seed"])
        return venv
    return make_vec_env(env_thunk(cfg), n_envs=cfg["n_envs"], seed=cfg["seed"])


class SB3VecEnv(VecEnv):
    """stable-baselines3 ``VecEnv`` over a :class:`gym_gridloc.vector.GridLocVectorEnv` (SB3
    takes its own VecEnv API, not Gymnasium's ``VectorEnv``).

    SB3 resets a finished environment in the same step: the returned observation is the new
    episode's first, ``infos[i]["terminal_observation"]`` the last one of the finished episode
    and ``infos[i]["TimeLimit.truncated"]`` says a time limit (not localisation) ended it.  The
    vector env is switched to ``AutoresetMode.SAME_STEP`` for this.

    >>> import gymnasium as gym, gym_gridloc
    >>> from gym_gridloc_agents.envs import SB3VecEnv
    >>> venv = SB3VecEnv(gym.make_vec("WindyMaze-v0", num_envs=8, vectorization_mode="vector_entry_point"))
    >>> venv.num_envs
    8

    ``SB3VecEnv.make(env_id, num_envs, **kwargs)`` builds the native env and the adapter.
    ``history={"past_actions": K, "steps_left": H}`` (or ``"time_step": H``) appends each episode's
    :class:`~gym_gridloc_agents.history.History` to its observations (as :class:`HistoryWrapper` does).
    """

    def __init__(self, venv, *, history: dict[str, int] | None = None) -> None:
        env = getattr(venv, "unwrapped", venv)
        if not isinstance(env, GridLocVectorEnv):
            raise TypeError(f"SB3VecEnv needs a gym_gridloc native vector env (GridLocVectorEnv), got {type(venv).__name__}")
        env.set_autoreset_mode(AutoresetMode.SAME_STEP)
        self.venv = env
        opts = history_options(history)
        self.history = (History(int(env.single_action_space.n), options=opts, n=env.num_envs,
                                limit=episode_limit(env) if opts.needs_limit else None) if opts.any else None)
        space = env.single_observation_space if self.history is None else self.history.space(env.single_observation_space)
        super().__init__(env.num_envs, space, env.single_action_space)
        self._actions: np.ndarray | None = None

    @classmethod
    def make(cls, env_id: str, num_envs: int, *, history: dict[str, int] | None = None, **kwargs: Any) -> "SB3VecEnv":
        return cls(gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs), history=history)

    def reset(self):
        obs, _ = self.venv.reset(seed=next((s for s in self._seeds if s is not None), None))
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [{} for _ in range(self.num_envs)]
        if self.history is not None:
            self.history.reset()
            obs = self.history.attach(obs)
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        acts = np.asarray(actions).reshape(self.num_envs)
        if not whole_numbers(acts):
            raise ValueError(f"actions must be integers (one per environment), got {actions!r}")
        self._actions = acts.astype(np.int64)

    def step_wait(self):
        obs, rewards, terminated, truncated, info = self.venv.step(self._actions)
        dones = terminated | truncated
        final = None
        if self.history is not None:
            self.history.record(self._actions)
            final = self.history.features()  # the finished episodes' last features
            self.history.reset(dones)
            obs = self.history.attach(obs)
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for i in np.flatnonzero(dones):
            last = info["final_obs"][i] if final is None else self.history.attach(info["final_obs"][i], final[i : i + 1], batched=False)
            infos[i] = {**info["final_info"][i], "terminal_observation": last,
                        "TimeLimit.truncated": bool(truncated[i] and not terminated[i])}
        return obs, rewards.astype(np.float32), dones, infos

    def close(self) -> None:
        self.venv.close()

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return [None if attr_name == "render_mode" else getattr(self.venv.template, attr_name)
                for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        raise AttributeError(f"the native vector env's {self.num_envs} environments share one template; cannot set {attr_name!r} per environment")

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        raise AttributeError(f"the native vector env has no per-environment objects to call {method_name!r} on")

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]
