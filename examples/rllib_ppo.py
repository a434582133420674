"""RLlib PPO on a gym_gridloc environment (an example for RLlib users; not run in CI).

The repository's own training (``gridloc train`` / ``gridloc sweep``) uses stable-baselines3.
This script shows the same environment in RLlib: the environment is registered with
``ray.tune.registry.register_env`` and wrapped in ``HMMBeliefWrapper(flatten=True)``, so the policy
sees the reading and the exact position belief as one flat vector (an MLP input).  The reward is
-1 per step until the belief localises the robot, so ``episode_len_mean`` is the mean number of
steps to localise (compare with ``gridloc bench``'s ``mean_steps``).

Install
-------
In the environment ``scripts/setup.sh`` made, everything is there (the ``rllib`` extra: Ray Tune
and what RLlib imports besides, dm-tree among them).  Elsewhere::

    pip install torch==2.13.0 && pip install -e ".[rl,rllib]"    # torch first and pinned (see the README)

The ``rllib`` extra leaves out ``ray[rllib]``'s exact gymnasium pin (``gymnasium==1.2.2`` for Ray
2.60.0), which would downgrade gymnasium; RLlib 2.60 ran this example with gymnasium 1.4.0.  For
the exact pin, use an environment of its own::

    python -m venv .venv-rllib && . .venv-rllib/bin/activate
    pip install torch==2.13.0                  # first and pinned, as for the rl extra (see the README)
    pip install "ray[rllib]==2.60.0" .         # gym_gridloc from this repository; gymnasium resolves to 1.2.2

(For another Ray version, read its pin: ``pip download "ray[rllib]==X" --no-deps`` and look for
``gymnasium`` in the wheel's METADATA, or ``pip install --dry-run --report - "ray[rllib]==X"``.)

Run
---
    python examples/rllib_ppo.py [--env ColourGrid-v0] [--iterations 20] [--env-runners 1] [--checkpoint DIR]

(``--checkpoint`` is an RLlib checkpoint, restored with ``Algorithm.from_checkpoint(DIR)``; the
benchmark's ``ppo`` policy reads stable-baselines3 models only.)  RLlib writes its result logs to
``~/ray_results/<date>...`` and Ray its own to ``/tmp/ray``.

Tried with ray 2.60.0, gymnasium 1.2.2 and torch 2.13.0 (CPU): 3 iterations of 1,000 steps on
ColourGrid-v0 ran in about a minute on a busy 2-core machine; the mean episode length went from
5.3 to 4.9 steps (a training-time number of the stochastic policy, not a benchmark result).  With
gymnasium 1.4.0 (the ``rllib`` extra), ``--iterations 1 --batch 500`` runs in about 30 s.

On a Ray cluster, start the script with ``RAY_ADDRESS=HEAD_IP:6379`` set (``ray.init()`` joins it).
"""

from __future__ import annotations

import argparse
import importlib
import sys

#: What the example imports beyond gym_gridloc (module: what to install), all in the rl and rllib extras.
NEEDS = {"ray": "ray[tune]", "tree": "dm-tree", "torch": "torch"}
INSTALL = "pip install torch==2.13.0 && pip install -e '.[rl,rllib]'"


def missing_modules() -> list[str]:
    """What to install for the modules RLlib needs that are missing (empty: nothing)."""
    missing = []
    for module, dist in NEEDS.items():
        try:
            importlib.import_module(module)
        except ImportError:
            missing.append(dist)
    return missing


def make_env(env_config: dict):
    """RLlib's environment creator: ``gym.make(env_id, **env_kwargs)`` behind the flat belief
    wrapper.  It runs in every RLlib EnvRunner process, so gym_gridloc is imported here (importing
    it registers the environments)."""
    import gymnasium as gym

    import gym_gridloc

    env = gym.make(env_config.get("env_id", "ColourGrid-v0"), **dict(env_config.get("env_kwargs", {})))
    return gym_gridloc.HMMBeliefWrapper(env, flatten=True)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--env", default="ColourGrid-v0", help="a gym_gridloc environment id")
    p.add_argument("--iterations", type=int, default=20, help="PPO training iterations")
    p.add_argument("--env-runners", type=int, default=1, help="RLlib EnvRunner actors (sampling processes)")
    p.add_argument("--batch", type=int, default=2000, help="environment steps per iteration")
    p.add_argument("--checkpoint", metavar="DIR", help="save the trained algorithm here (algo.save_to_path)")
    args = p.parse_args(argv)
    missing = missing_modules()
    if missing:
        print(f"examples/rllib_ppo.py needs {', '.join(missing)}: {INSTALL}", file=sys.stderr)
        raise SystemExit(2)

    import ray
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig
    from ray.tune.registry import register_env

    ray.init(include_dashboard=False)
    register_env("gridloc", make_env)
    config = (
        PPOConfig()
        .environment("gridloc", env_config={"env_id": args.env, "env_kwargs": {}})
        .env_runners(num_env_runners=args.env_runners, num_envs_per_env_runner=4)
        .training(lr=3e-4, gamma=0.99, lambda_=0.95, train_batch_size_per_learner=args.batch, minibatch_size=250,
                  num_epochs=10, entropy_coeff=0.0)
        .rl_module(model_config=DefaultModelConfig(fcnet_hiddens=[256, 256], fcnet_activation="tanh"))
    )
    algo = config.build_algo()
    try:
        for i in range(args.iterations):
            result = algo.train()
            runners = result.get("env_runners", {})
            print(f"iteration {i + 1}: {runners.get('num_env_steps_sampled_lifetime', '?')} steps, "
                  f"mean episode length (steps to localise or the limit) {runners.get('episode_len_mean', float('nan')):.2f}",
                  flush=True)
        if args.checkpoint:
            import os

            print(f"saved {algo.save_to_path(os.path.abspath(args.checkpoint))}")
    finally:
        algo.stop()
        ray.shutdown()


if __name__ == "__main__":
    main()
