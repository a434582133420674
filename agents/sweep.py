"""``gridloc sweep``: seeds and hyperparameter sweeps of :func:`gym_gridloc_agents.train.train` on Ray Tune.

    gridloc sweep configs/ppo_colourgrid.yml --seeds 5 \\
        --grid hyperparams.learning_rate=1e-4,3e-4 hyperparams.n_steps=128,256
    gridloc sweep CONFIG --seeds 3 --grid hyperparams.learning_rate=1e-4,3e-4,1e-3 --search optuna --trials 6
    gridloc sweep CONFIG ... --address HEAD_IP:6379      # the same sweep on a running Ray cluster
    gridloc sweep CONFIG ... --resume                     # continue an interrupted sweep

Every trial is the usual training (same config format, checkpoints and metadata) of one
*configuration* (the config with one value of each ``--grid`` key, given as a dotted path) and
one seed (the config's ``seed`` + 0..N-1), run by Ray Tune as a function trainable, 1 CPU each.
``--search optuna`` lets Optuna (Tune's ``OptunaSearch``) pick ``--trials`` configurations among
the ``--grid`` values, every one trained with every seed, and Tune's ``ASHAScheduler`` stop the
trials whose held-out evaluations fall behind.

The score of a trial is lower-is-better: the mean steps to localise on the held-out evaluation
episodes, or minus the accuracy when ``env_kwargs.episode_length`` is set (fixed-length episodes),
as :func:`train._score`; a seed's number is the evaluation of the model ``train`` kept (its best
evaluation).  These are validation numbers (the same episodes chose the model): compare the
winners on the benchmark's episodes with ``gridloc bench --ppo-model <output>/models/<configuration>``.

Everything goes under ``--output`` (default ``runs/sweeps/<config stem>``)::

    sweep.json                        what was asked (``--resume`` checks it is the same sweep)
    tune/                             Ray Tune's experiment directory (trial results, state)
    models/<configuration>/seed<S>.zip  each seed's model, its metadata beside it (.json)
    checkpoints/<configuration>/seed<S>/  that training's checkpoints and evaluations' best.zip
    results/<configuration>.md/.json  per configuration: one row per seed and the aggregates
    summary.md, summary.json          every configuration, best first
    best.zip, best.json               the best configuration's median-seed model

Rules:

* the aggregate across seeds (:mod:`gym_gridloc_agents.stats`): mean, interquartile mean and a
  bootstrap 95% interval of the mean (fixed bootstrap seed);
* the best configuration is the one with the best (lowest) mean score across its seeds, among the
  configurations whose seeds all finished training (a seed stopped by the pruner or failed
  disqualifies its configuration);
* ``best.zip`` is that configuration's **median seed**: the seed whose score is the median of the
  configuration's seeds (the lower median for an even count, ties to the lower seed) -- not its
  best seed, which would report the luck of the draw as the configuration's quality.

Interrupted sweeps (Ctrl-C, a killed process, a lost node) continue with ``--resume``: Tune
restores its experiment, finished trials are kept, an unfinished trial continues from its latest
training checkpoint (``checkpoint_freq``) or restarts.  A trial whose model is already complete
(finished after Tune last saved its state) is not trained again: its metadata is reported.

Ray and Optuna are imported here only, when a sweep runs (the ``sweep`` extra).
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import itertools
import json
import os
import re
import shutil
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from gym_gridloc_agents.config import ConfigError, load_config, validate_config

#: Tune's experiment directory, under the sweep's output directory.
EXPERIMENT = "tune"
#: Config keys the sweep sets itself (seeds come from ``--seeds``, paths from ``--output``).
OWNED_KEYS = ("seed", "output", "checkpoint_dir", "tensorboard_log")
#: What is compared on ``--resume``: a sweep resumes only with the same arguments.
SPEC_KEYS = ("config", "grid", "seeds", "search", "trials")
#: Per-seed evaluation metrics (those ``train`` reports) and the score.
METRICS = ("score", "mean_steps", "accuracy", "argmax_accuracy")

MEDIAN_RULE = ("the seed whose score is the median of the configuration's seeds (the lower median for an even "
               "count, ties to the lower seed), not the best seed")
BEST_RULE = "the configuration with the best (lowest) mean score across seeds, among those whose seeds all finished"


class SweepError(ValueError):
    """Bad sweep arguments, or a sweep that cannot start or resume (one line, names the problem)."""


# -- --grid ---------------------------------------------------------------------------------------
_NUMBER = re.compile(r"^[-+]?(\d[\d_]*\.?\d*|\.\d+)([eE][-+]?\d+)?$")


def parse_value(text: str) -> Any:
    """One value as YAML reads a scalar (``64`` int, ``0.5`` float, ``true``, ``null``, a word is
    a string, ``[16, 16]`` a list), except that a number in exponent notation without a dot
    (``1e-4``, a string in YAML 1.1) is a float."""
    import yaml

    text = text.strip()
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise SweepError(f"{text!r} is not a YAML value ({' '.join(str(exc).split())})") from None
    if isinstance(value, str) and _NUMBER.match(text):
        value = float(text.replace("_", ""))
    return value


def split_values(text: str) -> list[str]:
    """``"1e-4,3e-4"`` -> ``["1e-4", "3e-4"]``; commas inside ``[...]``/``{...}`` or quotes do not split."""
    parts, depth, quote, cur = [], 0, None, []
    for ch in text:
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append("".join(cur))
            cur = []
            continue
        cur.append(ch)
    parts.append("".join(cur))
    return parts


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
        values = []
        for t in texts:
            try:
                values.append(parse_value(t))
            except SweepError as exc:
                raise SweepError(f"--grid {item!r}: {exc}") from None
        if len({_canonical(v) for v in values}) != len(values):
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


def _canonical(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"))


def configurations(grid: dict[str, list[Any]]) -> list[dict[str, Any]]:
    """Every combination of the grid's values (the first key varies slowest); ``[{}]`` without a grid."""
    keys = list(grid)
    return [dict(zip(keys, combo)) for combo in itertools.product(*(grid[k] for k in keys))]


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
    lossless, parts = True, []
    for k in keys:
        v = overrides[k]
        text = json.dumps(v) if not isinstance(v, str) else v
        if not _SAFE.match(text):
            lossless = False
            text = re.sub(r"[^A-Za-z0-9._+-]+", "_", text).strip("_") or "x"
        parts.append(f"{names[k]}={text}")
    label = "_".join(parts)
    if not lossless or len(label) > 80:
        digest = hashlib.sha1(_canonical({k: overrides[k] for k in keys}).encode()).hexdigest()[:6]
        label = f"{label[:72]}-{digest}"
    return label


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
    :class:`ConfigError` with a one-line message.  (``address`` and ``cpus`` only go into the
    recorded command: a sweep may be resumed elsewhere.)"""
    import yaml

    command = command_line(config, seeds=seeds, grid=grid, search=search, trials=trials, output=output,
                           address=address, cpus=cpus)

    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise SweepError(f"--seeds must be a whole number >= 1, got {seeds!r}")
    if search not in (None, "optuna"):
        raise SweepError(f"--search must be optuna, got {search!r}")
    if search == "optuna" and trials is None:
        raise SweepError("--search optuna needs --trials N (how many configurations Optuna tries, each with every seed)")
    if search is None and trials is not None:
        raise SweepError("--trials N needs --search optuna (a --grid sweep runs every combination)")
    if trials is not None and (isinstance(trials, bool) or not isinstance(trials, int) or trials < 1):
        raise SweepError(f"--trials must be a whole number >= 1, got {trials!r}")
    grid = dict(grid) if isinstance(grid, dict) else parse_grid(grid)
    if search == "optuna" and not grid:
        raise SweepError("--search optuna chooses among --grid values: give at least one --grid KEY=V1,V2,...")
    base = load_config(config)  # a missing or malformed config fails here, naming its file
    raw = yaml.safe_load(Path(config).read_text(encoding="utf-8"))
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
        return [trial_config(spec, o, 0) for o in configurations(spec["grid"])]
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
    if isinstance(seed, int) and not isinstance(seed, bool):
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
        if _canonical(stored.get(key)) != _canonical(spec.get(key)):
            raise SweepError(
                f"--resume: the sweep in {directory} was started with another {key} "
                f"({'config file contents' if key == 'config' else json.dumps(stored.get(key))}); "
                f"resume it with the same arguments: {stored.get('command', '?')}"
            )


# -- one trial (runs in a Ray worker) ---------------------------------------------------------------
@contextlib.contextmanager
def _exclusive(path: Path) -> Iterator[None]:
    """An exclusive lock on ``path`` (two trials of the same configuration and seed -- Optuna can
    propose a configuration twice -- never train into the same files at once)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    with open(path, "a+") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def latest_checkpoint(directory: Path) -> Path | None:
    """The training checkpoint with the most steps in ``directory`` (periodic ``step_N.zip`` or
    ``interrupted_step_N.zip``), among those whose metadata was written (a complete checkpoint)."""
    best, best_steps = None, -1
    for p in Path(directory).glob("*step_*.zip"):
        m = re.fullmatch(r"(?:interrupted_)?step_(\d+)\.zip", p.name)
        if m and p.with_suffix(".json").is_file() and int(m.group(1)) > best_steps:
            best, best_steps = p, int(m.group(1))
    return best


def _comparable(cfg: dict[str, Any]) -> str:
    return _canonical({k: v for k, v in cfg.items() if k not in ("output", "checkpoint_dir", "tensorboard_log")})


def completed_metadata(cfg: dict[str, Any]) -> dict[str, Any] | None:
    """The metadata of this trial's finished model, if it exists and was trained with this config."""
    from gym_gridloc_agents.files import read_metadata

    out = Path(cfg["output"])
    if not out.is_file():
        return None
    try:
        meta = read_metadata(out)
    except ValueError:
        return None
    if meta.get("interrupted") is not False or not isinstance(meta.get("config"), dict):
        return None
    if _comparable(meta["config"]) != _comparable(json.loads(json.dumps(cfg))):
        return None
    return meta


def selected_evaluation(meta: dict[str, Any]) -> dict[str, Any]:
    """The held-out evaluation of the model ``train`` kept (its best evaluation)."""
    evals = meta.get("evaluations") or []
    chosen = [e for e in evals if e.get("num_timesteps") == meta.get("selected_timesteps")]
    if not chosen and not evals:
        raise ValueError("the model's metadata holds no evaluation")
    return dict((chosen or evals)[-1])


def _score(cfg: dict[str, Any], entry: dict[str, Any]) -> float:
    from gym_gridloc_agents.train import _score as score

    return float(score(cfg, entry))


def trial_fn(config: dict[str, Any], spec: dict[str, Any]) -> None:
    """Ray Tune's function trainable: train one configuration with one seed, reporting every
    held-out evaluation (``final: False``) and the kept model's evaluation at the end (``final: True``)."""
    from ray import tune

    from gym_gridloc_agents.train import train

    overrides = {k: json.loads(v) for k, v in (config.get("overrides") or {}).items()}
    index = int(config.get("seed_index", config.get("__trial_index__", 0)))
    cfg = trial_config(spec, overrides, index)
    label = config_label(overrides, list(spec["grid"]))
    ids = {"label": label, "seed": cfg["seed"]}

    def on_evaluation(entry: dict[str, Any]) -> None:
        tune.report({**entry, "score": _score(cfg, entry), "final": False, **ids})

    ckpt_dir = Path(cfg["checkpoint_dir"])
    with _exclusive(ckpt_dir / ".trial.lock"):
        meta = completed_metadata(cfg)
        reused = meta is not None
        if meta is None:
            meta = train(cfg, force=True, resume=latest_checkpoint(ckpt_dir), progress_bar=False, torch_threads=1,
                         on_evaluation=on_evaluation,
                         command=f"{spec['command']}  [trial {tune.get_context().get_trial_id()}: {label} seed {cfg['seed']}]")
    entry = selected_evaluation(meta)
    tune.report({**entry, "num_timesteps": int(meta["num_timesteps"]), "selected_timesteps": entry["num_timesteps"],
                 "score": _score(cfg, entry), "final": True, "reused": reused, "model": cfg["output"], **ids})


def _trial_dirname(trial) -> str:
    return trial.trial_id


# -- running it --------------------------------------------------------------------------------------
def param_space(spec: dict[str, Any]) -> dict[str, Any]:
    """Tune's parameter space: each --grid value as JSON text (any YAML value, also for Optuna's
    categorical choices) and, for a grid sweep, the seed index."""
    from ray import tune

    values = {k: [json.dumps(v) for v in vs] for k, vs in spec["grid"].items()}
    if spec["search"] == "optuna":
        return {"overrides": {k: tune.choice(v) for k, v in values.items()}}
    return {"overrides": {k: tune.grid_search(v) for k, v in values.items()},
            "seed_index": tune.grid_search(list(range(spec["seeds"])))}


def tune_config(spec: dict[str, Any]):
    from ray import tune

    common = {"metric": "score", "mode": "min", "reuse_actors": True, "trial_dirname_creator": _trial_dirname}
    if spec["search"] != "optuna":
        return tune.TuneConfig(num_samples=1, **common)
    from ray.tune.schedulers import ASHAScheduler
    from ray.tune.search import Repeater
    from ray.tune.search.optuna import OptunaSearch

    cfgs = checked_configs(spec)
    longest = max(c["total_timesteps"] for c in cfgs)
    grace = max(1, min(min(c["eval_freq"] for c in cfgs), longest))
    # Repeater: every configuration Optuna proposes runs once per seed (``__trial_index__``), and
    # Optuna is told the mean score of its seeds.  ASHA stops single trials on their evaluations;
    # its max_t is past the last step, else it would stop every trial at its last evaluation,
    # before the final report.
    searcher = Repeater(OptunaSearch(seed=cfgs[0]["seed"]), repeat=spec["seeds"], set_index=True)
    scheduler = ASHAScheduler(time_attr="num_timesteps", max_t=longest + 1, grace_period=grace, reduction_factor=2)
    return tune.TuneConfig(search_alg=searcher, scheduler=scheduler, num_samples=spec["trials"] * spec["seeds"], **common)


def run(spec: dict[str, Any], *, address: str | None = None, cpus: int | None = None, resume: bool = False,
        verbose: int = 1) -> dict[str, Any]:
    """Run (or resume) the sweep; returns the summary (also written under the output directory).

    Ray starts embedded on this machine (``cpus`` CPUs, default all) unless ``address`` names a
    running cluster to join.  Raises :class:`SweepError` before starting when the output directory
    holds another sweep (without ``resume``) or nothing to resume (with it)."""
    from gym_gridloc_agents.files import atomic_write_json, writable_directory

    out = Path(spec["output"])
    exp_dir = out / EXPERIMENT
    stored_path = out / "sweep.json"
    if address is not None and cpus is not None:
        raise SweepError("--cpus sets the CPUs of the Ray started on this machine; with --address the cluster's own CPUs are used")
    if cpus is not None and (isinstance(cpus, bool) or not isinstance(cpus, int) or cpus < 1):
        raise SweepError(f"--cpus must be a whole number >= 1, got {cpus!r}")
    if resume:
        if not stored_path.is_file():
            raise SweepError(f"--resume: {out} holds no sweep (no {stored_path.name}); run the command without --resume")
        try:
            stored = json.loads(stored_path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise SweepError(f"--resume: {stored_path} is not readable ({exc})") from None
        check_resume(spec, stored, out)
    else:
        if stored_path.exists() or exp_dir.exists():
            raise SweepError(f"{out} already holds a sweep: pass --resume to continue it, or choose another --output")
        try:
            writable_directory(out, "sweep output directory")
        except OSError as exc:
            raise SweepError(str(exc)) from None

    import ray
    from ray import tune

    started = False
    if not ray.is_initialized():
        try:
            if address is not None:
                ray.init(address=address, include_dashboard=False, logging_level="WARNING")
            else:
                # address="local": always a Ray of our own, never a cluster someone else started here.
                ray.init(address="local", num_cpus=cpus or os.cpu_count(), include_dashboard=False, logging_level="WARNING")
        except (ConnectionError, ValueError, RuntimeError) as exc:
            where = f"join the Ray cluster at {address}" if address is not None else "start Ray on this machine"
            hint = (" (a cluster with token authentication needs RAY_AUTH_MODE=token and its token: RAY_AUTH_TOKEN or "
                    "~/.ray/auth_token)") if isinstance(exc, ConnectionError) and address is not None else ""
            raise SweepError(f"cannot {where}: {' '.join(str(exc).split())}{hint}") from None
        started = True
    try:
        if not resume:  # written once Ray is up: a sweep that could not start leaves no sweep behind
            atomic_write_json(stored_path, spec)
        trainable = tune.with_resources(tune.with_parameters(trial_fn, spec=spec), {"cpu": 1})
        if resume and tune.Tuner.can_restore(str(exp_dir)):
            tuner = tune.Tuner.restore(str(exp_dir), trainable=trainable, resume_unfinished=True, resume_errored=True)
        else:  # a fresh sweep, or one killed before Tune saved anything (finished models are reused)
            tuner = tune.Tuner(
                trainable, param_space=param_space(spec), tune_config=tune_config(spec),
                run_config=tune.RunConfig(
                    name=EXPERIMENT, storage_path=str(out), verbose=verbose,
                    # A trial that fails (a lost node) is retried, from its training checkpoint.
                    failure_config=tune.FailureConfig(max_failures=2),
                    # Tune saves its experiment state every >= 10 s, but by default copies it to
                    # storage_path at most every 5 minutes: a killed sweep would forget minutes of
                    # finished trials.  Copy it whenever it is saved.
                    sync_config=tune.SyncConfig(sync_period=0),
                ),
            )
        results = tuner.fit()
        records = collect(results, exp_dir, spec["search"])
    finally:
        if started:
            ray.shutdown()
    return summarise(spec, records)


def saved_statuses(exp_dir: Path) -> dict[str, str]:
    """Trial id -> status in Tune's last saved experiment state (what ``Tuner.restore`` resumes
    from): after Ctrl-C the interrupted trials are RUNNING or PENDING there, while in memory Tune
    has already stopped them (TERMINATED, like a trial the pruner stopped).  ``{}`` if unreadable."""
    try:
        latest = max(Path(exp_dir).glob("experiment_state-*.json"), key=lambda p: p.stat().st_mtime)
        out = {}
        for item in json.loads(latest.read_text(encoding="utf-8"))["trial_data"]:
            state = json.loads(item[0]) if isinstance(item[0], str) else item[0]
            out[str(state["trial_id"])] = str(state["status"])
        return out
    except (OSError, ValueError, KeyError, TypeError, IndexError):
        return {}


def _status(result, trial_id: str | None, status: str | None, saved: dict[str, str], search: str | None) -> str:
    if (result.metrics or {}).get("final"):
        return "done"
    if result.error is not None or status == "ERROR":
        return "error"
    status = saved.get(str(trial_id), status)
    if status == "TERMINATED" and search == "optuna":
        return "stopped"  # by the pruner (a grid sweep has none)
    return "unfinished"


def collect(results, exp_dir: Path, search: str | None = None) -> list[dict[str, Any]]:
    """One record per Tune trial: its configuration, seed index, status and last report."""
    trials = list(getattr(getattr(results, "_experiment_analysis", None), "trials", None) or [])
    saved = saved_statuses(exp_dir)
    records = []
    for i, result in enumerate(results):
        trial = trials[i] if i < len(trials) else None
        config = getattr(trial, "config", None) or result.config or {}  # a trial that never ran has no result config
        metrics = {k: v for k, v in (result.metrics or {}).items() if k != "config"}
        trial_id = getattr(trial, "trial_id", None) or metrics.get("trial_id")
        records.append({
            "trial_id": trial_id,
            "overrides": {k: json.loads(v) for k, v in (config.get("overrides") or {}).items()},
            "index": int(config.get("seed_index", config.get("__trial_index__", 0))),
            "status": _status(result, trial_id, getattr(trial, "status", None), saved, search),
            "metrics": metrics,
            "error": None if result.error is None else " ".join(str(result.error).split())[:500],
        })
    return records


# -- results ----------------------------------------------------------------------------------------
_PRIORITY = {"done": 0, "stopped": 1, "error": 2, "unfinished": 3}


def summarise(spec: dict[str, Any], records: list[dict[str, Any]]) -> dict[str, Any]:
    """Group the trials by configuration, aggregate across seeds, pick the best configuration and
    its median seed; write the tables, JSON files and ``best.zip``; return the summary."""
    from gym_gridloc_agents import stats
    from gym_gridloc_agents.files import atomic_path, atomic_write_json, atomic_write_text, read_metadata

    out = Path(spec["output"])
    keys = list(spec["grid"])
    order = configurations(spec["grid"]) if spec["search"] != "optuna" else []
    groups: dict[str, dict[str, Any]] = {}
    for o in order:
        groups[_canonical(o)] = {"overrides": o, "seeds": {}}
    for r in sorted(records, key=lambda r: (_PRIORITY[r["status"]], str(r["trial_id"]))):
        g = groups.setdefault(_canonical(r["overrides"]), {"overrides": r["overrides"], "seeds": {}})
        g["seeds"].setdefault(r["index"], r)  # one record per seed: a finished one first (Optuna may repeat a configuration)
    configs = []
    for g in groups.values():
        overrides = g["overrides"]
        cfg0 = trial_config(spec, overrides, 0)
        label = config_label(overrides, keys)
        rows = []
        for index in range(spec["seeds"]):
            r = g["seeds"].get(index)
            m = (r or {}).get("metrics") or {}
            rows.append({
                "seed": cfg0["seed"] + index, "status": r["status"] if r else "not run",
                **{k: m.get(k) for k in ("score", "mean_steps", "accuracy", "argmax_accuracy")},
                "selected_timesteps": m.get("selected_timesteps"), "num_timesteps": m.get("num_timesteps"),
                "model": m.get("model") if r and r["status"] == "done" else None,
                "trial_id": r["trial_id"] if r else None, "error": r["error"] if r else None,
            })
        done = [row for row in rows if row["status"] == "done"]
        entry: dict[str, Any] = {
            "label": label, "overrides": overrides, "seeds": rows, "complete": len(done) == len(rows),
            "score": "minus the accuracy (fixed-length episodes)" if cfg0["env_kwargs"].get("episode_length")
            else "mean steps to localise (lower is better)",
            "evaluation": f"held-out validation episodes (seeds 2000000+i, {cfg0['eval_episodes']} per evaluation); "
                          "each seed's number is the evaluation of the model train kept (its best evaluation)",
            "aggregate": {k: stats.aggregate([row[k] for row in done]) for k in METRICS} if done else None,
            "median_seed": None, "median_model": None,
        }
        if done:
            med = done[stats.median_index([row["score"] for row in done])]
            entry["median_seed"], entry["median_model"] = med["seed"], med["model"]
        configs.append(entry)
    configs.sort(key=lambda c: (not c["complete"], c["aggregate"]["score"]["mean"] if c["aggregate"] else float("inf")))
    # Trials still to run (an interrupted sweep): no best model until --resume has run them.
    if spec["search"] == "optuna":
        pending = max(0, spec["trials"] * spec["seeds"] - sum(r["status"] in ("done", "stopped", "error") for r in records))
    else:
        pending = sum(r["status"] in ("unfinished", "not run") for c in configs for r in c["seeds"])
    complete = [c for c in configs if c["complete"]]
    best = complete[0] if complete and not pending else None
    summary: dict[str, Any] = {
        "output": str(out), "command": spec["command"], "seeds": spec["seeds"], "grid": spec["grid"],
        "search": spec["search"], "trials": len(records), "pending": pending,
        "statuses": {s: sum(1 for r in records if r["status"] == s) for s in _PRIORITY if any(r["status"] == s for r in records)},
        "best_rule": BEST_RULE, "median_rule": MEDIAN_RULE,
        "best": None, "configurations": configs,
    }
    for c in configs:
        atomic_write_json(out / "results" / f"{c['label']}.json", c)
        atomic_write_text(out / "results" / f"{c['label']}.md", config_table(c) + "\n")
    if best is not None:
        src = Path(best["median_model"])
        best_info = {"label": best["label"], "overrides": best["overrides"], "seed": best["median_seed"],
                     "source": str(src), "aggregate": best["aggregate"], "best_rule": BEST_RULE, "median_rule": MEDIAN_RULE}
        if src.is_file():
            with atomic_path(out / "best.zip") as tmp:
                shutil.copyfile(src, tmp)
            atomic_write_json(out / "best.json", {**read_metadata(src), "sweep": best_info})
            best_info["model"] = str(out / "best.zip")
        else:
            best_info["model"] = None
            best_info["problem"] = (f"{src} is not on this machine: on a cluster, --output must be a directory every "
                                    "node reaches at the same path (a shared file system)")
        summary["best"] = best_info
    atomic_write_json(out / "summary.json", summary)
    atomic_write_text(out / "summary.md", summary_table(summary) + "\n")
    return summary


def _f(x: Any, digits: int = 3) -> str:
    return "-" if x is None else f"{x:.{digits}f}" if isinstance(x, float) else str(x)


def config_table(c: dict[str, Any]) -> str:
    """One configuration: a row per seed, then the mean, IQM and bootstrap 95% interval across seeds."""
    over = ", ".join(f"{k}={json.dumps(v)}" for k, v in c["overrides"].items()) or "the config as it is"
    lines = [f"## {c['label']}", "", f"Overrides: {over}. Score: {c['score']}. {c['evaluation']}.", "",
             "| seed | status | steps trained | model kept at | mean steps | accuracy | argmax accuracy | score |",
             "|---|---|---|---|---|---|---|---|"]
    for r in c["seeds"]:
        lines.append(f"| {r['seed']} | {r['status']} | {_f(r['num_timesteps'])} | {_f(r['selected_timesteps'])} | "
                     f"{_f(r['mean_steps'])} | {_f(r['accuracy'])} | {_f(r['argmax_accuracy'])} | {_f(r['score'])} |")
    a = c["aggregate"]
    if a:
        n = a["score"]["n"]
        for name, key in (("mean", "mean"), ("IQM", "iqm")):
            lines.append(f"| **{name}** ({n} seeds) | | | | {_f(a['mean_steps'][key])} | {_f(a['accuracy'][key])} | "
                         f"{_f(a['argmax_accuracy'][key])} | {_f(a['score'][key])} |")
        ci = {k: "{:.3f}-{:.3f}".format(*a[k]["ci95"]) for k in METRICS}
        lines.append(f"| **95% CI of the mean** (bootstrap) | | | | {ci['mean_steps']} | {ci['accuracy']} | "
                     f"{ci['argmax_accuracy']} | {ci['score']} |")
        lines += ["", f"Median seed: {c['median_seed']} ({c['median_model']})."]
    if not c["complete"]:
        lines += ["", "Not every seed finished training: this configuration cannot be the best one."]
    return "\n".join(lines)


def summary_table(s: dict[str, Any]) -> str:
    """Every configuration, best first: the score's mean, IQM and 95% interval across seeds."""
    lines = ["| configuration | seeds done | score mean | score IQM | score 95% CI | mean steps | accuracy | |",
             "|---|---|---|---|---|---|---|---|"]
    best = (s.get("best") or {}).get("label")
    for c in s["configurations"]:
        a = c["aggregate"]
        done = sum(r["status"] == "done" for r in c["seeds"])
        if a:
            cells = [_f(a["score"]["mean"]), _f(a["score"]["iqm"]), "{:.3f}-{:.3f}".format(*a["score"]["ci95"]),
                     _f(a["mean_steps"]["mean"]), _f(a["accuracy"]["mean"])]
        else:
            cells = ["-"] * 5
        mark = "best" if c["label"] == best else ("" if c["complete"] else "incomplete")
        lines.append(f"| {c['label']} | {done}/{len(c['seeds'])} | " + " | ".join(cells) + f" | {mark} |")
    if s.get("best"):
        b = s["best"]
        where = b["model"] or b.get("problem")
        lines += ["", f"Best configuration: {b['label']}; its median seed {b['seed']}: {where}."]
    elif s.get("pending"):
        lines += ["", f"The sweep is unfinished ({s['pending']} trial(s) to run): continue it with --resume."]
    else:
        lines += ["", "No configuration finished every seed: no best model."]
    return "\n".join(lines)
