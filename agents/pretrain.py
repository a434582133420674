"""Behaviour-cloning warm start of a PPO policy from an expert policy.

The expert (``greedy``, ``greedy2`` or a planner) plays ``episodes`` episodes on seeds
``1_000_000 + i`` (disjoint from the benchmark's seeds ``0..N-1``).  The actor is fitted to the
expert's actions (cross-entropy) and the critic to the discounted returns the expert obtained
(reward -1 per step), so that PPO starts from the expert's behaviour with a matching value
function; PPO then improves on it with the environment's own reward.  Only the PPO policy's
weights are changed.

Nothing is lost to Ctrl-C: the expert's episodes are kept in a cache file (``expert.npz`` in the
checkpoint directory, saved as they come when interrupted) and the cloning epochs already done
are counted; :class:`WarmStartInterrupted` says how far it got, and a resumed training continues
from there.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

PRETRAIN_SEED_BASE = 1_000_000


class WarmStartInterrupted(Exception):
    """Ctrl-C during the warm start: ``episodes`` expert episodes are cached, ``epochs`` cloning
    epochs are done."""

    def __init__(self, episodes: int, epochs: int) -> None:
        super().__init__(f"warm start interrupted after {episodes} expert episodes and {epochs} cloning epochs")
        self.episodes, self.epochs = episodes, epochs


def _cache_key(cfg: dict[str, Any]) -> str:
    pre = cfg["pretrain"]
    return json.dumps({"env_id": cfg["env_id"], "env_kwargs": cfg["env_kwargs"], "expert": pre["expert"],
                       "gamma": float(cfg["hyperparams"].get("gamma", 0.99))}, sort_keys=True, default=str)


def _load_cache(cache: Path | None, key: str) -> list[dict[str, np.ndarray]]:
    if cache is None or not cache.is_file():
        return []
    try:
        with np.load(cache, allow_pickle=False) as data:
            if str(data["key"]) != key:
                return []
            bounds = data["bounds"]
            return [{k: data[k][a:b] for k in ("obs", "actions", "returns")} | {"length": int(n)}
                    for a, b, n in zip(bounds[:-1], bounds[1:], data["lengths"])]
    except (OSError, KeyError, ValueError):
        return []  # an unreadable cache is collected again


def _save_cache(cache: Path, key: str, episodes: list[dict[str, np.ndarray]]) -> None:
    from gym_gridloc_agents.files import atomic_path

    sizes = [len(e["actions"]) for e in episodes]
    arrays = {k: np.concatenate([e[k] for e in episodes]) if episodes else np.zeros(0) for k in ("obs", "actions", "returns")}
    with atomic_path(cache) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, key=np.array(key), bounds=np.concatenate([[0], np.cumsum(sizes)]),
                 lengths=np.array([e["length"] for e in episodes]), **arrays)


def collect_expert(cfg: dict[str, Any], progress: bool = True, cache: Path | None = None) -> dict[str, np.ndarray]:
    """The expert's episodes on the config's environment: the flat observations PPO sees, the
    expert's actions and the discounted returns (continued from ``cache`` if it holds some)."""
    from tqdm.auto import tqdm

    from gym_gridloc_agents.envs import make_env
    from gym_gridloc_agents.policies import make_policy, wrapped_observation
    from gym_gridloc_agents.rollout import rollout

    pre = cfg["pretrain"]
    gamma = float(cfg["hyperparams"].get("gamma", 0.99))
    key = _cache_key(cfg)
    episodes = _load_cache(cache, key)[: pre["episodes"]]
    env = make_env(cfg["env_id"], cfg["env_kwargs"])
    expert = make_policy(pre["expert"], env.unwrapped.model, pose=env.unwrapped.referee_pose)
    try:
        for i in tqdm(range(len(episodes), pre["episodes"]), desc=f"expert {pre['expert']} episodes",
                      disable=not progress, leave=False, initial=len(episodes), total=pre["episodes"]):
            ep = rollout(env, expert, PRETRAIN_SEED_BASE + i, keep=True)
            model = env.unwrapped.model
            g = 0.0
            if ep.truncated and not ep.terminated:  # the episode would go on: a rough bootstrap, as if it had as many steps left
                n = len(ep.rewards)
                g = -(1 - gamma ** n) / (1 - gamma) if gamma < 1 else -float(n)
            rets = []
            for r in reversed(ep.rewards):
                g = r + gamma * g
                rets.append(g)
            episodes.append({
                "obs": np.asarray([wrapped_observation(model, o, b) for o, b in zip(ep.observations, ep.beliefs)], dtype=np.float32),
                "actions": np.asarray(ep.actions, dtype=np.int64),
                "returns": np.asarray(rets[::-1], dtype=np.float32),
                "length": ep.steps,
            })
    except KeyboardInterrupt:
        if cache is not None:
            _save_cache(cache, key, episodes)
        raise WarmStartInterrupted(len(episodes), 0) from None
    finally:
        env.close()
    if cache is not None:
        _save_cache(cache, key, episodes)
    return {
        "obs": np.concatenate([e["obs"] for e in episodes]),
        "actions": np.concatenate([e["actions"] for e in episodes]),
        "returns": np.concatenate([e["returns"] for e in episodes]),
        "lengths": np.asarray([e["length"] for e in episodes]),
    }


def behaviour_cloning(model, cfg: dict[str, Any], progress: bool = True, *, cache: Path | None = None,
                      start_epoch: int = 0) -> dict[str, Any]:
    """Fit ``model.policy`` (an sb3 ActorCriticPolicy) to the expert, from epoch ``start_epoch``
    (a resumed warm start); returns a summary.  Ctrl-C raises :class:`WarmStartInterrupted`."""
    import torch
    from tqdm.auto import tqdm

    pre = cfg["pretrain"]
    start = time.perf_counter()
    data = collect_expert(cfg, progress=progress, cache=cache)
    policy = model.policy
    device = policy.device
    obs = torch.as_tensor(data["obs"], device=device)
    actions = torch.as_tensor(data["actions"], device=device)
    returns = torch.as_tensor(data["returns"], device=device)
    optimiser = torch.optim.Adam(policy.parameters(), lr=pre["learning_rate"])
    gen = torch.Generator().manual_seed(int(cfg["seed"]))
    n = len(actions)
    for _ in range(start_epoch):  # the shuffles of the epochs already done
        torch.randperm(n, generator=gen)
    policy.set_training_mode(True)
    epoch = start_epoch
    try:
        for epoch in tqdm(range(start_epoch, pre["epochs"]), desc="behaviour cloning epochs", disable=not progress,
                          leave=False, initial=start_epoch, total=pre["epochs"]):
            order = torch.randperm(n, generator=gen)
            for k in range(0, n, pre["batch_size"]):
                idx = order[k : k + pre["batch_size"]]
                values, log_prob, _ = policy.evaluate_actions(obs[idx], actions[idx])
                loss = -log_prob.mean() + 0.5 * torch.nn.functional.mse_loss(values.flatten(), returns[idx])
                optimiser.zero_grad()
                loss.backward()
                optimiser.step()
            epoch += 1
    except KeyboardInterrupt:
        raise WarmStartInterrupted(int(pre["episodes"]), epoch) from None
    finally:
        policy.set_training_mode(False)
    with torch.no_grad():
        dist = policy.get_distribution(obs)
        agree = float((dist.distribution.probs.argmax(dim=1) == actions).float().mean())
    return {
        "expert": pre["expert"],
        "episodes": int(pre["episodes"]),
        "samples": int(n),
        "expert_mean_steps": float(data["lengths"].mean()),
        "argmax_agreement": round(agree, 4),
        "seconds": round(time.perf_counter() - start, 2),
        "resumed_at_epoch": start_epoch or None,
    }
