"""Environment steps per second with exact beliefs: the native vector env vs SyncVectorEnv.

For N = 1, 16, 64, 256 environments, random actions, beliefs in the observations:

* ``native``: ``gym.make_vec(ENV, num_envs=N, vectorization_mode="vector_entry_point", belief="exact")``;
* ``sync``: ``gym.make_vec(ENV, num_envs=N, vectorization_mode="sync", wrappers=[HMMBeliefWrapper])``
  (Gymnasium's SyncVectorEnv over single wrapped environments).

Then PPO (stable-baselines3, ``MultiInputPolicy``) training throughput in timesteps per second
with each: the native env through :class:`gym_gridloc_agents.envs.SB3VecEnv`, and SB3's own
``DummyVecEnv`` over ``HMMBeliefWrapper`` environments.  All ratios come from this one run.

    .venv/bin/python scripts/bench_vector.py
    .venv/bin/python scripts/bench_vector.py --env WindyMaze-v0 --ppo-envs 8 64 --ppo-steps 8192
"""

from __future__ import annotations

import argparse
import sys
import time

import gymnasium as gym
import numpy as np
from tqdm import tqdm

import gym_gridloc


def steps_per_second(env, n: int, min_seconds: float, seed: int = 0) -> float:
    """Environment steps per second (N per vector step), random actions, best of 3 runs."""
    rng = np.random.default_rng(seed)
    actions = rng.integers(0, env.single_action_space.n, size=(4096, n))
    env.reset(seed=seed)
    for t in range(5):  # warm up (compilation, caches)
        env.step(actions[t])
    best = 0.0
    for _ in range(3):
        steps, t0 = 0, time.perf_counter()
        while True:
            env.step(actions[steps % len(actions)])
            steps += 1
            elapsed = time.perf_counter() - t0
            if elapsed >= min_seconds and steps >= 5:
                break
        best = max(best, steps * n / elapsed)
    return best


def ppo_throughput(venv, timesteps: int, seed: int) -> float:
    import torch
    from stable_baselines3 import PPO

    torch.manual_seed(seed)
    n_envs = venv.num_envs
    model = PPO("MultiInputPolicy", venv, n_steps=max(8, 1024 // n_envs), batch_size=256, n_epochs=2,
                seed=seed, device="cpu", verbose=0)
    model.learn(n_envs * model.n_steps)  # warm-up rollout and update
    t0 = time.perf_counter()
    model.learn(timesteps, reset_num_timesteps=True)
    return model.num_timesteps / (time.perf_counter() - t0)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--env", default="ColourGrid-v0", choices=gym_gridloc.ENV_IDS, help="environment id")
    p.add_argument("--num-envs", type=int, nargs="+", default=[1, 16, 64, 256], help="values of N")
    p.add_argument("--seconds", type=float, default=0.5, help="minimum seconds per timing")
    p.add_argument("--ppo-envs", type=int, nargs="+", default=[8, 64], help="values of N for the PPO comparison (0: skip PPO)")
    p.add_argument("--ppo-steps", type=int, default=16384, help="PPO timesteps per timing")
    args = p.parse_args(argv)
    for n in args.num_envs:
        if n < 1:
            p.error(f"--num-envs: each N must be at least 1, got {n}")
    ppo_envs = [n for n in args.ppo_envs if n != 0]
    if any(n < 0 for n in ppo_envs):
        p.error(f"--ppo-envs: each N must be at least 1 (or 0: skip PPO), got {args.ppo_envs}")

    rows = []
    for n in tqdm(args.num_envs, desc="N", file=sys.stderr):
        native = gym.make_vec(args.env, num_envs=n, vectorization_mode="vector_entry_point", belief="exact")
        sync = gym.make_vec(args.env, num_envs=n, vectorization_mode="sync", wrappers=[gym_gridloc.HMMBeliefWrapper])
        rows.append((n, steps_per_second(native, n, args.seconds), steps_per_second(sync, n, args.seconds)))
        native.close()
        sync.close()

    print(f"{args.env}, exact beliefs in the observations, random actions: environment steps per second")
    print(f"{'N':>5} | {'native':>12} {'sync':>12} | {'native / sync':>13}")
    for n, a, b in rows:
        print(f"{n:>5} | {a:>10.0f}/s {b:>10.0f}/s | {a / b:>12.1f}x")

    if ppo_envs:
        import torch
        from stable_baselines3.common.env_util import make_vec_env
        from stable_baselines3.common.vec_env import DummyVecEnv

        from gym_gridloc_agents.envs import SB3VecEnv

        torch.set_num_threads(1)
        results = []
        with tqdm(total=2 * len(ppo_envs), desc="PPO", file=sys.stderr) as bar:
            for n in ppo_envs:
                fast = ppo_throughput(SB3VecEnv.make(args.env, n), args.ppo_steps, seed=0)
                bar.update()
                slow = ppo_throughput(make_vec_env(lambda: gym_gridloc.HMMBeliefWrapper(gym.make(args.env)), n_envs=n,
                                                   vec_env_cls=DummyVecEnv), args.ppo_steps, seed=0)
                bar.update()
                results.append((n, fast, slow))
        print(f"\nPPO (stable-baselines3, MultiInputPolicy, n_steps 1024 / N, batch 256, 2 epochs, torch 1 thread): "
              "training timesteps per second")
        print(f"{'N':>5} | {'native (SB3VecEnv)':>18} {'DummyVecEnv':>12} | {'native / Dummy':>14}")
        for n, fast, slow in results:
            print(f"{n:>5} | {fast:>16.0f}/s {slow:>10.0f}/s | {fast / slow:>13.2f}x")


if __name__ == "__main__":
    main()
