"""Where do the policies drive the robot on RingSensor8x8-v0?  The fraction of steps spent on an
edge cell and in a corner, over the first 40 steps of episodes 0..99 (the README's finding on
entropy-greedy).

    .venv/bin/python scripts/bench_ring_positions.py [--episodes 100] [--steps 40]
"""

from __future__ import annotations

import argparse

import gymnasium as gym

import gym_gridloc
from gym_gridloc_agents.policies import make_policy
from gym_gridloc_agents.evaluation.rollout import rollout


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--policies", default="random,ppo,greedy")
    args = ap.parse_args()
    env = gym_gridloc.HMMBeliefWrapper(gym.make("RingSensor8x8-v0"))
    h, w = env.unwrapped.model.shape
    print("| policy | steps | on an edge | in a corner |\n|---|---:|---:|---:|")
    for name in args.policies.split(","):
        policy = make_policy(name, env.unwrapped.model, env_id="RingSensor8x8-v0")
        edge = corner = n = 0
        for i in range(args.episodes):
            ep = rollout(env, policy, i, keep=True, max_steps=args.steps)
            for info in ep.infos[1:]:  # where the robot is after each step
                r, c = info["position"]
                k = (r in (0, h - 1)) + (c in (0, w - 1))
                edge += k >= 1
                corner += k == 2
                n += 1
        print(f"| {name} | {n} | {edge / n:.3f} | {corner / n:.3f} |")


if __name__ == "__main__":
    main()
