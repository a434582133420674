"""Paired comparisons of benchmark rows on their common episodes (common random numbers).

The benchmark plays every policy on the same seeded episodes, so two rows of one task differ by
their policies alone, episode by episode.  For every pair (A, B) of rows of a task that keep their
episodes' results (``per_episode``, :mod:`gym_gridloc_agents.evaluation.rows`), on the episodes both
played (the first ``min(episodes)``):

- ``difference``: A's mean minus B's, of the steps to localise, or of the accuracy at L under the
  protocol (``episode_length``);
- ``ci95``: its percentile-bootstrap 95% interval (10,000 resamples): a paired bootstrap over the
  episodes, or, when a row holds several models (training seeds), a hierarchical one that
  resamples each row's seeds, then the common episodes
  (:func:`gym_gridloc_agents.evaluation.stats.hierarchical_replicates`);
- ``probability_of_improvement``: the fraction of common episodes on which A does better than B
  (fewer steps, or localised where B is not), ties counted half, averaged over the pairs of seeds;
- ``verdict``: ``better`` or ``worse`` (for A) when the interval excludes 0, else ``tie``: decided
  by the interval, never by the point estimate;
- under the protocol with one model each, McNemar's exact test on the discordant episodes
  (``mcnemar``: A right and B wrong, the reverse, the two-sided binomial p-value).
"""

from __future__ import annotations

import itertools
from typing import Any, Sequence

import numpy as np

from gym_gridloc_agents.evaluation import stats
from gym_gridloc_agents.evaluation.rows import episode_arrays
from gym_gridloc_agents.evaluation.scores import task_key


def verdict(ci: Sequence[float], lower_is_better: bool) -> str:
    """``better``/``worse`` for A when the interval of A - B excludes 0, else ``tie``."""
    lo, hi = ci
    if lo > 0:
        return "worse" if lower_is_better else "better"
    if hi < 0:
        return "better" if lower_is_better else "worse"
    return "tie"


def mcnemar(a: np.ndarray, b: np.ndarray) -> dict[str, Any]:
    """McNemar's exact test of two paired 0/1 outcomes: ``{"a_only", "b_only", "p_value"}``
    (``scipy.stats.binomtest`` of the discordant pairs at 1/2; 1 without any)."""
    from scipy.stats import binomtest

    a, b = np.asarray(a, dtype=bool), np.asarray(b, dtype=bool)
    a_only, b_only = int(np.sum(a & ~b)), int(np.sum(~a & b))
    p = 1.0 if a_only + b_only == 0 else float(binomtest(a_only, a_only + b_only, 0.5).pvalue)
    return {"a_only": a_only, "b_only": b_only, "p_value": p}


def compare(a: dict[str, Any], b: dict[str, Any], *, resamples: int = stats.BOOTSTRAP_RESAMPLES,
            seed: int = stats.BOOTSTRAP_SEED, scale: float = 1.0) -> dict[str, Any] | None:
    """Row ``a`` against row ``b`` (module docstring); None when they are not of one task on the
    same episodes or either lacks its episodes' results.  ``scale``: against ``scale`` times
    ``b`` (the difference is A's mean minus ``scale`` times B's, paired as ever: "A within 10%
    of B" is ``scale=1.1`` and a ``better`` verdict for fewer steps)."""
    from gym_gridloc_agents.evaluation.report import env_label, policy_label

    ea, eb = episode_arrays(a), episode_arrays(b)
    if ea is None or eb is None or task_key(a) != task_key(b):
        return None
    key, lower = ("accuracy_at_L", False) if a.get("episode_length") else ("steps", True)
    if key not in ea or key not in eb:
        return None
    n = min(ea[key].shape[1], eb[key].shape[1])
    x, y = ea[key][:, :n], eb[key][:, :n]
    reps = stats.hierarchical_replicates([x, y], [1.0, -float(scale)], resamples=resamples, seed=seed)
    ci = [float(reps[0])] * 2 if np.ptp(reps) == 0 else stats.percentile_interval(reps)
    # per pair of seeds: episodes where A does better, ties half
    wins = (x[:, None, :] < y[None, :, :]) if lower else (x[:, None, :] > y[None, :, :])
    ties = x[:, None, :] == y[None, :, :]
    out = {"env": env_label(a), "a": policy_label(a), "b": policy_label(b), "metric": key, "episodes": int(n),
           "seeds": [int(x.shape[0]), int(y.shape[0])], "difference": float(x.mean() - scale * y.mean()), "ci95": ci,
           "interval_over": ("episodes (paired bootstrap)" if x.shape[0] == y.shape[0] == 1
                             else "seeds, then the common episodes (hierarchical bootstrap)"),
           "probability_of_improvement": float(np.mean(wins + 0.5 * ties)), "verdict": verdict(ci, lower)}
    if key == "accuracy_at_L" and x.shape[0] == y.shape[0] == 1:
        out["mcnemar"] = mcnemar(x[0], y[0])
    return out


def pairs(rows: Sequence[dict[str, Any]], **kwargs: Any) -> list[dict[str, Any]]:
    """:func:`compare` of every pair of rows of one task (in the rows' order, A before B)."""
    out = []
    for a, b in itertools.combinations(rows, 2):
        if task_key(a) == task_key(b) and (c := compare(a, b, **kwargs)) is not None:
            out.append(c)
    return out


def attach_pairs(rows: Sequence[dict[str, Any]], **kwargs: Any) -> list[dict[str, Any]]:
    """:func:`pairs` of ``rows``, each also kept in its row A's ``pairs`` list (``gridloc bench --compare``)."""
    found = []
    for a in rows:
        a.pop("pairs", None)
    for a, b in itertools.combinations(rows, 2):
        if task_key(a) == task_key(b) and (c := compare(a, b, **kwargs)) is not None:
            a.setdefault("pairs", []).append(c)
            found.append(c)
    return found


def pairs_table(found: Sequence[dict[str, Any]]) -> str:
    """The pairs as a markdown table (A - B with its interval, what the interval is over, the
    probability that A does better on an episode, the verdict, McNemar's p under the protocol)."""
    lines = ["| task | A | B | metric | episodes | A - B (95% CI) | interval over | P(A better) | verdict | McNemar p |",
             "| --- | --- | --- | --- | ---: | --- | --- | ---: | --- | ---: |"]
    for p in found:
        digits = 3 if p["metric"] == "accuracy_at_L" else 2
        lo, hi = p["ci95"]
        mc = p.get("mcnemar")
        lines.append(f"| {p['env']} | {p['a']} | {p['b']} | {'accuracy at L' if p['metric'] == 'accuracy_at_L' else 'steps'} | "
                     f"{p['episodes']} | {p['difference']:+.{digits}f} ({lo:+.{digits}f} to {hi:+.{digits}f}) | "
                     f"{p['interval_over']} | {p['probability_of_improvement']:.3f} | {p['verdict']} | "
                     f"{'-' if mc is None else format(mc['p_value'], '.3g')} |")
    return "\n".join(lines)


__all__ = ["attach_pairs", "compare", "mcnemar", "pairs", "pairs_table", "verdict"]
