"""The commands' arguments, the environment they build and pygame, each with one-line errors
(:class:`UsageError`: exit status 2)."""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from gym_gridloc_agents.viewer.style import GRID_PX

RENDER_HINT = "pip install 'gym_gridloc[render]'"
MP4_HINT = "pip install imageio imageio-ffmpeg"


class UsageError(Exception):
    """A bad argument or a missing dependency: one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one clear line instead of usage + error
        raise UsageError(message)


def parse_value(text: str) -> Any:
    """An environment keyword's value (:func:`gym_gridloc_agents.values.parse_value`: ``true``,
    ``none``, ints, floats with ``1e-4``, ``16,16`` a tuple, else the string itself)."""
    from gym_gridloc_agents import values

    try:
        return values.parse_value(text)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def parse_kw(items: Sequence[str] | None) -> dict[str, Any]:
    """``["slip=0.2", "size=16,16"]`` -> ``{"slip": 0.2, "size": (16, 16)}``."""
    from gym_gridloc_agents.values import key_values

    return key_values(items, "--kw (e.g. --kw slip=0.2 --kw size=16,16)", UsageError, identifiers=True)


def _cell(text: str, what: str) -> tuple[int, int]:
    from gym_gridloc.core.validation import is_int

    value = parse_value(text)
    if not (isinstance(value, tuple) and len(value) == 2 and all(is_int(v) for v in value)):
        raise UsageError(f"{what} takes ROW,COL (two integers), got {text!r}")
    return value


def viewer_parser(prog: str, description: str) -> _Parser:
    """The parser of ``prog`` with the arguments both commands take."""
    p = _Parser(prog=prog, description=description)
    p.add_argument("env", help="environment id, e.g. WindyMaze-v0")
    p.add_argument("--kw", action="append", metavar="KEY=VALUE",
                   help="an environment keyword (repeatable): int, float, bool or comma-separated tuple, e.g. size=16,16")
    p.add_argument("--layout", metavar="PATH", help="a map file (the environment's layout keyword)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first episode (default 0; later episodes seed+1, ...)")
    p.add_argument("--steps", type=int, metavar="N", help="at most N steps per episode")
    p.add_argument("--record", metavar="FILE", help="write what was shown as an animated .gif (or .mp4: needs imageio-ffmpeg)")
    p.add_argument("--no-window", action="store_true", help="draw off screen (with --record: for scripts and tests)")
    p.add_argument("--keys", metavar="K1,K2,...", help="scripted key presses (pygame key names: up, left, space, s, ...)")
    p.add_argument("--inspect", metavar="ROW,COL", help="pin the inspector on this cell")
    p.add_argument("--delay", type=int, default=600, metavar="MS",
                   help="milliseconds per step when playing and per frame of a scripted recording (default 600)")
    p.add_argument("--tile", type=int, metavar="PX", help=f"pixels per cell (default: about {GRID_PX} pixels for the grid)")
    return p


def check_args(args: argparse.Namespace) -> None:
    """Check the parsed arguments both commands take (a :class:`UsageError` names the bad one) and
    convert ``--keys`` and ``--inspect``."""
    from gym_gridloc.core.validation import check_int

    if args.steps is not None:
        check_int("--steps", args.steps, error=UsageError)
    if not 0 <= args.seed < 2**63:
        raise UsageError(f"--seed must be in 0..2**63-1, got {args.seed}")
    check_int("--delay", args.delay, what="at least 1 ms", error=UsageError)
    if args.tile is not None and not 2 <= args.tile <= 200:
        raise UsageError(f"--tile must be 2..200 pixels, got {args.tile}")
    if args.record is not None:
        suffix = Path(args.record).suffix.lower()
        if suffix not in (".gif", ".mp4"):
            raise UsageError(f"--record writes .gif or .mp4 files, got {args.record!r}")
        if suffix == ".mp4":
            import importlib.util

            missing = [m for m in ("imageio", "imageio_ffmpeg") if importlib.util.find_spec(m) is None]
            if missing:
                raise UsageError(f"--record .mp4 needs imageio with its ffmpeg plugin (missing: {', '.join(missing)}): "
                                 f"{MP4_HINT}, or record a .gif")
        from gym_gridloc_agents import files

        try:  # a .gif is a figure: an existing file of another kind under that name is refused
            if suffix == ".gif":
                files.check_outputs([(args.record, files.FIGURE, "recording")], inputs=[getattr(args, "layout", None)])
            else:
                files.writable_file(args.record, "recording")
        except files.OutputError as exc:
            raise UsageError(str(exc)) from None
    args.keys = None if args.keys is None else [k.strip().lower() for k in args.keys.split(",") if k.strip()]
    args.inspect = None if args.inspect is None else _cell(args.inspect, "--inspect")


def env_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """The environment keywords of ``--kw`` and ``--layout``."""
    kwargs = parse_kw(args.kw)
    if args.layout is not None:
        if "layout" in kwargs:
            raise UsageError("give the layout once: --layout PATH or --kw layout=PATH")
        if not Path(args.layout).is_file():
            raise UsageError(f"--layout: {args.layout} is not a file")
        kwargs["layout"] = args.layout
    return kwargs


def build_env(env_id: str, kwargs: dict[str, Any]):
    """``gym.make(env_id, **kwargs)`` for a gym_gridloc environment, or a one-line :class:`UsageError`."""
    import gymnasium as gym

    import gym_gridloc
    from gym_gridloc.core.errors import GridLocError
    from gym_gridloc.envs.base import GridLocEnv

    if env_id not in gym.registry:
        raise UsageError(f"{env_id!r} is not a registered environment (gym_gridloc's: {', '.join(gym_gridloc.ENV_IDS)})")
    try:
        env = gym.make(env_id, **kwargs)
    except (TypeError, ValueError, OSError, GridLocError, gym.error.Error) as exc:
        detail = " ".join(str(exc).split())
        raise UsageError(f"{env_id} does not build with {kwargs}: {detail}") from None
    if not isinstance(env.unwrapped, GridLocEnv):
        env.close()
        raise UsageError(f"{env_id} is not a gym_gridloc environment (allowed: {', '.join(gym_gridloc.ENV_IDS)})")
    return env


def import_pygame(command: str):
    """pygame (pygame-ce), or a :class:`UsageError` naming the ``render`` extra."""
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    try:
        import pygame
    except ImportError:
        raise UsageError(f"{command} needs pygame-ce (the 'render' extra): {RENDER_HINT}") from None
    pygame.font.init()
    return pygame
