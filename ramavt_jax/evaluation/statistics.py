"""Uncertainty of evaluation numbers: a stratified bootstrap confidence interval of a mean over episodes, and for
comparisons between arms trained with several seeds the interquartile mean (IQM) and the probability of
improvement of `rliable` (Agarwal et al. 2021, "Deep RL at the edge of the statistical precipice").

Scores of several seeds are matrices [runs, tasks] as in rliable: one row per training seed, one column per target.
The bootstrap resamples runs within each task (rliable's StratifiedBootstrap), written here in numpy because
`rliable.library` imports `arch`, whose 7.x releases fail to import under pandas 3 (arch 8 works).
"""

from __future__ import annotations

import numpy as np

CONFIDENCE = 0.95
RESAMPLES = 2000


def _rliable():
    """rliable's metrics, imported on first use: they import scipy.stats (0.8 s), which a training run's clock
    would otherwise count before its first chunk."""
    from rliable import metrics

    return metrics


def stratified_resample_means(
    values: np.ndarray, strata: np.ndarray | None, resamples: int, rng: np.random.Generator
) -> np.ndarray:
    """Means [resamples] of `values` [N] resampled with replacement within each stratum (`strata` [N] labels; None:
    one stratum), each stratum keeping its size, so every resample weighs the targets as the data does."""
    values = np.asarray(values, np.float64).reshape(-1)
    strata = np.zeros(values.size, np.int64) if strata is None else np.asarray(strata).reshape(-1)
    total = np.zeros(resamples)
    for label in np.unique(strata):
        group = values[strata == label]
        picks = rng.integers(0, group.size, size=(resamples, group.size))
        total += group[picks].sum(axis=1)
    return total / values.size


def bootstrap_ci(
    values: np.ndarray,
    strata: np.ndarray | None = None,
    confidence: float = CONFIDENCE,
    resamples: int = RESAMPLES,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile bootstrap interval (low, high) of the mean of `values` [N], stratified by `strata` [N] (e.g. the
    target of each episode). NaNs for fewer than two values: one sample gives no interval."""
    values = np.asarray(values, np.float64).reshape(-1)
    if values.size < 2:
        return float("nan"), float("nan")
    means = stratified_resample_means(values, strata, resamples, np.random.default_rng(seed))
    tail = 100 * (1 - confidence) / 2
    low, high = np.percentile(means, [tail, 100 - tail])
    return float(low), float(high)


def sample_std(values: np.ndarray) -> float:
    """Sample standard deviation (ddof 1) of `values` [N]; NaN for fewer than two values."""
    values = np.asarray(values, np.float64).reshape(-1)
    return float(values.std(ddof=1)) if values.size > 1 else float("nan")


def iqm(scores: np.ndarray) -> float:
    """Interquartile mean of a score matrix [runs, tasks] (rliable.metrics.aggregate_iqm)."""
    return float(_rliable().aggregate_iqm(np.asarray(scores, np.float64)))


def iqm_ci(
    scores: np.ndarray, confidence: float = CONFIDENCE, resamples: int = RESAMPLES, seed: int = 0
) -> tuple[float, float]:
    """Stratified bootstrap interval of the IQM of `scores` [runs, tasks]: runs resampled within each task."""
    scores = np.asarray(scores, np.float64)
    runs, tasks = scores.shape
    if runs < 2:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, runs, size=(resamples, runs, tasks))
    resampled = np.take_along_axis(np.broadcast_to(scores, (resamples, runs, tasks)), picks, axis=1)
    aggregate_iqm = _rliable().aggregate_iqm
    stats = np.array([aggregate_iqm(r) for r in resampled])
    tail = 100 * (1 - confidence) / 2
    low, high = np.percentile(stats, [tail, 100 - tail])
    return float(low), float(high)


def probability_of_improvement(scores_x: np.ndarray, scores_y: np.ndarray) -> float:
    """P(X > Y): the chance that a run of arm X scores above a run of arm Y on a task, averaged over tasks
    (rliable.metrics.probability_of_improvement; Mann-Whitney U). Scores [runs_x, tasks], [runs_y, tasks]."""
    return float(
        _rliable().probability_of_improvement(np.asarray(scores_x, np.float64), np.asarray(scores_y, np.float64))
    )


def compare_arms(scores: dict[str, np.ndarray], seed: int = 0) -> dict:
    """IQM (with a 95 % stratified bootstrap interval) of each arm's score matrix [runs, tasks] and the probability
    of improvement of every ordered pair of arms. Returns {'iqm': {arm: {...}}, 'probability_of_improvement':
    {'x>y': p}}."""
    out = {"iqm": {}, "probability_of_improvement": {}}
    for arm, s in scores.items():
        low, high = iqm_ci(s, seed=seed)
        out["iqm"][arm] = {"iqm": iqm(s), "ci_low": low, "ci_high": high, "runs": int(np.shape(s)[0])}
    for x in scores:
        for y in scores:
            if x != y:
                out["probability_of_improvement"][f"{x}>{y}"] = probability_of_improvement(scores[x], scores[y])
    return out
