"""Copy a trained model with its network weights stored as float16 (half the file).

stable-baselines3 loads such a file unchanged: ``load_state_dict`` copies the float16 tensors
into the policy's float32 parameters, so the model acts in float32 on weights rounded to float16.
The rounding can change a decision, so benchmark the copy, not the original, before quoting it.
The metadata beside the model is copied with ``"weights": "float16"`` added.

    .venv/bin/python scripts/half_precision.py runs/model.zip agents/gym_gridloc_agents/models/WindyMaze-v0-size9.zip
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import zipfile
from pathlib import Path

import torch

from gym_gridloc_agents.files import atomic_path, atomic_write_json, read_metadata


def half_precision(source: Path, target: Path) -> tuple[int, int]:
    """Write ``target``: ``source`` with ``policy.pth``'s floating-point tensors as float16; returns
    both file sizes in bytes."""
    with zipfile.ZipFile(source) as zin:
        names = zin.namelist()
        if "policy.pth" not in names:
            raise ValueError(f"{source} is not a stable-baselines3 model (no policy.pth inside)")
        with atomic_path(target) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zout:
            for name in names:
                data = zin.read(name)
                if name == "policy.pth":
                    state = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
                    halves: dict[tuple, torch.Tensor] = {}  # tensors shared under two names stay shared
                    for k, v in state.items():
                        if v.is_floating_point():
                            key = (v.data_ptr(), v.shape, v.stride())
                            state[k] = halves.setdefault(key, v.half())
                    buf = io.BytesIO()
                    torch.save(state, buf)
                    data = buf.getvalue()
                zout.writestr(name, data)
    meta = read_metadata(source)
    if meta:
        atomic_write_json(target.with_suffix(".json"), {**meta, "weights": "float16", "half_precision_of": str(source)})
    return source.stat().st_size, target.stat().st_size


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", type=Path, help="a trained model (.zip)")
    parser.add_argument("target", type=Path, help="where to write the float16 copy (.zip)")
    args = parser.parse_args(argv)
    try:
        before, after = half_precision(args.source, args.target)
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        print(f"half_precision: {exc}", file=sys.stderr)
        return 1
    print(json.dumps({"source": str(args.source), "bytes": before, "target": str(args.target), "target_bytes": after}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
