"""Checks for parameters where they enter: each error names the parameter, the value and what is
allowed.  The one place for integer checks: :func:`is_int` and :func:`check_int` for one value,
:func:`whole_numbers` for an array (``tests/test_one_owner.py`` holds other modules to them);
:func:`unknown_names` writes the names a check refuses, each with the closest allowed one."""

from __future__ import annotations

import difflib
import math
import numbers
from typing import Any, Sequence

import numpy as np


def check_probability(name: str, value: Any) -> float:
    """A real number in [0, 1]."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a probability (a number in [0, 1]), got {value!r}")
    v = float(value)
    if not math.isfinite(v) or not 0.0 <= v <= 1.0:
        raise ValueError(f"{name} must be a probability in [0, 1], got {value!r}")
    return v


def check_threshold(name: str, value: Any) -> float:
    """A real number in (0, 1]."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a number in (0, 1], got {value!r}")
    v = float(value)
    if not math.isfinite(v) or not 0.0 < v <= 1.0:
        raise ValueError(f"{name} must be in (0, 1], got {value!r}")
    return v


def is_int(value: Any) -> bool:
    """``value`` is an integer: Python's or numpy's, not a bool."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def check_int(name: str, value: Any, minimum: int = 1, maximum: int | None = None, *, whole: bool = False,
              what: str | None = None, error: type[Exception] | None = None) -> int:
    """An integer (:func:`is_int`) in ``minimum..maximum`` (no upper bound with ``maximum=None``),
    as an ``int``; else a TypeError (another type) or a ValueError (another value) naming ``name``.

    ``whole``: a number equal to its ``int()`` counts too (``3.0``, a 0-d array; not a bool or a
    string); a fraction is a ValueError.  ``what``: what the messages say is allowed (``"a positive
    integer"``; default: "an integer" and the bounds).  ``error``: the one exception class for
    both (a caller's ``ValueError`` subclass, say)."""
    if is_int(value):
        v = int(value)
    elif not whole or isinstance(value, (bool, np.bool_, str, bytes)):
        raise (error or TypeError)(f"{name} must be {what or 'an integer'}, got {value!r}")
    else:
        try:
            v = int(value)
        except (TypeError, ValueError, OverflowError):
            raise (error or TypeError)(f"{name} must be {what or 'an integer'}, got {value!r}") from None
        if v != value:
            raise (error or ValueError)(f"{name} must be {what or 'a whole number'}, got {value!r}")
    if v < minimum or (maximum is not None and v > maximum):
        hi = "" if maximum is None else f" and at most {maximum}"
        raise (error or ValueError)(f"{name} must be {what or f'at least {minimum}{hi}'}, got {value!r}")
    return v


def whole_numbers(values: np.ndarray) -> bool:
    """``values`` (an array) holds integers: an integer dtype, or finite floats with whole values
    (not bools)."""
    dtype = values.dtype
    if np.issubdtype(dtype, np.integer):
        return True
    return (np.issubdtype(dtype, np.floating) and bool(np.all(np.isfinite(values)))
            and bool(np.all(values == np.round(values))))


def check_size(name: str, value: Any, maximum: int = 4096) -> tuple[int, int]:
    """A grid size ``(H, W)`` with both at least 1 (a single int means square)."""
    if is_int(value):
        value = (value, value)
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
        raise TypeError(f"{name} must be a pair (H, W) of integers, got {value!r}")
    return check_int(f"{name}[0] (rows)", value[0], 1, maximum), check_int(f"{name}[1] (columns)", value[1], 1, maximum)


def check_choice(name: str, value: Any, allowed: Sequence[Any]) -> Any:
    if value not in allowed:
        raise ValueError(f"{name} must be one of {', '.join(repr(a) for a in allowed)}; got {value!r}"
                         + did_you_mean(value, [a for a in allowed if isinstance(a, str)]))
    return value


def did_you_mean(word: Any, allowed: Sequence[str]) -> str:
    """`` (did you mean 'x'?)``: the allowed name closest to a mistyped ``word`` (:mod:`difflib`),
    or ``""`` when none is close."""
    if not isinstance(word, str):
        return ""
    close = difflib.get_close_matches(word, [str(a) for a in allowed], n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def unknown_names(names: Sequence[Any], allowed: Sequence[str]) -> str:
    """``'lerning_rate' (did you mean 'learning_rate'?), 'x'``: refused names, each with the
    closest allowed one."""
    return ", ".join(repr(n) + did_you_mean(n, allowed) for n in names)
