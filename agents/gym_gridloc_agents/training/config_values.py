"""The checks of a training config's values (:mod:`gym_gridloc_agents.training.config` reads the
file and walks its keys): :class:`ConfigError`, numbers, known keys, and the algorithms'
hyperparameters -- their ranges, no null where the algorithm has no null, the schedules, and the
memory their rollout or replay buffers would take, estimated before anything is allocated."""

from __future__ import annotations

import inspect
import math
import os
from typing import Any

from gym_gridloc.core.validation import check_int, unknown_names
from gym_gridloc_agents.loading import algo_class


class ConfigError(ValueError):
    """A training config is malformed; the message names the file and the key."""


#: Hyperparameters a ``schedule`` may anneal linearly over training (from ``hyperparams``' value).
SCHEDULED = ("learning_rate", "clip_range", "ent_coef")

#: Ranges of the algorithms' numeric hyperparameters: (integer, minimum, strictly above it, maximum).
HYPER_RANGES = {
    "n_steps": (True, 1, False, None), "batch_size": (True, 2, False, None), "n_epochs": (True, 1, False, None),
    "learning_rate": (False, 0, True, None), "gamma": (False, 0, True, 1), "gae_lambda": (False, 0, False, 1),
    "clip_range": (False, 0, True, None), "ent_coef": (False, 0, False, None), "vf_coef": (False, 0, False, None),
    "max_grad_norm": (False, 0, True, None), "target_kl": (False, 0, True, None), "buffer_size": (True, 1, False, None),
}

# Keys of the algorithm's constructor that the config must not set through ``hyperparams``
# (they come from elsewhere in the config, or would let a config run arbitrary code).
_RESERVED = {"policy", "env", "seed", "policy_kwargs", "tensorboard_log", "verbose", "device",
             "_init_setup_model", "rollout_buffer_class", "rollout_buffer_kwargs", "stats_window_size"}


def allowed_hyperparams(algo: str) -> set[str]:
    params = inspect.signature(algo_class(algo).__init__).parameters
    return {k for k in params if k != "self"} - _RESERVED


def hyperparam_defaults(algo: str) -> dict[str, Any]:
    """The algorithm's own default of each hyperparameter a config may set."""
    params = inspect.signature(algo_class(algo).__init__).parameters
    return {k: p.default for k, p in params.items() if k in allowed_hyperparams(algo)}


def number(source: str, key: str, value: Any, *, integer: bool, minimum: float, maximum: float | None = None,
           above: bool = False) -> Any:
    """A finite number (a whole one with ``integer``) at least ``minimum`` (above it, with
    ``above``) and at most ``maximum``; else a :class:`ConfigError` naming the key."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{source}: {key} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ConfigError(f"{source}: {key} must be a finite number, got {value!r}")
    if integer:  # (no integer range is open below)
        return check_int(f"{source}: {key}", value, minimum, maximum, whole=True, error=ConfigError)
    if value < minimum or (above and value == minimum):
        raise ConfigError(f"{source}: {key} must be {'>' if above else '>='} {minimum}, got {value!r}")
    if maximum is not None and value > maximum:
        raise ConfigError(f"{source}: {key} must be <= {maximum}, got {value!r}")
    return value


def known_keys(source: str, value: Any, allowed, name: str | None = None, qualifier: str = "") -> None:
    """``value`` (the config, or its mapping ``name``) has only keys among ``allowed`` (listed in
    this order, ``allowed{qualifier}:``), else a :class:`ConfigError` naming the others."""
    if name is not None and not isinstance(value, dict):
        raise ConfigError(f"{source}: {name} must be a mapping, got {value!r}")
    bad = sorted(set(value) - set(allowed))
    if bad:
        where = "" if name is None else f"in {name}: "
        raise ConfigError(f"{source}: unknown key(s) {where}{unknown_names(bad, list(allowed))}; "
                          f"allowed{qualifier}: {', '.join(allowed)}")


def check_hyperparams(source: str, cfg: dict[str, Any]) -> None:
    """``cfg["hyperparams"]`` and ``cfg["schedule"]`` (filled in, numbers checked in place): known
    keys, numbers in their ranges, no null where the algorithm's default is not null (the
    algorithm would fail on it, or take it for something else), a schedule only from a
    hyperparameter given."""
    algo = cfg["algo"]
    hp = cfg.setdefault("hyperparams", {})
    known_keys(source, hp, sorted(allowed_hyperparams(algo)), "hyperparams", f" for {algo}")
    defaults = hyperparam_defaults(algo)
    for k, v in hp.items():
        if v is None and defaults.get(k) is not None:
            raise ConfigError(f"{source}: hyperparams.{k} must not be null ({algo}'s default: {defaults[k]!r}; "
                              "leave the key out for it)")
        if isinstance(v, str):
            raise ConfigError(f"{source}: hyperparams.{k} must be a number or boolean (strings are not evaluated), got {v!r}")
        if k in HYPER_RANGES and v is not None:
            integer, lo, above, hi = HYPER_RANGES[k]
            hp[k] = number(source, f"hyperparams.{k}", v, integer=integer, minimum=lo, maximum=hi, above=above)
        elif isinstance(v, float) and not math.isfinite(v):
            raise ConfigError(f"{source}: hyperparams.{k} must be a finite number, got {v!r}")
    sched = cfg.setdefault("schedule", {})
    known_keys(source, sched, SCHEDULED, "schedule")
    for k, v in sched.items():
        if k not in allowed_hyperparams(algo):
            raise ConfigError(f"{source}: schedule.{k}: {algo} has no {k} to anneal")
        if k not in hp:
            raise ConfigError(f"{source}: schedule.{k} needs hyperparams.{k}, the value it starts from")
        integer, lo, above, hi = HYPER_RANGES[k]
        sched[k] = number(source, f"schedule.{k}", v, integer=integer, minimum=lo, maximum=hi, above=above)
    if hp.get("n_steps", 2048) * cfg["n_envs"] < 2:
        raise ConfigError(f"{source}: hyperparams.n_steps x n_envs must be at least 2, got {hp.get('n_steps')} x {cfg['n_envs']}")


#: The policy keywords that are plain values: true/false, or (integer, minimum) numbers.
POLICY_VALUES = {"ortho_init": bool, "share_features_extractor": bool, "shared_lstm": bool, "enable_critic_lstm": bool,
                 "lstm_hidden_size": (True, 1), "n_lstm_layers": (True, 1), "log_std_init": (False, -math.inf)}


def check_policy_values(source: str, pk: dict[str, Any]) -> None:
    """``policy_kwargs``' plain values (:data:`POLICY_VALUES`): no null, of their type; else a
    :class:`ConfigError` naming the key."""
    for key, kind in POLICY_VALUES.items():
        if key not in pk:
            continue
        if kind is bool:
            if not isinstance(pk[key], bool):
                raise ConfigError(f"{source}: policy_kwargs.{key} must be true or false, got {pk[key]!r}")
        else:
            pk[key] = number(source, f"policy_kwargs.{key}", pk[key], integer=kind[0], minimum=kind[1])


def memory_bytes() -> int | None:
    """This machine's physical memory (None where the system does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, OSError, ValueError):  # pragma: no cover - not POSIX
        return None


def check_buffer_memory(source: str, cfg: dict[str, Any], observation_floats: int) -> None:
    """The rollout buffer (``n_steps x n_envs`` rows; ``buffer_size`` transitions for DQN, which
    keeps each observation twice) of float32 observations of ``observation_floats`` numbers, the
    per-step numbers beside them (action, reward, value, ...) and a recurrent policy's LSTM states
    must fit in this machine's memory, and so must the networks (``net_arch``, the LSTM: their
    weights, gradients and Adam's two moments): else a :class:`ConfigError` naming the key, before
    anything is allocated."""
    algo, hp, pk = cfg["algo"], cfg["hyperparams"], cfg["policy_kwargs"]
    defaults, have = hyperparam_defaults(algo), memory_bytes()
    arch = pk.get("net_arch", [64, 64])
    widths = [[observation_floats, *w] for w in (arch.values() if isinstance(arch, dict) else [arch])]
    weights = sum(a * b for w in widths for a, b in zip(w, w[1:]))
    hidden, layers = int(pk.get("lstm_hidden_size", 256)), int(pk.get("n_lstm_layers", 1))
    if algo == "recurrent_ppo":  # (an actor's and a critic's LSTM at most)
        weights += 2 * 4 * hidden * (observation_floats + hidden + layers * 2 * hidden)
    if have is not None and 16 * weights > have:
        raise ConfigError(f"{source}: policy_kwargs (net_arch, lstm_hidden_size) make networks of {weights:_} weights that need "
                          f"about {16 * weights / 2**30:.1f} GiB to train, more than this machine's memory ({have / 2**30:.1f} GiB)")
    if algo == "dqn":
        key, rows = "hyperparams.buffer_size", int(hp.get("buffer_size", defaults["buffer_size"]))
        per_row = 2 * observation_floats + 4
    else:
        key, rows = "hyperparams.n_steps x n_envs", int(hp.get("n_steps", defaults["n_steps"])) * cfg["n_envs"]
        per_row = observation_floats + 8 + (4 * hidden * layers if algo == "recurrent_ppo" else 0)
    need = 4 * rows * per_row
    if have is not None and need > have:
        raise ConfigError(f"{source}: {key} = {rows:_} rows of {per_row:_} float32 numbers need about {need / 2**30:.1f} GiB, "
                          f"more than this machine's memory ({have / 2**30:.1f} GiB); give fewer")


__all__ = ["ConfigError", "HYPER_RANGES", "POLICY_VALUES", "SCHEDULED", "allowed_hyperparams", "check_buffer_memory",
           "check_hyperparams", "check_policy_values", "hyperparam_defaults", "known_keys", "memory_bytes", "number"]
