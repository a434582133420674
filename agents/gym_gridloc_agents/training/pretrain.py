"""Warm start of a PPO policy from an expert: behaviour cloning, then DAgger rounds.

The expert (``greedy``, ``greedy2``, a planner, ...) plays ``episodes`` episodes on seeds
``1_000_000 + i`` (disjoint from the benchmark's seeds ``0..N-1`` and the held-out maps).  The
actor is fitted to the expert's actions (cross-entropy) and the critic to the discounted returns
obtained (the environment's own reward), so that PPO starts from the expert's behaviour with a
matching value function.  With ``dagger_rounds`` (DAgger, Ross et al. 2011), each round then lets
the student play ``dagger_episodes`` episodes (seeds ``1_500_000 + ...``), asks the expert what
it would have done in every belief the student reached, adds those labels (and the student's
returns) to the data and fits again: the student learns to recover from its own mistakes.  PPO
then trains on the environment's reward.  Only the PPO policy's weights are changed.

With ``temperature > 0`` (planner experts) the actor imitates ``softmax(-(Q - min Q) / temperature)``
of the planner's action values ``Q`` (cached with the episodes), not only its tied best actions;
``learning_rate_final`` lowers each fit's learning rate along a cosine.

Nothing is lost to Ctrl-C: the expert's episodes (and each DAgger round's labels) are kept in
cache files in the checkpoint directory, and the epochs and rounds already done are counted;
:class:`WarmStartInterrupted` says how far it got, and a resumed training continues from there.
The expert's episodes do not depend on the training seed: trainings whose checkpoint directories
are siblings (the seeds of a sweep) share them.
"""

from __future__ import annotations

import itertools
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from gym_gridloc_agents.envs import make_env
from gym_gridloc_agents.files import atomic_path
from gym_gridloc_agents.policies import POLICIES, PPOPolicy, make_policy

PRETRAIN_SEED_BASE = 1_000_000
DAGGER_SEED_BASE = 1_500_000


def with_episodes(cfg: dict[str, Any], episodes: int) -> dict[str, Any]:
    """A copy of ``cfg`` whose warm start plays ``episodes`` expert episodes, and each DAgger round
    ``dagger_episodes`` scaled by the same factor (at least 1): ``gridloc train --pretrain-episodes``,
    e.g. a quick run of a distilled config.  The expert's episodes are cached as usual: a later run
    with more of them continues from these."""
    import copy

    if not cfg.get("pretrain"):
        raise ValueError("--pretrain-episodes: this config has no warm start (no pretrain section)")
    out = copy.deepcopy(cfg)
    pre = out["pretrain"]
    factor = episodes / pre["episodes"]
    pre["episodes"] = int(episodes)
    pre["dagger_episodes"] = max(1, round(pre["dagger_episodes"] * factor))
    return out


class _FitInterrupted(Exception):
    def __init__(self, done: int) -> None:
        super().__init__(f"interrupted after {done} epochs")
        self.done = done


class WarmStartInterrupted(Exception):
    """Ctrl-C during the warm start, with how far it got."""

    def __init__(self, episodes: int, epochs: int, rounds: int = 0) -> None:
        super().__init__(f"warm start interrupted after {episodes} expert episodes, {epochs} cloning epochs "
                         f"and {rounds} DAgger rounds")
        self.episodes, self.epochs, self.rounds = episodes, epochs, rounds


# -- samples ---------------------------------------------------------------------------------------
def _discounted(rewards: list[float], gamma: float, truncated: bool) -> np.ndarray:
    g = 0.0
    if truncated:  # the episode would go on: a rough bootstrap, as if it had as many steps left
        n = len(rewards)
        g = -(1 - gamma ** n) / (1 - gamma) if gamma < 1 else -float(n)
    out = list(itertools.accumulate(reversed(rewards), lambda g, r: r + gamma * g, initial=g))[1:]
    return np.asarray(out[::-1], dtype=np.float32)


def _stack(observations: list[Any]) -> Any:
    """A list of observations as one array, or a dict of arrays for Dict observations."""
    if observations and isinstance(observations[0], dict):
        return {k: np.stack([o[k] for o in observations]) for k in observations[0]}
    return np.asarray(observations, dtype=np.float32)


def _concat(parts: list[Any]) -> Any:
    if parts and isinstance(parts[0], dict):
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return np.concatenate(parts)


def _episode_samples(ep, targets: list[np.ndarray], cfg: dict[str, Any],
                     values: list[np.ndarray] | None = None) -> dict[str, Any]:
    """One episode's samples: the observations PPO sees (the config's wrapper), the expert's action
    distributions to imitate (one-hot, or even over a planner's tied best actions), the returns
    (the config's gamma), and the planner's action values where they are asked for."""
    obs = ep.encoded[: len(ep.beliefs)]  # the wrapper's observations: the config's (:func:`_env`)
    gamma = float(cfg["hyperparams"].get("gamma", 0.99))
    return {"obs": _stack(obs), "targets": np.asarray(targets, dtype=np.float32),
            "returns": _discounted(ep.rewards, gamma, ep.truncated and not ep.terminated), "length": ep.steps,
            **({"values": np.asarray(values, dtype=np.float32)} if values is not None else {})}


def _label(expert, observation, belief, values: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """The expert's action distribution here and, with ``values``, a planner's action values."""
    if not values:
        return expert.probabilities(observation, belief), None
    return expert.probabilities_and_values(observation, belief)


class _Recorded:
    """An expert that plays and records its action distribution at every step."""

    def __init__(self, expert, values: bool = False) -> None:
        self.expert, self.values, self.targets, self.q = expert, values, [], []

    def reset(self, seed=None, model=None) -> None:
        self.expert.reset(seed=seed, model=model)
        self.targets, self.q = [], []

    def act(self, observation, belief) -> int:
        p, q = _label(self.expert, observation, belief, self.values)
        self.targets.append(p)
        self.q.append(q)
        return self.expert.choose(p)


# -- caches ----------------------------------------------------------------------------------------
def _cache_key(cfg: dict[str, Any], what: str) -> str:
    pre = cfg["pretrain"]
    # "labels": the targets are the expert's action distributions (a cache of one-hot indices from
    # an older version is collected again); "values": the planner's action values are kept too
    return json.dumps({"what": what, "labels": "distribution", "env_id": cfg["env_id"], "env_kwargs": cfg["env_kwargs"], "wrapper": cfg["wrapper"],
                       "expert": pre["expert"], "expert_kwargs": pre.get("expert_kwargs", {}),
                       "gamma": float(cfg["hyperparams"].get("gamma", 0.99)), **({"values": True} if _wants_values(cfg) else {})},
                      sort_keys=True, default=str)


def _wants_values(cfg: dict[str, Any]) -> bool:
    return float(cfg["pretrain"].get("temperature", 0.0)) > 0.0


def _load_cache(cache: Path | None, key: str) -> list[dict[str, Any]]:
    if cache is None or not cache.is_file():
        return []
    try:
        with np.load(cache, allow_pickle=False) as data:
            if str(data["key"]) != key:
                return []
            # Each array is read once (``data[name]`` decompresses the whole array again at every access);
            # episodes are copies of their rows, so no episode keeps a whole array alive.
            arrays = {k: data[k] for k in data.files if k != "key"}
        bounds, lengths = arrays["bounds"], arrays["lengths"]
        obs_keys = [k for k in arrays if k.startswith("obs.")]
        return [{"obs": {k[4:]: arrays[k][a:b].copy() for k in obs_keys} if obs_keys else arrays["obs"][a:b].copy(),
                 "length": int(n),
                 **{k: arrays[k][a:b].copy() for k in ("targets", "returns", "values") if k in arrays}}
                for a, b, n in zip(bounds[:-1], bounds[1:], lengths)]
    except (OSError, KeyError, ValueError):
        return []  # an unreadable cache is collected again


def _sibling_caches(cache: Path, key: str) -> list[tuple[int, Path]]:
    """Expert caches of other trainings beside this one (``<checkpoints>/*/expert.npz``) made for the
    same data (the same key: environment, wrapper, expert, gamma).  The expert's episodes do not
    depend on the training seed (seeds ``PRETRAIN_SEED_BASE + i``), so the seeds of a sweep, or a
    config trained again under another output, share them instead of playing them again."""
    found = []
    for other in sorted(p for p in cache.parent.parent.glob(f"*/{cache.name}") if p.resolve() != cache.resolve()):
        try:
            with np.load(other, allow_pickle=False) as data:
                if str(data["key"]) == key:
                    found.append((len(data["lengths"]), other))
        except (OSError, KeyError, ValueError):
            continue
    return sorted(found, key=lambda t: -t[0])


def _save_cache(cache: Path | None, key: str, episodes: list[dict[str, Any]]) -> None:
    if cache is None or not episodes:
        return
    data = _merge(episodes)  # obs, targets, returns, lengths (and values)
    obs = data.pop("obs")
    arrays = {f"obs.{k}": v for k, v in obs.items()} if isinstance(obs, dict) else {"obs": obs}
    bounds = np.concatenate([[0], np.cumsum([len(e["targets"]) for e in episodes])])
    with atomic_path(cache) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, key=np.array(key), bounds=bounds, **data, **arrays)


def _env(cfg: dict[str, Any]):
    """The environment behind the config's wrapper: its observations are what PPO trains on (the
    samples keep them as they come; the expert reads the wrapper's exact belief)."""
    return make_env(cfg["env_id"], cfg["env_kwargs"], cfg["wrapper"])


def _expert(cfg: dict[str, Any], env):
    pre = cfg["pretrain"]
    options = dict(pre.get("expert_kwargs", {}))
    if "threshold" in POLICIES[pre["expert"]].options:  # the planners plan for the referee's own test
        options.setdefault("threshold", env.unwrapped.localise_threshold)
    return make_policy(pre["expert"], env.unwrapped.model, env_id=cfg["env_id"], pose=env.unwrapped.referee_pose,
                       env_kwargs=cfg["env_kwargs"], **options)


def collect_expert(cfg: dict[str, Any], progress: bool = True, cache: Path | None = None) -> list[dict[str, Any]]:
    """The expert's episodes as samples (continued from ``cache`` if it holds some)."""
    from gym_gridloc_agents.evaluation.rollout import rollout

    pre = cfg["pretrain"]
    key = _cache_key(cfg, "expert")
    episodes = _load_cache(cache, key)[: pre["episodes"]]
    if cache is not None and len(episodes) < pre["episodes"]:
        others = _sibling_caches(cache, key)  # (episodes held, path), most first
        if others and others[0][0] > len(episodes):
            episodes = _load_cache(others[0][1], key)[: pre["episodes"]]
    env = _env(cfg)
    expert = _Recorded(_expert(cfg, env), values=_wants_values(cfg))
    try:
        for i in tqdm(range(len(episodes), pre["episodes"]), desc=f"expert {pre['expert']} episodes",
                      disable=not progress, leave=False, initial=len(episodes), total=pre["episodes"]):
            ep = rollout(env, expert, PRETRAIN_SEED_BASE + i, keep=True)
            episodes.append(_episode_samples(ep, expert.targets, cfg, expert.q if expert.values else None))
    except KeyboardInterrupt:
        _save_cache(cache, key, episodes)
        raise WarmStartInterrupted(len(episodes), 0) from None
    finally:
        env.close()
    _save_cache(cache, key, episodes)
    return episodes


def dagger_round(model, cfg: dict[str, Any], round_index: int, progress: bool = True) -> list[dict[str, Any]]:
    """One DAgger round: the student (``model``, sampling its actions) plays; every belief it
    reaches is labelled with the expert's action."""
    from gym_gridloc_agents.evaluation.rollout import rollout

    pre = cfg["pretrain"]
    env = _env(cfg)
    expert, values = _expert(cfg, env), _wants_values(cfg)
    student = PPOPolicy(env.unwrapped.model, sb3_model=model, wrapper=cfg["wrapper"], deterministic=False)
    out = []
    n = pre["dagger_episodes"]
    for i in tqdm(range(n), desc=f"DAgger round {round_index + 1}", disable=not progress, leave=False):
        seed = DAGGER_SEED_BASE + round_index * n + i
        ep = rollout(env, student, seed, keep=True)
        expert.reset(seed=seed, model=ep.model)
        labels = [_label(expert, o, b, values) for o, b in zip(ep.observations, ep.beliefs)]
        out.append(_episode_samples(ep, [p for p, _ in labels], cfg, [q for _, q in labels] if values else None))
    env.close()
    return out


# -- fitting ---------------------------------------------------------------------------------------
def _epoch_order(n: int, lengths, gen):
    """The samples' order for one epoch: shuffled, or (``lengths``: the episodes' sample counts, in
    order) whole episodes shuffled, so that a minibatch holds the steps of a few episodes."""
    if lengths is None:
        return torch.randperm(n, generator=gen)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    episodes = torch.randperm(len(lengths), generator=gen).numpy()
    return torch.from_numpy(np.concatenate([np.arange(starts[e], starts[e] + lengths[e]) for e in episodes]))


def _fit(model, data: dict[str, Any], cfg: dict[str, Any], *, epochs: range, progress: bool, label: str) -> int:
    """Fit the actor to the expert's action distributions (cross-entropy; with a ``temperature``,
    the softmax of the planner's action values) and the critic to the returns for ``epochs`` (a
    range: the shuffles of earlier epochs are drawn first, so a resumed fit continues the same sequence).
    Returns the number of epochs done; Ctrl-C raises :class:`_FitInterrupted` with that number."""
    pre = cfg["pretrain"]
    policy = model.policy
    obs = policy.obs_to_tensor(data["obs"])[0] if isinstance(data["obs"], dict) else torch.as_tensor(data["obs"])
    targets = torch.as_tensor(soft_targets(data, float(pre.get("temperature", 0.0))))
    returns = torch.as_tensor(data["returns"])
    optimiser = torch.optim.Adam(policy.parameters(), lr=pre["learning_rate"])
    lr_final = pre.get("learning_rate_final")
    batches = -(-len(targets) // pre["batch_size"])
    gen = torch.Generator().manual_seed(int(cfg["seed"]))
    n = len(targets)
    lengths = data["lengths"] if pre.get("episode_batches") else None  # one sample per step
    for _ in range(epochs.start):
        _epoch_order(n, lengths, gen)
    policy.set_training_mode(True)
    done = epochs.start
    try:
        for epoch in tqdm(epochs, desc=label, disable=not progress, leave=False, initial=epochs.start, total=epochs.stop):
            order = _epoch_order(n, lengths, gen)
            for j, k in enumerate(range(0, n, pre["batch_size"])):
                if lr_final is not None:  # cosine from learning_rate to learning_rate_final over the fit
                    frac = (epoch * batches + j) / max(1, epochs.stop * batches - 1)
                    for group in optimiser.param_groups:
                        group["lr"] = lr_final + 0.5 * (pre["learning_rate"] - lr_final) * (1.0 + math.cos(math.pi * frac))
                idx = order[k : k + pre["batch_size"]]
                batch = {key: v[idx] for key, v in obs.items()} if isinstance(obs, dict) else obs[idx]
                logits = policy.get_distribution(batch).distribution.logits
                values = policy.predict_values(batch)
                cross_entropy = -(targets[idx] * torch.log_softmax(logits, dim=-1)).sum(dim=-1).mean()
                loss = cross_entropy + 0.5 * torch.nn.functional.mse_loss(values.flatten(), returns[idx])
                optimiser.zero_grad()
                loss.backward()
                optimiser.step()
            done += 1
    except KeyboardInterrupt:
        raise _FitInterrupted(done) from None
    finally:
        policy.set_training_mode(False)
    return done


def soft_targets(data: dict[str, Any], temperature: float) -> np.ndarray:
    """The targets to imitate: the expert's action distributions, or with ``temperature > 0``
    ``softmax(-(Q - min Q) / temperature)`` of the planner's action values ``data["values"]``."""
    if temperature <= 0.0:
        return np.asarray(data["targets"], dtype=np.float32)
    if "values" not in data:
        raise ValueError("a temperature needs the planner's action values, and these samples have none")
    z = -(data["values"] - data["values"].min(axis=1, keepdims=True)) / temperature
    e = np.exp(z - z.max(axis=1, keepdims=True))
    return (e / e.sum(axis=1, keepdims=True)).astype(np.float32)


def _agreement(model, data: dict[str, Any]) -> float:
    """How often the policy's most probable action is one of the expert's."""
    policy = model.policy
    obs = policy.obs_to_tensor(data["obs"])[0] if isinstance(data["obs"], dict) else torch.as_tensor(data["obs"])
    with torch.no_grad():
        best = policy.get_distribution(obs).distribution.probs.argmax(dim=1).numpy()
    return float((data["targets"][np.arange(len(best)), best] > 0).mean())


def _merge(episodes: list[dict[str, Any]]) -> dict[str, Any]:
    out = {"obs": _concat([e["obs"] for e in episodes]), "targets": np.concatenate([e["targets"] for e in episodes]),
           "returns": np.concatenate([e["returns"] for e in episodes]), "lengths": np.asarray([e["length"] for e in episodes])}
    if episodes and all("values" in e for e in episodes):
        out["values"] = np.concatenate([e["values"] for e in episodes])
    return out


def behaviour_cloning(model, cfg: dict[str, Any], progress: bool = True, *, cache: Path | None = None,
                      start_epoch: int = 0, start_round: int = 0) -> dict[str, Any]:
    """Fit ``model.policy`` (an sb3 ActorCriticPolicy) to the expert, from epoch ``start_epoch``
    and DAgger round ``start_round`` (a resumed warm start); returns a summary.  Ctrl-C raises
    :class:`WarmStartInterrupted`."""
    pre = cfg["pretrain"]
    start = time.perf_counter()
    expert_eps = collect_expert(cfg, progress=progress, cache=cache)
    dagger_cache = None if cache is None else cache.with_name("dagger.npz")
    dagger_key = _cache_key(cfg, "dagger")
    dagger_eps = _load_cache(dagger_cache, dagger_key)[: start_round * pre["dagger_episodes"]]
    rounds = start_round
    epoch = start_epoch if start_round == 0 else pre["epochs"]
    try:
        if start_round == 0:
            epoch = _fit(model, _merge(expert_eps), cfg, epochs=range(start_epoch, pre["epochs"]), progress=progress,
                         label="behaviour cloning epochs")
        while rounds < pre["dagger_rounds"]:
            dagger_eps += dagger_round(model, cfg, rounds, progress=progress)
            _save_cache(dagger_cache, dagger_key, dagger_eps)
            _fit(model, _merge(expert_eps + dagger_eps), cfg, epochs=range(pre["dagger_epochs"]), progress=progress,
                 label=f"DAgger round {rounds + 1} epochs")
            rounds += 1
    except (KeyboardInterrupt, _FitInterrupted) as exc:
        if isinstance(exc, _FitInterrupted) and rounds == 0 and start_round == 0:
            epoch = exc.done  # the initial cloning stopped here; a DAgger round is redone whole
        raise WarmStartInterrupted(len(expert_eps), epoch, rounds) from None
    data = _merge(expert_eps)
    return {
        "expert": pre["expert"],
        "episodes": int(pre["episodes"]),
        "samples": int(len(data["targets"])),
        "expert_mean_steps": float(data["lengths"].mean()),
        "argmax_agreement": round(_agreement(model, data), 4),
        "dagger_rounds": int(pre["dagger_rounds"]),
        "dagger_samples": int(sum(len(e["targets"]) for e in dagger_eps)),
        "seconds": round(time.perf_counter() - start, 2),
        "resumed_at_epoch": start_epoch or None,
        "resumed_at_round": start_round or None,
    }
