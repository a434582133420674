"""One episode of a policy: the loop that training evaluation, the warm start, the benchmark and
the tools (figures, filter comparisons) all run.

The environment is usually an :class:`gym_gridloc.HMMBeliefWrapper` (what
:func:`gym_gridloc_agents.envs.make_env` builds); the policy sees the sensor observation and the
exact hidden-state belief, ``policy.act(observation, belief)``, and builds whatever input it needs
from them.  A learned policy whose ``observation_options`` are the wrapper's (``env.builder``) is
handed the wrapper's observation as well (``encoded=``): the observation it was trained on, built
once.  On an environment without a belief filter the policy gets
``belief=None`` (only policies that ignore the belief, such as ``random``, can run there).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class Episode:
    """What one episode did.

    ``steps`` counts actions; ``correct[k]`` says whether the most probable position (pose, where
    the referee tests poses) was the truth after ``k`` steps (``k = 0``: at reset),
    ``localised_at[k]`` whether the referee declared it localised then, ``collapsed[k]`` both.  With
    ``keep=True``, ``observations[k]`` (the sensor's) and ``beliefs[k]`` are what the policy saw before
    ``actions[k]`` (``observations`` ends with the last one), ``encoded[k]`` the environment's
    observation then (the wrapper's, belief included), ``infos[k]`` came with
    ``observations[k]`` and ``states[k]`` is the true hidden state then; with ``frames=True``,
    ``frames[k]`` is ``env.render()`` then.
    """

    seed: int
    steps: int = 0
    terminated: bool = False
    truncated: bool = False
    success: bool = False
    correct: list[bool] = field(default_factory=list)
    collapsed: list[bool] = field(default_factory=list)
    localised_at: list[bool] = field(default_factory=list)
    rewards: list[float] = field(default_factory=list)
    actions: list[int] = field(default_factory=list)
    observations: list[Any] = field(default_factory=list)
    encoded: list[Any] = field(default_factory=list)
    beliefs: list[np.ndarray] = field(default_factory=list)
    infos: list[dict[str, Any]] = field(default_factory=list)
    states: list[tuple[int, int, int]] = field(default_factory=list)
    frames: list[np.ndarray] = field(default_factory=list)
    final_info: dict[str, Any] = field(default_factory=dict)
    model: Any = None  # the episode's model (its map, when maps change at reset)

    @property
    def localised(self) -> bool:
        return self.terminated


def _right(info: dict[str, Any]) -> bool:
    """The estimate is the truth (the pose too, where the referee tests poses)."""
    return bool(info["error"] == 0 and ("estimate_heading" not in info or info["estimate_heading"] == info["heading"]))


def rollout(env, policy, seed: int, *, keep: bool = False, frames: bool = False, max_steps: int | None = None,
            until_truncated: bool = False, policy_seed: Any = None, reset_options: dict[str, Any] | None = None) -> Episode:
    """Run ``policy`` for one episode of ``env`` from ``env.reset(seed=seed)`` (the policy is
    reset with ``policy_seed``, by default the same seed, and the episode's model).  Ends when the
    environment terminates (unless ``until_truncated``) or truncates, or after ``max_steps``
    actions."""
    obs, info = env.reset(seed=int(seed), options=reset_options)
    unwrapped = env.unwrapped
    policy.reset(seed=int(seed) if policy_seed is None else policy_seed, model=getattr(unwrapped, "model", None))
    filt = getattr(env, "filter", None)
    builder = getattr(env, "builder", None)
    wanted = getattr(policy, "observation_options", None)
    served = wanted is not None and builder is not None and builder.options == wanted
    flat = builder is not None and builder.flatten
    ep = Episode(seed=int(seed), model=getattr(unwrapped, "model", None))

    def record(obs, info) -> None:
        ep.correct.append(_right(info))
        ep.localised_at.append(bool(info["localised"]))
        ep.collapsed.append(bool(info["localised"]) and _right(info))
        if keep:
            ep.observations.append(sensor_observation(obs))
            ep.encoded.append(obs)
            ep.infos.append(dict(info))
            ep.states.append(unwrapped.state)
        if frames:
            ep.frames.append(env.render())

    def sensor_observation(obs):
        if isinstance(obs, dict):
            return obs["observation"]
        return unwrapped.model.sensor.to_observation(unwrapped.last_reading) if flat else obs

    record(obs, info)
    while True:
        reading = sensor_observation(obs)
        belief = None if filt is None else filt.full_belief
        action = int(policy.act(reading, belief, encoded=obs) if served else policy.act(reading, belief))
        if keep:
            ep.beliefs.append(belief)
            ep.actions.append(action)
        obs, reward, terminated, truncated, info = env.step(action)
        ep.steps += 1
        ep.rewards.append(float(reward))
        ep.terminated = ep.terminated or bool(terminated)
        record(obs, info)
        if (terminated and not until_truncated) or truncated or (max_steps is not None and ep.steps >= max_steps):
            ep.truncated = bool(truncated)
            ep.success = bool(terminated and info["success"])
            ep.final_info = dict(info)
            return ep
