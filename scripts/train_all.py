"""Retrain every shipped policy from its config (overwrites agents/gym_gridloc_agents/models/*.zip).

    .venv/bin/python scripts/train_all.py            # all configs in configs/
    .venv/bin/python scripts/train_all.py ppo_windymaze recurrent_windymaze

Each config is one `gridloc train configs/<name>.yml --force`; the wall time of each is printed
and recorded in the model's JSON metadata.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from gym_gridloc_agents.cli import main

ROOT = Path(__file__).resolve().parent.parent


def run(names: list[str]) -> int:
    configs = sorted((ROOT / "configs").glob("*.yml"))
    if names:
        known = {c.stem: c for c in configs}
        missing = [n for n in names if n not in known]
        if missing:
            print(f"unknown config(s) {missing}; available: {', '.join(known)}", file=sys.stderr)
            return 2
        configs = [known[n] for n in names]
    for cfg in configs:
        start = time.perf_counter()
        code = main(["train", str(cfg.relative_to(ROOT)), "--force"])
        print(f"{cfg.name}: exit {code}, {time.perf_counter() - start:.0f} s", flush=True)
        if code != 0:
            return code
    return 0


if __name__ == "__main__":
    import os

    os.chdir(ROOT)
    sys.exit(run(sys.argv[1:]))
