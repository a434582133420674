"""Loading trained models: the algorithms a config may name (:data:`ALGOS`), how a model was made
(:func:`model_method`), :func:`load_model` with its checks (algorithm, environment and its keyword
arguments, observation space), and the model files of ``--ppo-model`` (:func:`expand_models`).

Model zip files are pickles: load only files from a trusted source.
"""

from __future__ import annotations

import glob
import json
import importlib
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from gym_gridloc_agents.files import read_metadata
from gym_gridloc_agents.registry import LEARNED_NAMES

#: The algorithms a config may name: ``algo`` -> (module, class).  Another stable-baselines3
#: algorithm that acts on the belief observation trains from the same config format once it has a
#: line here and its policy classes in :data:`gym_gridloc_agents.training.config.POLICIES`.
_ALGO_CLASSES = {"ppo": ("stable_baselines3", "PPO"), "recurrent_ppo": ("sb3_contrib", "RecurrentPPO"),
                 "a2c": ("stable_baselines3", "A2C"), "dqn": ("stable_baselines3", "DQN")}
ALGOS = tuple(_ALGO_CLASSES)


def algo_class(algo: str):
    """The stable-baselines3 (or sb3-contrib) class of ``algo``."""
    if algo not in ALGOS:
        raise ValueError(f"algo must be one of {', '.join(ALGOS)}, got {algo!r}")
    module, name = _ALGO_CLASSES[algo]
    return getattr(importlib.import_module(module), name)


def load_model(path: str | Path, *, algo: str = "ppo", env_id: str | None = None, env_kwargs: dict | None = None,
               observation_space=None, env=None, custom_objects: dict | None = None):
    """Load an sb3 model, refusing one trained for another algorithm, environment (id or keyword
    arguments) or observation space.  Returns ``(model, metadata)``.  ``custom_objects``: saved
    attributes replaced on loading, as sb3's ``load`` takes them (e.g. other update settings).
    Zip files are pickles: trusted sources only."""
    path = Path(path)
    if not path.is_file():
        hint = (" (train it with `gridloc train configs/...`, or pass --ppo-model PATH)"
                if path.parent.name == "models" else "")
        raise FileNotFoundError(f"model file {str(path)!r} does not exist{hint}")
    meta = read_metadata(path)
    if meta.get("algo") not in (None, algo):
        raise ValueError(f"{path} holds a {meta['algo']} model, not {algo}")
    env_id = plain_id(env_id)
    if env_id is not None and plain_id(meta.get("env_id")) not in (None, env_id):
        raise ValueError(f"{path} was trained for {meta['env_id']}, not {env_id}; train one for {env_id} or pick its model")
    if (env_kwargs is not None and "env_kwargs" in meta
            and model_kwargs(meta.get("env_id") or env_id, meta["env_kwargs"]) != model_kwargs(meta.get("env_id") or env_id, env_kwargs)):
        raise ValueError(
            f"{path} was trained for {meta.get('env_id', 'its environment')} with env_kwargs {meta['env_kwargs']}, "
            f"not {dict(env_kwargs)}: pass the same keyword arguments, or a model trained for these "
            f"({', '.join(EPISODE_KWARGS)} may differ)"
        )
    try:
        model = algo_class(algo).load(path, env=env, device="cpu", custom_objects=custom_objects)
    except (ValueError, KeyError) as exc:
        if env is not None and "space" in str(exc).lower():
            raise ValueError(f"{path} does not fit this environment: {exc}") from None
        raise ValueError(f"{path} is not a loadable {algo} model: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - a broken or foreign zip
        hint = ""
        if isinstance(exc, ModuleNotFoundError) and "numpy._core" in str(exc):
            hint = (f" (it was saved with numpy 2, and this Python has numpy {np.__version__}: "
                    "pip install 'numpy>=2', as the rl extra asks)")
        raise ValueError(f"{path} is not a loadable {algo} model: {type(exc).__name__}: {exc}{hint}") from None
    if observation_space is not None and model.observation_space != observation_space:
        where = f" (trained for {meta['env_id']})" if meta.get("env_id") else ""
        raise ValueError(
            f"{path}{where} expects observations {model.observation_space}, but this environment gives "
            f"{observation_space}: it was trained for another environment or observation space"
        )
    return model, meta


#: How a model was made (its metadata's ``method``): the names of the learned policies.
METHODS = LEARNED_NAMES


def model_method(meta: dict[str, Any]) -> str:
    """How the model a metadata dict describes was made: ``"recurrent"`` (RecurrentPPO on the
    readings), ``"distilled"`` (a planner imitated: its training had a ``pretrain`` warm start),
    ``"ppo"`` (PPO from the environment's reward alone) or another algorithm's name (``"a2c"``,
    ``"dqn"``: from the reward alone).  ``method`` when the metadata says
    it; older metadata is read from its ``algo`` and ``pretrain``."""
    if meta.get("method") in METHODS:
        return meta["method"]
    if meta.get("algo") == "recurrent_ppo":
        return "recurrent"
    if meta.get("pretrain") or (meta.get("config") or {}).get("pretrain"):
        return "distilled"
    algo = meta.get("algo")
    return algo if algo in ALGOS and algo != "ppo" else "ppo"  # another algorithm of the table: its name


#: Environment keywords that shape episodes, not the model a policy acts on: they may differ
#: between training and use (e.g. a policy trained for 15 steps, benchmarked at 30, or trained on
#: Kruskal's mazes and tested on Eller's).
EPISODE_KWARGS = ("episode_length", "reward", "render_mode", "new_map_each_reset", "generator", "reject_symmetric")


def expand_models(items: Sequence[str | Path], flag: str = "--ppo-model") -> list[Path]:
    """The model files of ``--ppo-model`` (or ``flag``): a file as given, a directory's ``*.zip`` (not its
    subdirectories), a glob pattern's matches, each sorted by name; ``ValueError`` for a directory
    or pattern without a model, or a file given twice."""
    models: list[Path] = []
    for item in items:
        path = Path(item)
        if path.is_dir():
            found, problem = sorted(path.glob("*.zip")), "the directory holds no .zip model"
        elif glob.has_magic(str(item)):
            found, problem = sorted(Path(p) for p in glob.glob(str(item)) if Path(p).is_file()), "no file matches"
        else:
            found = [path]
        if not found:
            raise ValueError(f"{flag} {item}: {problem}")
        models += found
    seen = set()
    for m in models:
        if m.resolve() in seen:
            raise ValueError(f"{flag}: {m} is given twice (each model is one seed)")
        seen.add(m.resolve())
    if len(models) > 1:  # several models are several seeds: not one training's checkpoints
        import re

        ckpts = [m for m in models if re.fullmatch(r"(interrupted_)?step_\d+\.zip|best(-before-.*)?\.zip", m.name)]
        if ckpts:
            raise ValueError(f"{flag}: {ckpts[0]} is a training checkpoint (step_N.zip, best.zip): several models "
                             f"are one per seed, and {ckpts[0].parent} looks like one training's checkpoint directory; "
                             "pass one model file")
        seeds: dict[Any, Path] = {}
        for m in models:
            seed = read_metadata(m).get("seed")
            if seed is not None and seed in seeds:
                raise ValueError(f"{flag}: {seeds[seed]} and {m} were trained with the same seed {seed}: "
                                 "several models are one per seed")
            seeds[seed if seed is not None else object()] = m
    return models


def plain_id(env_id: str | None) -> str | None:
    """``env_id`` without gym_gridloc's namespace (``gym_gridloc/WindyMaze-v0`` is ``WindyMaze-v0``,
    the same environment): how shipped models and their metadata name it."""
    prefix = "gym_gridloc/"
    return env_id[len(prefix):] if isinstance(env_id, str) and env_id.startswith(prefix) else env_id


def model_kwargs(env_id: str | None, kwargs: dict) -> str:
    """The keyword arguments that define ``env_id``'s model, in one comparable form: the
    environment's defaults filled in (so ``{}`` and ``{"size": 7}`` are the same DepthMaze-v0),
    :data:`EPISODE_KWARGS` left out."""
    import gymnasium as gym

    import gym_gridloc  # noqa: F401 - registers the environments
    from gym_gridloc_agents.envs import default_kwargs

    defaults = default_kwargs(env_id) if env_id in gym.registry else {}
    kwargs = {**defaults, **dict(kwargs)}
    # tuples and lists alike (JSON), keys sorted
    return json.dumps({k: v for k, v in kwargs.items() if k not in EPISODE_KWARGS}, sort_keys=True, default=str)
