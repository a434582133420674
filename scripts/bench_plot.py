"""Redraw the benchmark figures from a results JSON without rerunning any episode.

    .venv/bin/python scripts/bench_plot.py [results/bench.json]   # writes results/bench_<env>.png
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from agents.bench import plot


def main(path: str = "results/bench.json") -> int:
    src = Path(path)
    if not src.is_file():
        print(f"{src} does not exist; run `gridloc bench --all` first", file=sys.stderr)
        return 2
    rows = json.loads(src.read_text(encoding="utf-8"))
    for env in sorted({r["env"] for r in rows}):
        out = src.parent / f"bench_{env}.png"
        plot([r for r in rows if r["env"] == env], out)
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
