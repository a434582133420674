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
    """Run the expert on a flattened belief environment; returns observations, actions, returns."""
    from tqdm.auto import tqdm

    from agents.policies import make_policy
    from agents.train import make_env_fn

    pre = cfg["pretrain"]
    gamma = float(cfg["hyperparams"].get("gamma", 0.99))
    env = make_env_fn(cfg)()
    expert = make_policy(pre["expert"], env.unwrapped.model)
    obs_list, act_list, ret_list, lengths = [], [], [], []
    for i in tqdm(range(pre["episodes"]), desc=f"expert {pre['expert']} episodes", disable=not progress, leave=False):
        seed = PRETRAIN_SEED_BASE + i
        obs, _ = env.reset(seed=seed)
        expert.reset(seed=seed)
        ep_obs, ep_act, rewards = [], [], []
        truncated_last = False
        while True:
            a = expert.act(None, env.filter.full_belief)
            ep_obs.append(obs)
            ep_act.append(a)
            obs, r, term, trunc, _ = env.step(a)
            rewards.append(float(r))
            if term or trunc:
                truncated_last = bool(trunc and not term)
                break
        g = 0.0
        if truncated_last:  # the episode would go on: a rough bootstrap, as if it had as many steps left
            g = -(1 - gamma ** len(rewards)) / (1 - gamma) if gamma < 1 else -float(len(rewards))
        rets = []
        for r in reversed(rewards):
            g = r + gamma * g
            rets.append(g)
        obs_list.extend(ep_obs)
        act_list.extend(ep_act)
        ret_list.extend(reversed(rets))
        lengths.append(len(rewards))
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
