"""Batched exact filtering: one call updates N beliefs with N actions and N observations.

:class:`BatchFilter` holds N beliefs as one ``(N, L, H, W)`` array and runs the same stencil as
:meth:`GridModel.predict` on all of them at once: for each term of the transition, the N
weight arrays of the N actions are gathered (a broadcast when every action has the same weight)
and multiplied with the N shifted beliefs.  There is no Python loop over the N beliefs.  Each
belief equals the one a :class:`~gym_gridloc.ForwardFilter` computes from the same actions and
observations, within 1e-12 (tests/test_vector.py).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from gym_gridloc.core.errors import ImpossibleObservationError
from gym_gridloc.core.model import GridModel
from gym_gridloc.core.sensors import RingSensor, Sensor


def readings_of(sensor: Sensor, observations: Any, n: int) -> np.ndarray:
    """The reading indices (N,) int64 of N observations batched as a vector env emits them:
    ``(N,)`` ints for ``Discrete``, ``(N, 4)`` bits for ``MultiBinary(4)``."""
    obs = np.asarray(observations)
    space = sensor.observation_space
    if isinstance(space, spaces.Discrete):
        if obs.shape != (n,) or not np.issubdtype(obs.dtype, np.integer):
            raise ValueError(f"observations must be {n} integers (one per belief), got shape {obs.shape} dtype {obs.dtype}")
        readings = obs.astype(np.int64) - int(space.start)
        bad = (readings < 0) | (readings >= space.n)
    elif isinstance(space, spaces.MultiBinary) and space.shape == (4,):
        if obs.shape != (n, 4):
            raise ValueError(f"observations must have shape ({n}, 4) (four bits per belief), got {obs.shape}")
        bits = obs.astype(np.int64)
        bad = np.any((bits != 0) & (bits != 1), axis=1)
        readings = bits @ np.array([8, 4, 2, 1], dtype=np.int64)
    else:
        raise TypeError(f"BatchFilter cannot read observations of the space {space}")
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"observation {obs[i]!r} of belief {i} is not in the sensor's space {space}")
    return readings


def batch_likelihood(sensor: Sensor, readings: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """P(reading_i | position) for N readings, as an (N, H*W) array (rows zero on obstacles).

    Table sensors (colour, wall) gather rows of their table; the ring sensor writes its 5x5
    kernel round each cell reading (25 scatters over the batch) and its P(nothing) row for the
    others.  Other sensors fall back to one :meth:`Sensor.likelihood` call per reading.
    """
    h, w = sensor.grid.shape
    n = readings.shape[0]
    if out is None:
        out = np.empty((n, h * w))
    table = getattr(sensor, "_table", None)
    if isinstance(table, np.ndarray) and table.shape[1:] == (h, w):
        np.take(table.reshape(table.shape[0], -1), readings, axis=0, out=out)
        return out
    if isinstance(sensor, RingSensor):
        out.fill(0.0)
        nothing = readings == sensor.nothing
        if nothing.any():
            out[nothing] = sensor.nothing_probability.reshape(-1)
        cells = np.flatnonzero(~nothing)
        if cells.size:
            r0, c0 = np.divmod(readings[cells], w)
            free = sensor.grid.free
            for i in range(5):
                rr = r0 + i - 2
                for j in range(5):
                    cc = c0 + j - 2
                    ok = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
                    if ok.any():
                        r, c, k = rr[ok], cc[ok], cells[ok]
                        out[k, r * w + c] = sensor._kernel[i, j] * free[r, c]
        return out
    for i, reading in enumerate(readings):
        out[i] = sensor.likelihood(int(reading)).reshape(-1)
    return out


class BatchFilter:
    """N exact forward filters over one :class:`GridModel`, updated together.

    >>> import numpy as np, gym_gridloc
    >>> bf = gym_gridloc.BatchFilter(gym_gridloc.windy_maze_model(), 2)
    >>> _ = bf.reset([[0, 0, 0, 1], [1, 0, 0, 1]])
    >>> _ = bf.step([0, 1], [[0, 1, 0, 0], [0, 1, 0, 0]])
    >>> bf.beliefs.shape
    (2, 1, 6, 7)

    Parameters
    ----------
    model:
        The model of every belief.
    n:
        The number of beliefs.
    """

    def __init__(self, model: GridModel, n: int) -> None:
        if not isinstance(model, GridModel):
            raise TypeError(f"BatchFilter needs a GridModel, got {type(model).__name__}")
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"n (the number of beliefs) must be a positive integer, got {n!r}")
        self.model = model
        self.n = int(n)
        L, h, w = model.belief_shape
        self._hw = h * w
        self._size = L * h * w
        self._plan = self._batch_plan()
        self._b = np.empty((self.n, self._size))
        self._spare = np.empty((self.n, self._size))
        self._tmp = np.empty((self.n, self._hw))
        self._wbuf = np.empty((self.n, self._hw))
        self._lik = np.empty((self.n, self._hw))
        self._ready = np.zeros(self.n, dtype=bool)
        self.log_likelihood = np.zeros(self.n)
        # Compiled path (numba, on models small enough for it: kernels.uses_numba): one call for
        # the whole step, where the padded per-action weights are small (they copy the model's:
        # at most 32 MB).
        self._compiled = None
        from gym_gridloc import kernels

        if (
            model.kidnap_prob == 0.0
            and kernels.uses_numba(model)
            and model.n_actions * max(len(t) for t in model.transitions) * self._hw * 8 <= 32 * 2**20
        ):
            self._compiled = kernels.BatchPlan(model)

    def _batch_plan(self):
        """One entry per distinct flat shift over all actions, ordered as the single filter's
        plans: ``(first, src_lo, dst_lo, n, weights)`` with ``weights`` an (A, n) stack of the
        actions' weight slices, or a (1, n) row when every action has the same weight."""
        model = self.model
        per_action = [model.flat_plan(a)[1] for a in range(model.n_actions)]
        keys: list[tuple[int, int, int]] = []
        firsts: dict[tuple[int, int, int], bool] = {}
        for plan in per_action:
            for first, s0, d0, n, _ in plan:
                key = (s0, d0, n)
                if key not in firsts:
                    keys.append(key)
                    firsts[key] = first
                else:
                    firsts[key] = firsts[key] and first
        # A "first" term writes its whole destination layer; at most one per layer.
        covered: set[int] = set()
        first_keys, rest_keys = [], []
        for key in keys:
            layer = key[1] // self._hw
            if firsts[key] and layer not in covered:
                covered.add(layer)
                first_keys.append(key)
            else:
                rest_keys.append(key)
        self._zero_layers = tuple(layer for layer in range(model.n_layers) if layer not in covered)
        out = []
        for key in first_keys + rest_keys:
            s0, d0, n = key
            rows = []
            for plan in per_action:
                row = next((wf for _, a_s0, a_d0, a_n, wf in plan if (a_s0, a_d0, a_n) == key), None)
                rows.append(np.zeros(n) if row is None else row)
            if all(r is rows[0] or np.array_equal(r, rows[0]) for r in rows[1:]):
                weights = rows[0].reshape(1, n)
            else:
                weights = np.stack(rows)
            out.append((key in first_keys, s0, d0, n, weights))
        return tuple(out)

    # -- the API ---------------------------------------------------------------------------------
    def reset(self, observations: Any = None, mask: Any = None, *, readings: Any = None) -> "BatchFilter":
        """Start the beliefs (those where ``mask`` is True; default all) from the prior, updated
        with their observations when given (a batch of N, as for :meth:`step`).  ``readings``
        (N reading indices, as :func:`readings_of` gives) may replace ``observations``."""
        sel = self._mask(mask)
        prior = self.model.prior().reshape(-1)
        if observations is None and readings is None:
            self._b[sel] = prior
            self.log_likelihood[sel] = 0.0
            self._ready[sel] = True
            return self
        readings = readings_of(self.model.sensor, observations, self.n) if readings is None \
            else np.asarray(readings, dtype=np.int64)
        idx = np.flatnonzero(sel)
        post = np.tile(prior, (idx.size, 1))
        z = self._update(post, readings[idx], np.ones(idx.size, dtype=bool), idx)
        self._b[idx] = post
        self.log_likelihood[idx] = np.log(z)
        self._ready[idx] = True
        return self

    def step(self, actions: Any, observations: Any = None, mask: Any = None, *, readings: Any = None) -> "BatchFilter":
        """Predict each belief with its action, then update it with its observation (only the
        beliefs where ``mask`` is True; default all).  On an impossible observation nothing
        changes and :class:`ImpossibleObservationError` names the belief.  ``readings`` (N
        reading indices) may replace ``observations``."""
        sel = self._mask(mask)
        if not np.all(self._ready[sel]):
            raise RuntimeError("call BatchFilter.reset() before step() (some beliefs were never reset)")
        acts = np.asarray(actions)
        if acts.shape != (self.n,) or not np.issubdtype(acts.dtype, np.integer):
            raise ValueError(f"actions must be {self.n} integers (one per belief), got shape {acts.shape} dtype {acts.dtype}")
        acts = acts.astype(np.int64)
        bad = ((acts < 0) | (acts >= self.model.n_actions)) & sel
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"action {int(acts[i])} of belief {i} is outside 0..{self.model.n_actions - 1} (0=N, 1=E, 2=S, 3=W)")
        acts = np.where(sel, acts, 0)
        readings = readings_of(self.model.sensor, observations, self.n) if readings is None \
            else np.asarray(readings, dtype=np.int64)
        pred = self._spare
        if self._compiled is not None:
            lik = batch_likelihood(self.model.sensor, readings, self._lik)
            z = self._compiled.run(self._b, acts, lik, pred, sel)
            bad = sel & ~((z > 0.0) & np.isfinite(z))
            if np.any(bad):
                i = int(np.flatnonzero(bad)[0])
                raise ImpossibleObservationError(
                    f"observation (reading {int(readings[i])}) of belief {i} is impossible under the filter's "
                    f"model ({self.model!r}) given its belief so far (model mismatch?)"
                )
        else:
            self.predict_into(self._b, acts, pred)
            z = self._update(pred, readings, sel)
        if sel.all():
            self._b, self._spare = pred, self._b
        else:
            self._b[sel] = pred[sel]
        self.log_likelihood[sel] += np.log(z[sel])
        return self

    def predict_into(self, beliefs: np.ndarray, actions: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``out[i] = T_{actions[i]}^T beliefs[i]`` for (N, L*H*W) arrays (the stencil, batched)."""
        hw = self._hw
        for layer in self._zero_layers:
            out[:, layer * hw : (layer + 1) * hw] = 0.0
        for first, s0, d0, n, weights in self._plan:
            if weights.shape[0] == 1:
                wv = weights
            else:
                wv = self._wbuf[:, :n]
                np.take(weights, actions, axis=0, out=wv)
            src = beliefs[:, s0 : s0 + n]
            dst = out[:, d0 : d0 + n]
            if first:
                np.multiply(wv, src, out=dst)
            else:
                tmp = self._tmp[:, :n]
                np.multiply(wv, src, out=tmp)
                np.add(dst, tmp, out=dst)
        k = self.model.kidnap_prob
        if k > 0.0:
            mask = self.model.state_mask.reshape(-1)
            out *= 1.0 - k
            out += (k / self.model.n_states) * beliefs.sum(axis=1, keepdims=True) * mask
        return out

    def _update(self, post: np.ndarray, readings: np.ndarray, sel: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """Multiply by the likelihoods and normalise, in place; returns the normalisers.
        ``rows``: the beliefs the rows of ``post`` belong to (default all N)."""
        m = post.shape[0]
        lik = batch_likelihood(self.model.sensor, readings, self._lik[:m])
        L = self.model.n_layers
        view = post.reshape(m, L, self._hw)
        np.multiply(view, lik[:, None, :], out=view)
        z = post.sum(axis=1)
        bad = sel & ~(z > 0.0) | sel & ~np.isfinite(z)
        if np.any(bad):
            j = int(np.flatnonzero(bad)[0])
            i = j if rows is None else int(rows[j])
            readings = {i: readings[j]}
            raise ImpossibleObservationError(
                f"observation (reading {int(readings[i])}) of belief {i} is impossible under the filter's "
                f"model ({self.model!r}) given its belief so far (model mismatch?)"
            )
        post /= np.where(z > 0.0, z, 1.0)[:, None]
        return z

    def _mask(self, mask: Any) -> np.ndarray:
        if mask is None:
            return np.ones(self.n, dtype=bool)
        m = np.asarray(mask)
        if m.shape != (self.n,) or m.dtype != bool:
            raise ValueError(f"mask must be {self.n} booleans, got shape {m.shape} dtype {m.dtype}")
        return m

    # -- reading the beliefs ---------------------------------------------------------------------
    @property
    def beliefs(self) -> np.ndarray:
        """The hidden-state beliefs, (N, L, H, W) float64 (a view: copy it to keep it)."""
        return self._b.reshape(self.n, *self.model.belief_shape)

    @property
    def position_beliefs(self) -> np.ndarray:
        """P(position) per belief, (N, H, W) float64."""
        b = self.beliefs
        return b[:, 0] if b.shape[1] == 1 else b.sum(axis=1)
