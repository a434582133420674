"""What a ``gridloc sweep`` is before Ray runs anything: the ``--grid`` values and their
configurations (and their names), the checked arguments (:func:`prepare`, what ``sweep.json``
holds), each trial's validated training config, and the ``--resume`` check.

No Ray here: :mod:`gym_gridloc_agents.sweeps.sweep` runs the sweep; :mod:`gym_gridloc_agents.sweeps.sweep_results`
reads and reports what its trials produced.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gym_gridloc.core.validation import check_int, is_int
from gym_gridloc_agents import values
from gym_gridloc_agents.training.config import ConfigError, load_config, read_yaml, validate_config
from gym_gridloc_agents.values import split_values

#: Config keys the sweep sets itself (seeds come from ``--seeds``, paths from ``--output``).
OWNED_KEYS = ("seed", "output", "checkpoint_dir", "tensorboard_log")
#: The most seeds per configuration, and trainings per sweep (seeds x configurations), checked
#: before Ray starts.
MAX_SEEDS, MAX_TRIALS = 1000, 10_000
#: What is compared on ``--resume``: a sweep resumes only with the same arguments.
SPEC_KEYS = ("config", "grid", "seeds", "search", "trials")


class SweepError(ValueError):
    """Bad sweep arguments, or a sweep that cannot start or resume (one line, names the problem)."""


# -- --grid ---------------------------------------------------------------------------------------
def parse_value(text: str) -> Any:
    """One ``--grid`` value (:func:`gym_gridloc_agents.values.parse_value`, without tuples: the
    commas separate the values; ``[16, 16]`` is a list)."""
    try:
        return values.parse_value(text, tuples=False)
    except ValueError as exc:
        raise SweepError(str(exc)) from None


def parse_grid(items: Sequence[str] | None) -> dict[str, list[Any]]:
    """``["hyperparams.learning_rate=1e-4,3e-4", ...]`` -> ``{"hyperparams.learning_rate": [0.0001, 0.0003]}``."""
    grid: dict[str, list[Any]] = {}
    for item in items or ():
        key, eq, rest = item.partition("=")
        key = key.strip()
        if not eq or not key:
            raise SweepError(f"--grid {item!r}: expected KEY=V1,V2,... with KEY a config key as a dotted path, "
                             "e.g. hyperparams.learning_rate=1e-4,3e-4")
        if any(not part for part in key.split(".")):
            raise SweepError(f"--grid {item!r}: {key!r} is not a dotted path of config keys")
        if key.split(".")[0] in OWNED_KEYS:
            raise SweepError(f"--grid {item!r}: the sweep sets {key.split('.')[0]} itself "
                             f"(seeds: --seeds N, from the config's seed; paths: --output DIR)")
        if key in grid:
            raise SweepError(f"--grid: {key} is given twice; give all its values in one --grid {key}=V1,V2,...")
        texts = split_values(rest)
        if not rest.strip() or any(not t.strip() for t in texts):
            raise SweepError(f"--grid {item!r}: {key} needs values, e.g. {key}=V1,V2 (an empty value is not one)")
        try:
            values = [parse_value(t) for t in texts]
        except SweepError as exc:
            raise SweepError(f"--grid {item!r}: {exc}") from None
        if len({canonical(v) for v in values}) != len(values):
            raise SweepError(f"--grid {item!r}: {key} repeats a value")
        grid[key] = values
    return grid


def set_dotted(cfg: dict[str, Any], key: str, value: Any) -> None:
    """``cfg["a"]["b"] = value`` for ``key="a.b"`` (missing mappings are created)."""
    parts = key.split(".")
    d = cfg
    for i, part in enumerate(parts[:-1]):
        if d.get(part) is None:
            d[part] = {}
        if not isinstance(d[part], dict):
            raise SweepError(f"--grid {key}: {'.'.join(parts[: i + 1])} is {d[part]!r} in the config, not a mapping")
        d = d[part]
    d[parts[-1]] = copy.deepcopy(value)


def canonical(value: Any) -> str:
    """``value`` as canonical JSON (sorted keys, no spaces): equal values, equal texts."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"))


def configurations(grid: dict[str, list[Any]]) -> list[dict[str, Any]]:
    """Every combination of the grid's values (the first key varies slowest); ``[{}]`` without a grid."""
    return [dict(zip(grid, combo)) for combo in itertools.product(*grid.values())]


_SAFE = re.compile(r"^[A-Za-z0-9._+-]+$")


def config_label(overrides: dict[str, Any], keys: Sequence[str]) -> str:
    """A configuration's name, also its directory name: ``learning_rate=0.0001_n_steps=64``
    (``base`` without a grid).  Keys are shortened to their last part unless two grid keys share
    it; a value that is not a plain word or number, or a name over 80 characters, gets a short
    hash of the configuration so that two configurations never share a name."""
    if not overrides:
        return "base"
    short = [k.split(".")[-1] for k in keys]
    names = {k: (s if short.count(s) == 1 else k) for k, s in zip(keys, short)}
    present = [k for k in keys if k in overrides]  # Optuna's validation trials set one key of several
    # a string that reads back as another value ('1', 'true') is quoted: 1 and '1' never share a name
    texts = {k: overrides[k] if isinstance(overrides[k], str) and _reads_back(overrides[k]) else json.dumps(overrides[k])
             for k in present}
    label = "_".join(f"{names[k]}={t if _SAFE.match(t) else re.sub(r'[^A-Za-z0-9._+-]+', '_', t).strip('_') or 'x'}"
                     for k, t in texts.items())
    if not all(map(_SAFE.match, texts.values())) or len(label) > 80:
        digest = hashlib.sha1(canonical({k: overrides[k] for k in present}).encode()).hexdigest()[:6]
        label = f"{label[:72]}-{digest}"
    return label


def _reads_back(text: str) -> bool:
    try:
        return parse_value(text) == text
    except SweepError:
        return False


# -- the sweep's specification ----------------------------------------------------------------------
def default_output(config: str | Path) -> Path:
    return Path("runs") / "sweeps" / Path(config).stem


def command_line(config: str | Path, *, seeds: int = 1, grid: Sequence[str] | dict | None = None, search: str | None = None,
                 trials: int | None = None, output: str | Path | None = None, address: str | None = None,
                 cpus: int | None = None) -> str:
    """The ``gridloc sweep`` command of these arguments (for messages and the metadata)."""
    import shlex

    items = grid if not isinstance(grid, dict) else [f"{k}={','.join(json.dumps(v) for v in vs)}" for k, vs in grid.items()]
    words = ["gridloc", "sweep", str(config), "--seeds", str(seeds)]
    words += ["--grid", *items] if items else []
    words += ["--search", search, "--trials", str(trials)] if search else []
    words += ["--address", address] if address else []
    words += ["--cpus", str(cpus)] if cpus else []
    words += ["--output", str(output)] if output is not None else []
    return " ".join(shlex.quote(w) for w in words)


def prepare(config: str | Path, *, seeds: int = 1, grid: Sequence[str] | dict | None = None, search: str | None = None,
            trials: int | None = None, output: str | Path | None = None, address: str | None = None,
            cpus: int | None = None) -> dict[str, Any]:
    """Check the arguments and every configuration of the sweep before anything runs; returns
    the sweep's specification (what ``sweep.json`` holds).  Raises :class:`SweepError` or
    :class:`ConfigError` with a one-line message.  (``address`` is checked, then it and ``cpus``
    only go into the recorded command: a sweep may be resumed elsewhere.)"""
    command = command_line(config, seeds=seeds, grid=grid, search=search, trials=trials, output=output,
                           address=address, cpus=cpus)

    seeds = check_int("--seeds", seeds, 1, MAX_SEEDS, what=f"a whole number in 1..{MAX_SEEDS}", error=SweepError)
    if address is not None:  # before any work, and before Ray is called
        from gym_gridloc_agents.cluster import check_address

        try:
            check_address(address)
        except ValueError as exc:
            raise SweepError(str(exc)) from None
    if search not in (None, "optuna"):
        raise SweepError(f"--search must be optuna, got {search!r}")
    if search == "optuna" and trials is None:
        raise SweepError("--search optuna needs --trials N (how many configurations Optuna tries, each with every seed)")
    if search is None and trials is not None:
        raise SweepError("--trials N needs --search optuna (a --grid sweep runs every combination)")
    if trials is not None:
        trials = check_int("--trials", trials, 1, MAX_TRIALS, what=f"a whole number in 1..{MAX_TRIALS}", error=SweepError)
    grid = dict(grid) if isinstance(grid, dict) else parse_grid(grid)
    n_configs = trials if search == "optuna" else math.prod(len(v) for v in grid.values())
    if n_configs * seeds > MAX_TRIALS:  # checked before Ray starts: Tune would list them all
        raise SweepError(f"--seeds {seeds} x {n_configs} {'--trials' if search else '--grid configurations'} "
                         f"= {n_configs * seeds} trainings; at most {MAX_TRIALS}")
    if search == "optuna" and not grid:
        raise SweepError("--search optuna chooses among --grid values: give at least one --grid KEY=V1,V2,...")
    base = load_config(config)  # a missing or malformed config fails here, naming its file
    raw = read_yaml(config)
    if base["seed"] + seeds - 1 > 2**32 - 1:
        raise SweepError(f"--seeds {seeds}: seeds {base['seed']}..{base['seed'] + seeds - 1} exceed 2**32 - 1")
    out = Path(output) if output is not None else default_output(config)
    spec = {
        "version": 1, "config_path": str(config), "config": raw, "grid": grid, "seeds": seeds, "search": search,
        "trials": trials, "output": str(out.expanduser().resolve()), "command": command,
    }
    try:
        json.dumps(spec)  # a config that JSON cannot hold fails now, not in sweep.json
    except (TypeError, ValueError) as exc:
        raise SweepError(f"{config}: the sweep records its config as JSON, which cannot hold it ({exc})") from None
    checked_configs(spec)
    return spec


def checked_configs(spec: dict[str, Any]) -> list[dict[str, Any]]:
    """The validated training configs (first seed) the sweep may run, checked now: every
    combination of a grid sweep; for Optuna, which picks among a product that may be large, the
    config alone and with each single ``--grid`` value (a combination that does not validate
    fails as that trial's error)."""
    if spec["search"] != "optuna":
        configs = configurations(spec["grid"])
        labels = [config_label(o, list(spec["grid"])) for o in configs]
        if len(set(labels)) != len(labels):  # (config_label hashes what it cannot spell; never expected)
            raise SweepError(f"--grid: two configurations share the name {next(x for x in labels if labels.count(x) > 1)}")
        checked = [trial_config(spec, o, 0) for o in configs]
        trained: dict[str, str] = {}  # two values the config reads as one (1 and 1.0 as n_epochs): one configuration
        for label, cfg in zip(labels, checked):
            same = trained.setdefault(canonical({k: v for k, v in cfg.items() if k not in ("output", "checkpoint_dir", "tensorboard_log")}), label)
            if same != label:
                raise SweepError(f"--grid: the configurations {same} and {label} are one configuration once the config is "
                                 "checked (their values read alike): give each value once")
        return checked
    return [trial_config(spec, {}, 0)] + [trial_config(spec, {k: v}, 0) for k, vs in spec["grid"].items() for v in vs]


def trial_config(spec: dict[str, Any], overrides: dict[str, Any], index: int) -> dict[str, Any]:
    """The validated training config of one trial: the configuration's overrides, seed
    ``config seed + index``, and its paths under the sweep's output directory.  A config without
    evaluations (``eval_freq: 0``) is evaluated once, at the end (the sweep needs a score)."""
    raw = copy.deepcopy(spec["config"])
    if not isinstance(raw, dict):
        raise ConfigError(f"{spec['config_path']}: a config must be a mapping of keys to values")
    for key, value in overrides.items():
        set_dotted(raw, key, value)
    where = spec["config_path"] + "".join(f" {k}={json.dumps(v)}" for k, v in overrides.items())
    label = config_label(overrides, list(spec["grid"]))
    seed = raw.get("seed", 0)
    if is_int(seed):
        seed = raw["seed"] = seed + index
    out = Path(spec["output"])
    raw["output"] = str(out / "models" / label / f"seed{seed}.zip")
    raw["checkpoint_dir"] = str(out / "checkpoints" / label / f"seed{seed}")
    if raw.get("tensorboard_log"):
        raw["tensorboard_log"] = str(out / "tensorboard" / label)
    cfg = validate_config(raw, source=where)
    if cfg["eval_freq"] == 0:
        cfg["eval_freq"] = cfg["total_timesteps"]
    return cfg


def check_resume(spec: dict[str, Any], stored: dict[str, Any], directory: Path) -> None:
    for key in SPEC_KEYS:
        if canonical(stored.get(key)) != canonical(spec.get(key)):
            raise SweepError(
                f"--resume: the sweep in {directory} was started with another {key} "
                f"({'config file contents' if key == 'config' else json.dumps(stored.get(key))}); "
                f"resume it with the same arguments: {stored.get('command', '?')}"
            )
