"""Behaviour-cloning warm start of a PPO policy from an entropy-greedy expert.

The expert (``greedy`` or ``greedy2``) plays ``episodes`` episodes on seeds ``1_000_000 + i``
(disjoint from the benchmark's seeds ``0..N-1``).  The actor is fitted to the expert's actions
(cross-entropy) and the critic to the discounted returns the expert obtained (reward -1 per step),
so that PPO starts from the expert's behaviour with a matching value function; PPO then improves
on it with the environment's own reward.  Only the PPO policy's weights are changed.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

PRETRAIN_SEED_BASE = 1_000_000


def collect_expert(cfg: dict[str, Any], progress: bool = True) -> dict[str, np.ndarray]:
    """Run the expert on the config's environment; returns the flat observations PPO sees, the
    expert's actions and the discounted returns."""
    from tqdm.auto import tqdm

    from gym_gridloc_agents.envs import make_env
    from gym_gridloc_agents.policies import flat_observation, make_policy
    from gym_gridloc_agents.rollout import rollout

    pre = cfg["pretrain"]
    gamma = float(cfg["hyperparams"].get("gamma", 0.99))
    env = make_env(cfg["env_id"], cfg["env_kwargs"])
    expert = make_policy(pre["expert"], env.unwrapped.model)
    obs_list, act_list, ret_list, lengths = [], [], [], []
    for i in tqdm(range(pre["episodes"]), desc=f"expert {pre['expert']} episodes", disable=not progress, leave=False):
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
        obs_list.extend(flat_observation(model, o, b) for o, b in zip(ep.observations, ep.beliefs))  # before each action
        act_list.extend(ep.actions)
        ret_list.extend(reversed(rets))
        lengths.append(ep.steps)
    env.close()
    return {
        "obs": np.asarray(obs_list, dtype=np.float32),
        "actions": np.asarray(act_list, dtype=np.int64),
        "returns": np.asarray(ret_list, dtype=np.float32),
        "lengths": np.asarray(lengths),
    }


def behaviour_cloning(model, cfg: dict[str, Any], progress: bool = True) -> dict[str, Any]:
    """Fit ``model.policy`` (an sb3 ActorCriticPolicy) to the expert; returns a summary."""
    import torch
    from tqdm.auto import tqdm

    pre = cfg["pretrain"]
    start = time.perf_counter()
    data = collect_expert(cfg, progress=progress)
    policy = model.policy
    device = policy.device
    obs = torch.as_tensor(data["obs"], device=device)
    actions = torch.as_tensor(data["actions"], device=device)
    returns = torch.as_tensor(data["returns"], device=device)
    optimiser = torch.optim.Adam(policy.parameters(), lr=pre["learning_rate"])
    gen = torch.Generator().manual_seed(int(cfg["seed"]))
    n = len(actions)
    policy.set_training_mode(True)
    for _ in tqdm(range(pre["epochs"]), desc="behaviour cloning epochs", disable=not progress, leave=False):
        order = torch.randperm(n, generator=gen)
        for k in range(0, n, pre["batch_size"]):
            idx = order[k : k + pre["batch_size"]]
            values, log_prob, _ = policy.evaluate_actions(obs[idx], actions[idx])
            loss = -log_prob.mean() + 0.5 * torch.nn.functional.mse_loss(values.flatten(), returns[idx])
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
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
    }
