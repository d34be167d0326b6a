"""Statistics over the runs of an entry, with bootstrap confidence intervals from ``scipy.stats``.

Times to solve are right-censored: a run that never solved is counted at what it used (its budget),
marked censored, never dropped; a median that a censored run can move is only a lower bound and says
so. Final returns are summarized by the interquartile mean (IQM), as rliable recommends (Agarwal et al.,
"Deep RL at the Edge of the Statistical Precipice", 2021): robust to outlier runs, yet it uses half of
them, unlike the median.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

CONFIDENCE = 0.95
RESAMPLES = 4000
BOOTSTRAP_SEED = 0
"""Fixed, so the same runs give the same report."""


def bootstrap_ci(values: np.ndarray, statistic: Callable[..., Any]) -> list[float] | None:
    """A percentile bootstrap 95% CI of ``statistic`` (vectorized over ``axis``); None below 2 values."""
    from scipy.stats import bootstrap

    if values.size < 2:
        return None
    if np.all(values == values[0]):  # every resample is the same: the interval is that value
        return [float(values[0]), float(values[0])]
    result = bootstrap(
        (values,),
        statistic,
        confidence_level=CONFIDENCE,
        n_resamples=RESAMPLES,
        method="percentile",
        vectorized=True,
        random_state=np.random.default_rng(BOOTSTRAP_SEED),
    )
    return [float(result.confidence_interval.low), float(result.confidence_interval.high)]


def interquartile_mean(values: np.ndarray, axis: int = -1) -> Any:
    """Mean of the middle 50% of values (scipy's trimmed mean, 25% cut at each end)."""
    from scipy.stats import trim_mean

    return trim_mean(values, 0.25, axis=axis)


def censored_summary(values: Sequence[float], censored: Sequence[bool]) -> dict[str, Any]:
    """Median, IQR and a bootstrap 95% CI of the median of right-censored values.

    Censored values (runs that did not solve) enter at what they used; ``median_is_lower_bound`` is
    true when at least half are censored, so the true median may be higher (or not exist).
    """
    data = np.asarray(values, dtype=np.float64)
    flags = np.asarray(censored, dtype=bool)
    if data.size == 0:
        return {"median": None, "iqr": None, "ci95": None, "censored": 0, "median_is_lower_bound": False}
    q25, median, q75 = np.percentile(data, [25, 50, 75])
    return {
        "median": float(median),
        "iqr": [float(q25), float(q75)],
        "ci95": bootstrap_ci(data, np.median),
        "censored": int(flags.sum()),
        "median_is_lower_bound": bool(flags.sum() * 2 >= data.size),
    }


def iqm_summary(values: Sequence[float]) -> dict[str, Any]:
    """Interquartile mean with a bootstrap 95% CI, plus the plain mean, min and max."""
    data = np.asarray(values, dtype=np.float64)
    if data.size == 0:
        return {"iqm": None, "ci95": None, "mean": None, "min": None, "max": None}
    return {
        "iqm": float(interquartile_mean(data)),
        "ci95": bootstrap_ci(data, interquartile_mean),
        "mean": float(data.mean()),
        "min": float(data.min()),
        "max": float(data.max()),
    }


# ----------------------------------------------------------------------------------------------
# rliable's views of the runs: performance profiles and the probability of improvement
# ----------------------------------------------------------------------------------------------
# Written here with NumPy and scipy after rliable's own definitions (Agarwal et al. 2021; rliable's
# library.create_performance_profile and metrics.probability_of_improvement): rliable itself pins
# arch==5.3.0, which has no wheels for the Pythons we support, so it cannot be in the lock.

PROFILE_POINTS = 101
"""Thresholds (tau) a performance profile is given at."""


def profile_taus(scores: Sequence[float], marks: Sequence[float] = ()) -> np.ndarray:
    """``PROFILE_POINTS`` thresholds from just below the lowest score (every run above it) to the
    highest (none above it), widened to take in ``marks`` (the solved threshold, say)."""
    values = np.asarray([*scores, *marks], dtype=np.float64)
    if values.size == 0:
        return np.zeros(0)
    low, high = float(values.min()), float(values.max())
    margin = (high - low) * 0.02 or 1.0
    return np.linspace(low - margin, high, PROFILE_POINTS)


def performance_profile(scores: Sequence[float], taus: np.ndarray) -> dict[str, list[float]]:
    """An entry's performance profile (rliable's run score distribution): at each tau, the fraction of
    its runs with a score > tau, and a pointwise percentile bootstrap 95% CI over runs (rliable's
    stratified bootstrap, with one task)."""
    data = np.asarray(scores, dtype=np.float64)
    above = (data[None, :] > taus[:, None]).astype(np.float64)  # [tau, run]
    fraction = above.mean(axis=1) if data.size else np.zeros(len(taus))
    low, high = fraction, fraction
    if data.size >= 2 and not np.all(data == data[0]):
        from scipy.stats import bootstrap

        result = bootstrap(
            (above,),
            np.mean,
            axis=1,
            confidence_level=CONFIDENCE,
            n_resamples=RESAMPLES,
            method="percentile",
            vectorized=True,
            random_state=np.random.default_rng(BOOTSTRAP_SEED),
        )
        interval = result.confidence_interval  # NaN where every resample agrees: the value itself
        low = np.where(np.isnan(interval.low), fraction, interval.low)
        high = np.where(np.isnan(interval.high), fraction, interval.high)
    return {
        "fraction": [float(v) for v in fraction],
        "ci95_low": [float(v) for v in low],
        "ci95_high": [float(v) for v in high],
    }


def improvement_probability(x: np.ndarray, y: np.ndarray, axis: int = -1) -> Any:
    """P(X > Y): the chance that a run of X scores above a run of Y, ties counting half; the
    Mann-Whitney U statistic of X over Y divided by n*m (the rank-sum form, vectorized)."""
    from scipy.stats import rankdata

    x, y = np.moveaxis(np.asarray(x), axis, -1), np.moveaxis(np.asarray(y), axis, -1)
    n, m = x.shape[-1], y.shape[-1]
    ranks = rankdata(np.concatenate((x, y), axis=-1), axis=-1)
    u = ranks[..., :n].sum(axis=-1) - n * (n + 1) / 2
    return u / (n * m)


def improvement_summary(x: Sequence[float], y: Sequence[float]) -> dict[str, Any]:
    """P(X > Y) with a percentile bootstrap 95% CI, X's and Y's runs resampled independently
    (rliable's StratifiedIndependentBootstrap, one task); None without runs on either side."""
    a, b = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    if a.size == 0 or b.size == 0:
        return {"probability": None, "ci95": None}
    point = float(improvement_probability(a, b))
    ci = None
    if a.size >= 2 and b.size >= 2:
        from scipy.stats import bootstrap

        result = bootstrap(
            (a, b),
            improvement_probability,
            confidence_level=CONFIDENCE,
            n_resamples=RESAMPLES,
            method="percentile",
            vectorized=True,
            paired=False,
            random_state=np.random.default_rng(BOOTSTRAP_SEED),
        )
        interval = result.confidence_interval
        ci = [point if np.isnan(v) else float(v) for v in (interval.low, interval.high)]
    return {"probability": point, "ci95": ci}
