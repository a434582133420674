"""``gridloc play`` and ``gridloc view``: parse, build the app, show it, record it."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gym_gridloc.wrappers import HMMBeliefWrapper
from gym_gridloc_agents.viewer.app import App
from gym_gridloc_agents.viewer.apps import PlayApp, ViewApp
from gym_gridloc_agents.viewer.args import UsageError, build_env, check_args, env_kwargs, import_pygame, viewer_parser
from gym_gridloc_agents.viewer.loop import Loop

def play_app(argv: Sequence[str]) -> tuple[PlayApp, argparse.Namespace]:
    """Parse ``gridloc play``'s arguments and build the app (raises :class:`UsageError`)."""
    parser = viewer_parser("gridloc play", "drive the robot with the arrow keys and watch the exact belief")
    args = parser.parse_args(list(argv))
    check_args(args)
    pg = import_pygame("gridloc play")
    env = HMMBeliefWrapper(build_env(args.env, env_kwargs(args)))  # its filter: the headings' belief
    app = PlayApp(pg, env, args.env, seed=args.seed, max_steps=args.steps, tile=args.tile, inspect=args.inspect)
    _check_inspect(app, args)
    return app, args


def view_app(argv: Sequence[str]) -> tuple[ViewApp, argparse.Namespace]:
    """Parse ``gridloc view``'s arguments, run the episode and build the app (raises :class:`UsageError`)."""
    from gym_gridloc_agents.policies import make_policy
    from gym_gridloc_agents.registry import LEARNED_NAMES, POLICY_NAMES, either, names_by_kind

    p = viewer_parser("gridloc view", "step through an episode of a policy: belief, smoothing, Viterbi, inspector")
    p.add_argument("--policy", default="greedy", choices=POLICY_NAMES, metavar="NAME",
                   help=f"the policy (default greedy), of the {names_by_kind()}")
    p.add_argument("--ppo-model", metavar="PATH",
                   help=f"the model file of --policy {either(LEARNED_NAMES)} (default: the shipped one for ENV)")
    p.add_argument("--smooth", action="store_true", help="start with the smoothed belief shown (key s)")
    p.add_argument("--viterbi", action="store_true", help="start with the Viterbi path shown (key v)")
    args = p.parse_args(list(argv))
    check_args(args)
    if args.ppo_model is not None and args.policy not in LEARNED_NAMES:
        raise UsageError(f"--ppo-model is the model of --policy {either(LEARNED_NAMES)}, not of --policy {args.policy}")
    if args.ppo_model is not None and not Path(args.ppo_model).is_file():
        raise UsageError(f"--ppo-model: {args.ppo_model} is not a file")
    kwargs = env_kwargs(args)
    pg = import_pygame("gridloc view")
    env = HMMBeliefWrapper(build_env(args.env, kwargs))
    try:
        policy = make_policy(args.policy, env.unwrapped.model, env_id=args.env, env_kwargs=kwargs, seed=args.seed,
                             path=args.ppo_model, pose=env.unwrapped.referee_pose)
    except (ValueError, FileNotFoundError, TypeError, ImportError) as exc:
        raise UsageError(f"--policy {args.policy}: {' '.join(str(exc).split())}") from None
    app = ViewApp(pg, env, args.env, policy, args.policy, seed=args.seed, max_steps=args.steps, delay_ms=args.delay,
                  smooth=args.smooth, viterbi=args.viterbi, tile=args.tile, inspect=args.inspect)
    _check_inspect(app, args)
    return app, args


def _check_inspect(app: App, args) -> None:
    if args.inspect is not None:
        h, w = app.shown().model.shape
        if not (0 <= args.inspect[0] < h and 0 <= args.inspect[1] < w):
            raise UsageError(f"--inspect {args.inspect[0]},{args.inspect[1]} is outside the {h}x{w} map")


def known_keys(app: App) -> set[str]:
    """The key names ``app`` acts on (``--keys`` takes only these)."""
    common = {"escape", "q", "h", "c"}
    if isinstance(app, ViewApp):
        return common | {"right", "left", "home", "end", "space", "s", "v", "r", "n"}
    return common | set(app.keymap) | {"r"}


def _run(command: str, build, argv: Sequence[str] | None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        app, args = build(argv)
        keys, generated = args.keys, args.keys is None
        if keys is not None and (unknown := [k for k in keys if k not in known_keys(app)]):
            raise UsageError(f"--keys: unknown key(s) {', '.join(map(repr, unknown))} "
                             f"(this command's keys: {', '.join(sorted(known_keys(app)))})")
        if keys is None and args.no_window:
            if isinstance(app, ViewApp):
                keys = ["right"] * app.last
            elif args.steps is not None:  # random arrow keys (digits only where there are no arrows)
                names = [k for k in app.keymap if not k.isdigit()] or list(app.keymap)
                keys = [names[int(i)] for i in np.random.default_rng(args.seed).integers(len(names), size=args.steps)]
            else:
                raise UsageError("--no-window needs --keys K1,K2,... or --steps N (random arrow keys)")
        loop = Loop(app, window=not args.no_window, record=args.record)
    except UsageError as exc:
        print(f"{command}: error: {exc}", file=sys.stderr)
        return 2
    except SystemExit as exc:  # --help
        return int(exc.code or 0)
    end = None
    try:
        if keys is not None:
            loop.script(keys, args.delay / 1000.0, until_done=generated and isinstance(app, PlayApp))
            end = loop.end
        else:
            loop.run()
    except KeyboardInterrupt:
        pass
    finally:
        loop.close()
        app.env.close()
    done = loop.finish(end)
    if done:
        print(done)
    return 0


def play_main(argv: Sequence[str] | None = None) -> int:
    """``gridloc play ENV [options]``; returns the exit status (2: bad arguments)."""
    return _run("gridloc play", play_app, argv)


def view_main(argv: Sequence[str] | None = None) -> int:
    """``gridloc view ENV [options]``; returns the exit status (2: bad arguments)."""
    return _run("gridloc view", view_app, argv)
