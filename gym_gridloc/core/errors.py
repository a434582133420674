"""Exceptions with messages that name what is wrong."""


class GridLocError(Exception):
    """Base class of gym_gridloc's own errors."""


class MapError(GridLocError, ValueError):
    """A map (file or rows) that cannot be used: ragged rows, unknown symbols, no free cell."""


class ImpossibleObservationError(GridLocError, ValueError):
    """An observation that the filter's model gives probability zero in every reachable state.

    This happens under model mismatch (the filter's model is not the one that produced the
    observation).  The belief is left as it was before the update.
    """
