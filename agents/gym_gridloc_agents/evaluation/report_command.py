"""``gridloc report``: the result tables of markdown files, written from the results files.

A markdown file asks for a table with a pair of markers, each a line of its own::

    <!-- gridloc-report:rows:bench -->
    (the table; gridloc report replaces everything between the markers)
    <!-- /gridloc-report:rows:bench -->

The name after ``gridloc-report:`` is a table of :mod:`gym_gridloc_agents.evaluation.tables`
(``KIND:STEM[+STEM...]``, the stems of bench JSON files in the results directory).  ``gridloc
report`` rewrites every marked table of the given files (default: ``README.md`` and
``docs/results.md``; a file without markers is left alone); ``--check`` writes nothing and exits
1 when a file's tables differ from what the results files give (a number edited by hand, a results
file changed since).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path
from typing import Callable

#: The markdown files ``gridloc report`` updates by default.
DEFAULT_FILES = ("README.md", "docs/results.md")
#: An opening marker (a line of its own) and its name; the closing marker of the same name follows it.
OPEN = re.compile(r"^<!-- gridloc-report:(?P<name>[^\s>]+) -->[ \t]*$", re.M)


def markers(text: str) -> list[tuple[str, int, int]]:
    """``(name, start, end)`` of every marked table: ``text[start:end]`` is what lies between the
    opening and the closing marker.  ``ValueError`` for a marker without its closing one, or nested."""
    found, pos = [], 0
    while (m := OPEN.search(text, pos)) is not None:
        name = m.group("name")
        close = f"<!-- /gridloc-report:{name} -->"
        closing = re.compile(rf"^{re.escape(close)}[ \t]*$", re.M).search(text, m.end())
        end = closing.start() if closing is not None else -1
        inner = OPEN.search(text, m.end())
        line = text.count("\n", 0, m.start()) + 1
        if end < 0:
            raise ValueError(f"line {line}: <!-- gridloc-report:{name} --> has no closing {close}")
        if inner is not None and inner.start() < end:
            raise ValueError(f"line {line}: another gridloc-report marker opens before {close}")
        found.append((name, m.end(), end))
        pos = end + len(close)
    return found


def render(text: str, table: Callable[[str], str]) -> str:
    """``text`` with every marked table replaced by ``table(name)`` (one blank-free block between
    the markers, each on its own line)."""
    out, last = [], 0
    for name, start, end in markers(text):
        out += [text[last:start], "\n", table(name).rstrip("\n"), "\n"]
        last = end
    out.append(text[last:])
    return "".join(out)


def report(paths, results: str | Path, *, check: bool = False) -> list[Path]:
    """Rewrite (or, with ``check``, only compare) the marked tables of ``paths``; returns the files
    whose tables were stale.  ``ValueError`` names the file and what is wrong."""
    from gym_gridloc_agents.evaluation.tables import table

    cache: dict[str, str] = {}

    def made(name: str) -> str:
        if name not in cache:
            cache[name] = table(name, results)
        return cache[name]

    stale = []
    for path in map(Path, paths):
        try:
            text = path.read_text(encoding="utf-8")
            new = render(text, made)
        except (OSError, UnicodeDecodeError) as exc:
            raise ValueError(f"{path}: cannot read it ({exc})") from None
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None
        if new != text:
            stale.append(path)
            if not check:
                from gym_gridloc_agents.files import atomic_write_text

                atomic_write_text(path, new)
    return stale


def report_main(args) -> int:
    """``gridloc report [FILE ...] [--results DIR] [--check]``."""
    from gym_gridloc_agents.evaluation.bench_command import fail

    paths = args.files or [p for p in DEFAULT_FILES if Path(p).is_file()]
    try:
        if not paths:
            raise ValueError(f"no markdown file given and none of {', '.join(DEFAULT_FILES)} here")
        if not Path(args.results).is_dir():
            raise ValueError(f"--results {args.results}: no such directory")
        stale = report(paths, args.results, check=args.check)
    except ValueError as exc:
        return fail("report", str(exc))
    for path in paths:
        state = ("stale: its tables differ from the results files" if args.check else "updated") if Path(path) in stale \
            else "up to date"
        print(f"{path}: {state}", file=sys.stderr)
    return 1 if args.check and stale else 0


__all__ = ["DEFAULT_FILES", "markers", "render", "report", "report_main"]
