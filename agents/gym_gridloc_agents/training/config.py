"""Training configurations: YAML files read with ``yaml.safe_load`` and validated.

A config (rl-baselines3-zoo style, one experiment per file)::

    algo: ppo                       # ppo | recurrent_ppo | a2c | dqn
    env_id: WindyMaze-v0
    env_kwargs: {}                  # keyword arguments of gym.make
    wrapper:                        # HMMBeliefWrapper options; belief: false = raw observations
      belief: true
      flatten: true
    n_envs: 8
    seed: 0
    total_timesteps: !!float 1e6
    policy: MlpPolicy
    policy_kwargs: {net_arch: [64, 64], activation_fn: tanh}
    hyperparams: {learning_rate: 3.0e-4, n_steps: 256, gamma: 0.995}
    output: agents/gym_gridloc_agents/models/WindyMaze-v0.zip
    checkpoint_freq: 100000         # environment steps between checkpoints (0: none)
    checkpoint_dir: null            # default runs/checkpoints/<output stem>
    tensorboard_log: null           # a directory, or null

Every key is checked: an unknown key is an error that names it and lists the allowed ones.  No
string from a config is ever evaluated: activation functions are looked up by name in a fixed table.
"""

from __future__ import annotations

import copy
import inspect
from pathlib import Path
from typing import Any

from gym_gridloc.core.validation import check_int, is_int
from gym_gridloc_agents.history import HISTORY_KEYS, history_options
from gym_gridloc_agents.loading import ALGOS
from gym_gridloc_agents.registry import EXPERT_NAMES, VALUE_NAMES, either
from gym_gridloc_agents.training.config_values import (HYPER_RANGES, SCHEDULED, ConfigError, allowed_hyperparams,  # noqa: F401
                                                       check_buffer_memory, check_hyperparams, check_policy_values,
                                                       known_keys as _known_keys,
                                                       number as _num)

TOP_KEYS = {
    "algo": "ppo, recurrent_ppo, a2c or dqn",
    "env_id": "a registered environment id",
    "env_kwargs": "keyword arguments of gym.make",
    "wrapper": "HMMBeliefWrapper options: belief, flatten, full_state, map, lookahead; previous_action (raw readings); "
               "past_actions, steps_left or time_step (gym_gridloc_agents.history)",
    "n_envs": "number of parallel environments (DummyVecEnv)",
    "seed": "the seed of environments, numpy and torch",
    "total_timesteps": "environment steps to train for",
    "policy": "the sb3 policy class name",
    "policy_kwargs": "net_arch, activation_fn, ortho_init, lstm_hidden_size, n_lstm_layers, ...",
    "hyperparams": "keyword arguments of the algorithm (learning_rate, n_steps, gamma, ...)",
    "output": "the model file to write (.zip); metadata goes to the same name with .json",
    "checkpoint_freq": "environment steps between checkpoints (0 = none)",
    "checkpoint_dir": "where checkpoints go (default runs/checkpoints/<output stem>)",
    "tensorboard_log": "a TensorBoard log directory, or null",
    "description": "free text, kept in the metadata",
    "eval_freq": "steps between evaluations on held-out seeds; the best evaluated model is saved (0 = keep the last)",
    "eval_episodes": "episodes per evaluation (seeds 2_000_000 + i)",
    "pretrain": "optional behaviour-cloning warm start: expert, episodes, epochs, batch_size, learning_rate",
    "vec_env": "dummy (SB3's DummyVecEnv of wrapped envs, default) or native (gym_gridloc's vector env)",
    "deterministic": "how the policy acts in evaluations and the benchmark: true (default) the most probable action, "
                     "false sampled from the policy (seeded per episode)",
    "break_cycles": "with deterministic true: sample the action where the belief is one the episode held before "
                    "(a deterministic policy of the belief would repeat itself), in evaluations and the benchmark (default false)",
    "schedule": "final values of learning_rate, clip_range or ent_coef: each goes linearly from its hyperparams value to this",
}

PRETRAIN_KEYS = {
    "expert": "the policy to imitate (a policy name that needs no model file: greedy, greedy2, a planner)",
    "expert_kwargs": "the expert's options (numbers, strings, booleans), e.g. {depth: 2}",
    "episodes": "expert episodes to collect (seeds 1_000_000 + i, disjoint from the benchmark's)",
    "epochs": "passes over the collected data (and over the data after each DAgger round)",
    "batch_size": "minibatch size",
    "learning_rate": "Adam learning rate of the warm start",
    "dagger_rounds": "DAgger rounds after the cloning (0: none): the student plays, the expert labels",
    "dagger_episodes": "episodes the student plays per DAgger round",
    "dagger_epochs": "passes over all the data after each DAgger round (default: epochs)",
    "episode_batches": "true: minibatches of whole episodes (the episodes are shuffled, not the samples), so that a "
                       "batch holds few maps (faster for pose_pool_cnn, which convolves each map once); default false",
    "temperature": "0 (default): imitate the expert's tied best actions; > 0 (planner experts): "
                   "softmax(-(Q - min Q) / temperature) of its action values Q",
    "learning_rate_final": "if set, each fit lowers the learning rate along a cosine to this",
}

WRAPPER_KEYS = {"belief": bool, "flatten": bool, "full_state": bool, "map": bool, "lookahead": int,
                "previous_action": bool, "past_actions": int, "steps_left": int, "time_step": int}

POLICIES = {
    "ppo": ("MlpPolicy", "MultiInputPolicy"),
    "recurrent_ppo": ("MlpLstmPolicy", "MultiInputLstmPolicy"),
    "a2c": ("MlpPolicy", "MultiInputPolicy"),
    "dqn": ("MlpPolicy", "MultiInputPolicy"),
}

ACTIVATIONS = ("tanh", "relu", "elu", "leaky_relu", "gelu")

POLICY_KWARGS = {
    "ppo": {"net_arch", "activation_fn", "ortho_init", "log_std_init", "share_features_extractor",
            "features_extractor", "features_extractor_kwargs"},
    "recurrent_ppo": {
        "net_arch", "activation_fn", "ortho_init", "lstm_hidden_size", "n_lstm_layers",
        "shared_lstm", "enable_critic_lstm", "share_features_extractor", "features_extractor",
        "features_extractor_kwargs",
    },
    "a2c": {"net_arch", "activation_fn", "ortho_init", "share_features_extractor", "features_extractor",
            "features_extractor_kwargs"},
    "dqn": {"net_arch", "activation_fn", "features_extractor", "features_extractor_kwargs"},
}


def activation(name: str):
    import torch.nn as nn

    return {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU, "leaky_relu": nn.LeakyReLU, "gelu": nn.GELU}[name]


def load_config(path: str | Path) -> dict[str, Any]:
    """Read and validate a YAML config; returns a dict with every default filled in."""
    return validate_config(read_yaml(path), source=str(path))


#: How deep a config's mappings and lists may nest (a real one nests three or four levels).
MAX_DEPTH = 50


def read_yaml(path: str | Path) -> Any:
    """A config file's YAML, or a one-line :class:`ConfigError` naming the file: missing, not
    UTF-8, not YAML, nested deeper than :data:`MAX_DEPTH`."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file {str(path)!r} does not exist")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason}); save the config as UTF-8") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    depth = level = 0
    for ch in text:  # flow collections nest by brackets; the composer recurses on each level
        level += (ch in "[{") - (ch in "]}")
        depth = max(depth, level)
    if depth > MAX_DEPTH:
        raise ConfigError(f"{path}: nested {depth} levels deep (at most {MAX_DEPTH})")
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {' '.join(str(exc).split())}") from None
    except RecursionError:
        raise ConfigError(f"{path}: nested too deep (at most {MAX_DEPTH} levels)") from None
    if _depth(raw) > MAX_DEPTH:
        raise ConfigError(f"{path}: nested more than {MAX_DEPTH} levels deep")
    return raw


def _depth(value: Any, level: int = 0) -> int:
    if level > MAX_DEPTH:
        return level
    if isinstance(value, dict):
        return max((_depth(v, level + 1) for v in value.values()), default=level + 1)
    if isinstance(value, list):
        return max((_depth(v, level + 1) for v in value), default=level + 1)
    return level


def validate_config(raw: Any, source: str = "config") -> dict[str, Any]:
    """Check a config dict (see the module docstring) and fill in defaults."""
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: a config must be a mapping of keys to values, got {type(raw).__name__}")
    _known_keys(source, raw, sorted(TOP_KEYS))
    cfg = copy.deepcopy(raw)
    for key in ("algo", "env_id"):
        if key not in cfg:
            raise ConfigError(f"{source}: missing required key {key!r}")
    if (algo := cfg["algo"]) not in ALGOS:
        raise ConfigError(f"{source}: algo must be one of {', '.join(ALGOS)}, got {algo!r}")
    import gymnasium as gym

    import gym_gridloc  # noqa: F401 - registers the environments

    if not isinstance(cfg["env_id"], str) or cfg["env_id"] not in gym.registry:
        raise ConfigError(f"{source}: env_id {cfg['env_id']!r} is not a registered environment (e.g. {', '.join(gym_gridloc.ENV_IDS)})")
    cfg.setdefault("env_kwargs", {})
    if not isinstance(cfg["env_kwargs"], dict):
        raise ConfigError(f"{source}: env_kwargs must be a mapping, got {cfg['env_kwargs']!r}")
    from gym_gridloc_agents.envs import check_environment

    raw_space = check_environment(cfg["env_id"], cfg["env_kwargs"], what=f"{source}: env_id/env_kwargs", error=ConfigError)

    wrapper = cfg.setdefault("wrapper", {})
    _known_keys(source, wrapper, WRAPPER_KEYS, "wrapper")
    wrapper.setdefault("belief", algo != "recurrent_ppo")
    wrapper.setdefault("flatten", bool(wrapper["belief"]))
    wrapper.setdefault("full_state", False)
    wrapper.setdefault("map", False)
    for k, v in wrapper.items():
        if k == "lookahead":
            check_int(f"{source}: wrapper.lookahead", v, 0, 2, what="0, 1 or 2", error=ConfigError)
        elif k not in HISTORY_KEYS and not isinstance(v, bool):
            raise ConfigError(f"{source}: wrapper.{k} must be true or false, got {v!r}")
    history_options(wrapper, error=ConfigError, source=f"{source}: wrapper.")  # the history's (one clock at most)
    if not wrapper["belief"] and (wrapper["flatten"] or wrapper["full_state"] or wrapper["map"] or wrapper.get("lookahead")):
        raise ConfigError(f"{source}: wrapper.flatten / wrapper.full_state / wrapper.map / wrapper.lookahead need wrapper.belief: true")
    if not wrapper["belief"] and algo != "recurrent_ppo":
        raise ConfigError(f"{source}: wrapper.belief: false (the raw readings, no belief) needs algo: recurrent_ppo, "
                          f"whose memory stands in for the belief; {algo} acts on the belief observation "
                          "(the evaluations and the benchmark give it one)")
    if cfg.setdefault("vec_env", "dummy") not in ("dummy", "native"):
        raise ConfigError(f"{source}: vec_env must be dummy or native, got {cfg['vec_env']!r}")
    if wrapper.get("previous_action"):
        if wrapper["belief"]:
            raise ConfigError(f"{source}: wrapper.previous_action (gym_gridloc.PreviousActionWrapper) is for the raw "
                              "readings: it needs wrapper.belief: false")
        if cfg["vec_env"] == "native":
            raise ConfigError(f"{source}: wrapper.previous_action needs vec_env: dummy (the native vector env "
                              "has no previous-action observation)")
    if algo == "recurrent_ppo" and wrapper["belief"]:
        raise ConfigError(f"{source}: algo recurrent_ppo reads the raw readings (wrapper.belief: false, its memory stands in for "
                          "the belief): the evaluations and the benchmark give it no belief; use algo ppo on the belief")
    from gym_gridloc_agents.envs import make_env  # the observation training builds (the buffers hold it) and its grid
    import gymnasium.spaces

    try:
        probe = make_env(cfg["env_id"], cfg["env_kwargs"], wrapper)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: wrapper {wrapper}: {exc}") from None
    floats, grid = gymnasium.spaces.flatdim(probe.observation_space), probe.unwrapped.model.shape
    probe.close()

    for key, default, minimum, maximum in (("n_envs", 8, 1, None), ("seed", 0, 0, 2**32 - 1),
                                           ("total_timesteps", None, 1, None), ("eval_freq", 0, 0, None),
                                           ("eval_episodes", 200, 1, None), ("checkpoint_freq", 0, 0, None)):
        if default is None and key not in cfg:  # no default: a required key
            raise ConfigError(f"{source}: missing required key {key!r}")
        cfg[key] = _num(source, key, cfg.get(key, default), integer=True, minimum=minimum, maximum=maximum)

    dict_obs = wrapper["belief"] and not wrapper["flatten"]
    cfg.setdefault("policy", POLICIES[algo][1] if dict_obs else POLICIES[algo][0])
    if cfg["policy"] not in POLICIES[algo]:
        raise ConfigError(f"{source}: policy for {algo} must be one of {', '.join(POLICIES[algo])}, got {cfg['policy']!r}")
    if (cfg["policy"] == POLICIES[algo][1]) != dict_obs:
        raise ConfigError(
            f"{source}: policy {cfg['policy']} needs {'Dict' if cfg['policy'] == POLICIES[algo][1] else 'flat'} observations, "
            f"but wrapper {wrapper} gives {'Dict' if dict_obs else 'flat'} ones; use policy {POLICIES[algo][1] if dict_obs else POLICIES[algo][0]}"
        )

    pk = cfg.setdefault("policy_kwargs", {})
    _known_keys(source, pk, sorted(POLICY_KWARGS[algo]), "policy_kwargs", f" for {algo}")
    check_policy_values(source, pk)
    if "features_extractor" in pk:
        from gym_gridloc_agents.features import EXTRACTORS

        if pk["features_extractor"] not in EXTRACTORS:
            raise ConfigError(f"{source}: policy_kwargs.features_extractor must be one of {', '.join(EXTRACTORS)}, got {pk['features_extractor']!r}")
        reads_dict = EXTRACTORS[pk["features_extractor"]].dict_observations
        if cfg["policy"] != POLICIES[algo][int(reads_dict)]:  # POLICIES[algo]: (flat policy, Dict policy)
            raise ConfigError(f"{source}: policy_kwargs.features_extractor {pk['features_extractor']} reads {'Dict' if reads_dict else 'flat'} "
                              f"observations: use policy {POLICIES[algo][int(reads_dict)]} (wrapper.flatten: {str(not reads_dict).lower()})")
    fek = pk.get("features_extractor_kwargs", {})
    if not isinstance(fek, dict) or not all(isinstance(k, str) and (isinstance(v, bool) or (is_int(v) and v > 0)) for k, v in fek.items()):
        raise ConfigError(f"{source}: policy_kwargs.features_extractor_kwargs must map names to positive integers or true/false, got {fek!r}")
    if fek and "features_extractor" not in pk:
        raise ConfigError(f"{source}: policy_kwargs.features_extractor_kwargs needs policy_kwargs.features_extractor")
    if fek:
        names = [k for k in inspect.signature(EXTRACTORS[pk["features_extractor"]]).parameters if k != "observation_space"]
        if set(fek) - set(names):
            raise ConfigError(f"{source}: policy_kwargs.features_extractor_kwargs for {pk['features_extractor']} takes {', '.join(names)}, got {', '.join(sorted(fek))}")
    if pk.get("features_extractor") == "reading_cell":  # the grid it decodes must be the sensor's
        try:
            decoded = EXTRACTORS["reading_cell"].reading_space(**fek)
        except ValueError as exc:
            raise ConfigError(f"{source}: policy_kwargs.features_extractor_kwargs: {exc}") from None
        default = inspect.signature(EXTRACTORS["reading_cell"].reading_space).parameters
        sides = tuple(fek.get(k, default[k].default) for k in ("height", "width"))  # the grid's sides, not only its cells
        if wrapper["belief"] or raw_space != decoded or sides != tuple(grid):
            raise ConfigError(f"{source}: features_extractor reading_cell ({fek or 'its default sizes'}) reads raw readings "
                              f"(wrapper.belief: false) of a sensor reporting a cell of a {sides[0]}x{sides[1]} grid, {decoded}; "
                              f"{cfg['env_id']} with {cfg['env_kwargs']} reads {raw_space} on a {grid[0]}x{grid[1]} grid"
                              f"{' behind the belief wrapper' if wrapper['belief'] else ''}")
    if pk.get("features_extractor") == "candidate_views":  # it reads the flat layout of one maze size
        side = fek.get("size", inspect.signature(EXTRACTORS["candidate_views"]).parameters["size"].default)
        layout = all(wrapper.get(k) for k in ("belief", "flatten", "full_state", "map"))
        if cfg["env_id"] != "DepthMaze-v0" or not layout or tuple(grid) != (side, side):
            raise ConfigError(f"{source}: features_extractor candidate_views (size {side}) reads the flat pose belief and maze of a "
                              f"DepthMaze-v0 of size {side} (wrapper belief, flatten, full_state and map true); got {cfg['env_id']} "
                              f"on a {grid[0]}x{grid[1]} grid with wrapper {wrapper}")
    if "activation_fn" in pk and pk["activation_fn"] not in ACTIVATIONS:
        raise ConfigError(f"{source}: policy_kwargs.activation_fn must be one of {', '.join(ACTIVATIONS)}, got {pk['activation_fn']!r}")
    if "net_arch" in pk:
        na = pk["net_arch"]
        ok = isinstance(na, list) and all(is_int(x) and x > 0 for x in na)
        ok = ok or (isinstance(na, dict) and set(na) <= {"pi", "vf"} and all(
            isinstance(v, list) and all(is_int(x) and x > 0 for x in v) for v in na.values()))
        if not ok:
            raise ConfigError(f"{source}: policy_kwargs.net_arch must be a list of positive integers or {{pi: [...], vf: [...]}}, got {na!r}")

    check_hyperparams(source, cfg)
    check_buffer_memory(source, cfg, floats)

    if "output" not in cfg:
        raise ConfigError(f"{source}: missing required key 'output' (the model file to write, .zip)")
    if not isinstance(cfg["output"], str) or not cfg["output"].endswith(".zip"):
        raise ConfigError(f"{source}: output must be a path ending in .zip, got {cfg['output']!r}")
    for key in ("checkpoint_dir", "tensorboard_log"):
        if cfg.setdefault(key, None) is not None and not isinstance(cfg[key], str):
            raise ConfigError(f"{source}: {key} must be a path or null, got {cfg[key]!r}")
    if not isinstance(cfg.setdefault("description", ""), str):  # (free text: 1 and '1' would print as one)
        raise ConfigError(f"{source}: description must be text (quote a number: '1'), got {cfg['description']!r}")
    for key, default in (("deterministic", True), ("break_cycles", False)):
        if not isinstance(cfg.setdefault(key, default), bool):
            raise ConfigError(f"{source}: {key} must be true or false, got {cfg[key]!r}")
    if cfg["break_cycles"] and (algo == "recurrent_ppo" or not wrapper["belief"]):
        raise ConfigError(f"{source}: break_cycles needs a policy of the belief (algo ppo, wrapper.belief: true): "
                          "it samples where the belief comes back")
    pre = cfg.setdefault("pretrain", None)
    if pre is not None:
        if algo != "ppo" or not wrapper["belief"]:
            raise ConfigError(f"{source}: pretrain needs algo: ppo with wrapper.belief: true")
        _known_keys(source, pre, PRETRAIN_KEYS, "pretrain")
        if pre.setdefault("expert", "greedy2") not in EXPERT_NAMES:
            raise ConfigError(f"{source}: pretrain.expert must be one of {', '.join(EXPERT_NAMES)}, "
                              f"got {pre['expert']!r}")
        ek = pre.setdefault("expert_kwargs", {})
        if not isinstance(ek, dict) or not all(isinstance(k, str) and isinstance(v, (int, float, str, bool)) for k, v in ek.items()):
            raise ConfigError(f"{source}: pretrain.expert_kwargs must map names to numbers, strings or booleans, got {ek!r}")
        pre["dagger_rounds"] = _num(source, "pretrain.dagger_rounds", pre.get("dagger_rounds", 0), integer=True, minimum=0)
        pre["dagger_episodes"] = _num(source, "pretrain.dagger_episodes", pre.get("dagger_episodes", 200), integer=True, minimum=1)
        pre["epochs"] = _num(source, "pretrain.epochs", pre.get("epochs", 10), integer=True, minimum=1)
        pre["dagger_epochs"] = _num(source, "pretrain.dagger_epochs", pre.get("dagger_epochs", pre["epochs"]), integer=True, minimum=1)
        pre["episodes"] = _num(source, "pretrain.episodes", pre.get("episodes", 1000), integer=True, minimum=1)
        pre["batch_size"] = _num(source, "pretrain.batch_size", pre.get("batch_size", 256), integer=True, minimum=1)
        pre["learning_rate"] = _num(source, "pretrain.learning_rate", pre.get("learning_rate", 1e-3), integer=False, minimum=0)
        if not isinstance(pre.setdefault("episode_batches", False), bool):
            raise ConfigError(f"{source}: pretrain.episode_batches must be true or false, got {pre['episode_batches']!r}")
        pre["temperature"] = _num(source, "pretrain.temperature", pre.get("temperature", 0.0), integer=False, minimum=0)
        if pre["temperature"] > 0 and pre["expert"] not in VALUE_NAMES:
            raise ConfigError(f"{source}: pretrain.temperature needs a planner's action values: expert "
                              f"{either(VALUE_NAMES)}, not {pre['expert']!r}")
        if pre.get("learning_rate_final") is not None:
            pre["learning_rate_final"] = _num(source, "pretrain.learning_rate_final", pre["learning_rate_final"], integer=False,
                                              minimum=0, maximum=pre["learning_rate"])
    return cfg
