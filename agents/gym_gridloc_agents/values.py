"""The one reader of ``KEY=VALUE`` values typed on a command line: ``gridloc bench --env-kwarg``
and ``--option``, ``gridloc bound --env-kwarg``, ``gridloc view --kw`` and ``gridloc sweep
--grid`` (each of its comma-separated values), so that the same text is the same value
everywhere."""

from __future__ import annotations

import re
from typing import Any, Callable, Sequence

_NUMBER = re.compile(r"^[-+]?(\d[\d_]*\.?\d*|\.\d+)([eE][-+]?\d+)?$")


def parse_value(text: str, *, tuples: bool = True) -> Any:
    """One value as YAML reads a scalar (``64`` int, ``0.5`` float, ``true``/``false``,
    ``null``/``~``, a word is a string, ``[16, 16]`` a list), except that a number in exponent
    notation (``1e-4``, a string in YAML 1.1) is a float, ``none`` (any case) is None, an empty
    value is None, and (``tuples``) values separated by commas outside brackets and quotes are a
    tuple (``16,16`` -> ``(16, 16)``).  A text YAML cannot read raises ``ValueError``."""
    import yaml

    text = text.strip()
    if not text:
        return None
    if tuples:
        parts = split_values(text)
        if len(parts) > 1:
            return tuple(parse_value(p, tuples=False) for p in parts if p.strip())
    if text.lower() == "none":
        return None
    if _NUMBER.match(text):
        number = yaml.safe_load(text)
        return float(text.replace("_", "")) if isinstance(number, str) else number
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"{text!r} is not a YAML value ({' '.join(str(exc).split())})") from None


def split_values(text: str) -> list[str]:
    """``"1e-4,3e-4"`` -> ``["1e-4", "3e-4"]``; commas inside ``[...]``/``{...}`` or quotes do not split."""
    parts, depth, quote, cur = [], 0, None, []
    for ch in text:
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append("".join(cur))
            cur = []
            continue
        cur.append(ch)
    parts.append("".join(cur))
    return parts


def key_values(items: Sequence[str] | None, what: str, error: Callable[[str], Exception] = ValueError, *,
               identifiers: bool = False) -> dict[str, Any]:
    """``["slip=1e-4", "size=16,16"]`` -> ``{"slip": 0.0001, "size": (16, 16)}`` (:func:`parse_value`);
    ``error(message)`` names ``what`` and the bad item (``identifiers``: keys must be Python names)."""
    out: dict[str, Any] = {}
    for item in items or ():
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key or (identifiers and not key.isidentifier()):
            raise error(f"{what} {item!r}: expected KEY=VALUE")
        try:
            out[key] = parse_value(value)
        except ValueError as exc:
            raise error(f"{what} {item!r}: {exc}") from None
    return out
