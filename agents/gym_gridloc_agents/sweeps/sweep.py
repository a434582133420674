"""``gridloc sweep``: seeds and hyperparameter sweeps of :func:`gym_gridloc_agents.training.train.train` on Ray Tune.

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
as :func:`~gym_gridloc_agents.training.evaluation.score`; a seed's number is the evaluation of the model
``train`` kept (its best evaluation).  These are validation numbers (the same episodes chose the model): compare the
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

* the aggregate across seeds (:mod:`gym_gridloc_agents.evaluation.stats`): mean, interquartile mean and a
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
(finished after Tune last saved its state) is not trained again: its metadata is reported.  A kill
while Tune copied its state to ``--output`` can leave a file cut short: ``--resume`` then keeps
that experiment directory as ``tune.unreadable-N`` and runs Tune again (the same reuse).

Ray and Optuna are imported here only, when a sweep runs (the ``sweep`` extra).
"""

from __future__ import annotations

import json
import os
import re
import sys
from pathlib import Path
from typing import Any

from gym_gridloc.core.validation import check_int
from gym_gridloc_agents.files import atomic_write_json, locked, writable_directory

# What a sweep is (--grid, the trials' configs, --resume's check) is sweep_spec; what its trials
# produced and the report, sweep_results.  Their public names are importable from here too.
from gym_gridloc_agents.sweeps.sweep_results import (
    BEST_RULE,
    MEDIAN_RULE,
    METRICS,
    collect,
    completed_metadata,
    config_table,
    saved_statuses,
    score,
    selected_evaluation,
    summarise,
    summary_table,
)
from gym_gridloc_agents.sweeps.sweep_spec import (
    OWNED_KEYS,
    SPEC_KEYS,
    SweepError,
    check_resume,
    checked_configs,
    command_line,
    config_label,
    configurations,
    default_output,
    parse_grid,
    parse_value,
    prepare,
    set_dotted,
    split_values,
    trial_config,
)

__all__ = [
    "BEST_RULE", "EXPERIMENT", "MEDIAN_RULE", "METRICS", "OWNED_KEYS", "SPEC_KEYS", "SweepError", "check_resume",
    "checked_configs", "collect", "command_line", "completed_metadata", "config_label", "config_table",
    "configurations", "default_output", "latest_checkpoint", "param_space", "parse_grid", "parse_value",
    "prepare", "run", "saved_statuses", "selected_evaluation", "set_dotted", "split_values", "summarise",
    "summary_table", "trial_config", "trial_fn", "tune_config",
]

#: Tune's experiment directory, under the sweep's output directory.
EXPERIMENT = "tune"
#: What a sweep writes in its output directory (a new sweep refuses a directory holding any of them).
SWEEP_OUTPUTS = ("models", "checkpoints", "results", "tensorboard", "summary.md", "summary.json", "best.zip", "best.json")


# -- one trial (runs in a Ray worker) ---------------------------------------------------------------
def latest_checkpoint(directory: Path) -> Path | None:
    """The training checkpoint with the most steps in ``directory`` (periodic ``step_N.zip`` or
    ``interrupted_step_N.zip``), among those whose metadata was written (a complete checkpoint)."""
    steps = {p: int(m.group(1)) for p in Path(directory).glob("*step_*.zip")
             if (m := re.fullmatch(r"(?:interrupted_)?step_(\d+)\.zip", p.name)) and p.with_suffix(".json").is_file()}
    return max(steps, key=steps.get, default=None)  # (the first found of equal steps, as glob lists them)


def trial_fn(config: dict[str, Any], spec: dict[str, Any]) -> None:
    """Ray Tune's function trainable: train one configuration with one seed, reporting every
    held-out evaluation (``final: False``) and the kept model's evaluation at the end (``final: True``)."""
    from gym_gridloc_agents.training.train import train
    from ray import tune

    overrides = {k: json.loads(v) for k, v in (config.get("overrides") or {}).items()}
    index = int(config.get("seed_index", config.get("__trial_index__", 0)))
    cfg = trial_config(spec, overrides, index)
    label = config_label(overrides, list(spec["grid"]))
    ids = {"label": label, "seed": cfg["seed"]}

    def on_evaluation(entry: dict[str, Any]) -> None:
        tune.report({**entry, "score": score(cfg, entry), "final": False, **ids})

    ckpt_dir = Path(cfg["checkpoint_dir"])
    # two trials of the same configuration and seed (Optuna can propose a configuration twice) never
    # train into the same files at once: the second waits, then reuses or resumes the first's work
    # (a lock of its own in the directory, beside the one training takes there)
    with locked(ckpt_dir, what="trial", directory=True, name=".trial.lock"):
        meta = completed_metadata(cfg)
        reused = meta is not None
        if meta is None:
            meta = train(cfg, force=True, resume=latest_checkpoint(ckpt_dir), progress_bar=False, torch_threads=1,
                         on_evaluation=on_evaluation,
                         command=f"{spec['command']}  [trial {tune.get_context().get_trial_id()}: {label} seed {cfg['seed']}]")
    entry = selected_evaluation(meta)
    tune.report({**entry, "num_timesteps": int(meta["num_timesteps"]), "selected_timesteps": entry["num_timesteps"],
                 "score": score(cfg, entry), "final": True, "reused": reused, "model": cfg["output"], **ids})


def _trial_dirname(trial) -> str:
    return trial.trial_id


#: Tune's saved state in its experiment directory: the newest file of each pattern is what
#: ``Tuner.restore`` loads (JSON or a pickle).
_TUNE_STATE = {"tuner.pkl": "pickle", "trainable.pkl": "pickle", "experiment_state-*.json": "json",
               "basic-variant-state-*.json": "pickle", "search_gen_state-*.json": "pickle"}


def unreadable_state(exp_dir: Path) -> list[Path]:
    """The state files in Tune's experiment directory that ``Tuner.restore`` would fail to load.

    Tune writes its state atomically in a staging directory, then copies it to the storage path
    file by file: a sweep killed during that copy leaves a truncated (often empty) file there."""
    import ray.cloudpickle as cloudpickle

    bad = []
    for pattern, kind in _TUNE_STATE.items():
        newest = max(Path(exp_dir).glob(pattern), default=None)  # the one Tune loads
        if newest is None:
            continue
        try:
            with open(newest, "rb") as fh:
                loads = (json.load(fh) if kind == "json" else cloudpickle.load(fh)) is not None
        except Exception:  # noqa: BLE001 - any failure to load is what restore would hit
            loads = False
        if not loads:
            bad.append(newest)
    return bad


def _set_aside(exp_dir: Path) -> Path:
    """Rename Tune's experiment directory to the first free ``<name>.unreadable-N`` beside it."""
    n = 1
    while (aside := exp_dir.with_name(f"{exp_dir.name}.unreadable-{n}")).exists():
        n += 1
    exp_dir.rename(aside)
    return aside


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
    running cluster to join.  ``verbose``: Ray Tune's verbosity (0: nothing of Tune's own on the
    terminal; 1: its trial status tables; ``gridloc sweep`` passes 0 unless ``--verbose``).  Raises :class:`SweepError` before starting when the output directory
    holds another sweep (without ``resume``) or nothing to resume (with it)."""
    out = Path(spec["output"])
    exp_dir = out / EXPERIMENT
    stored_path = out / "sweep.json"
    if address is not None and cpus is not None:
        raise SweepError("--cpus sets the CPUs of the Ray started on this machine; with --address the cluster's own CPUs are used")
    if cpus is not None:
        check_int("--cpus", cpus, what="a whole number >= 1", error=SweepError)
    if resume:
        if not stored_path.is_file():
            raise SweepError(f"--resume: {out} holds no sweep (no {stored_path.name}); run the command without --resume")
        try:
            stored = json.loads(stored_path.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError) as exc:
            raise SweepError(f"--resume: {stored_path} is not readable ({' '.join(str(exc).split())})") from None
        if not isinstance(stored, dict):
            raise SweepError(f"--resume: {stored_path} is not a sweep's record (a JSON object), got a {type(stored).__name__}")
        check_resume(spec, stored, out)
    else:
        if stored_path.exists() or exp_dir.exists():
            raise SweepError(f"{out} already holds a sweep: pass --resume to continue it, or choose another --output")
        # what a sweep writes there: never over another run's files (a best.zip, results/, ...)
        taken = sorted(p.name for p in (out / n for n in SWEEP_OUTPUTS) if p.exists() or p.is_symlink())
        if taken:
            raise SweepError(f"{out} holds {', '.join(taken)}, which the sweep would replace (it holds no sweep: no "
                             "sweep.json); choose another --output, or move them away")
        try:
            writable_directory(out, "sweep output directory")
        except OSError as exc:
            raise SweepError(str(exc)) from None

    import ray
    from ray import tune

    started = False
    if address is not None:  # a cluster: the address checked and a deadline on finding its head (as bench --address)
        from gym_gridloc_agents.cluster import ClusterError, join

        try:
            started = join(address, include_dashboard=False)
        except ClusterError as exc:
            raise SweepError(str(exc)) from None
    elif not ray.is_initialized():
        try:
            # address="local": always a Ray of our own, never a cluster someone else started here.
            ray.init(address="local", num_cpus=cpus or os.cpu_count(), include_dashboard=False, logging_level="WARNING")
        except Exception as exc:  # noqa: BLE001 - Ray raises bare Exception too (a node that timed out starting on a busy machine)
            hint = (" (an overloaded machine starts Ray slowly: try again when it is less busy; nothing was written)"
                    if "timed out" in str(exc) else "")
            raise SweepError(f"cannot start Ray on this machine: {' '.join(str(exc).split())}{hint}") from None
        started = True
    try:
        if not resume:  # written once Ray is up: a sweep that could not start leaves no sweep behind
            atomic_write_json(stored_path, spec)
        trainable = tune.with_resources(tune.with_parameters(trial_fn, spec=spec), {"cpu": 1})
        if resume and exp_dir.exists() and (torn := unreadable_state(exp_dir)):
            aside = _set_aside(exp_dir)
            print(f"--resume: Tune's saved state does not load ({', '.join(p.name for p in torn)}: the sweep was "
                  f"killed while Tune wrote it); the experiment directory is kept as {aside}. The sweep starts Tune "
                  "again: finished models are reused, not trained again, and unfinished trainings continue from "
                  "their checkpoints.", file=sys.stderr)
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
        # verbose 0: Tune's newer output still prints its experiment's box and paths; its classic output, nothing
        classic = {} if verbose or "RAY_AIR_NEW_OUTPUT" in os.environ else {"RAY_AIR_NEW_OUTPUT": "0"}
        os.environ.update(classic)
        try:
            results = tuner.fit()
        finally:
            for key in classic:
                os.environ.pop(key, None)
        records = collect(results, exp_dir, spec["search"])
    finally:
        if started:
            ray.shutdown()
    return summarise(spec, records)
