"""lab/aux_error.py's after-the-fact linear probe: it recovers what the features hold and nothing else."""

import numpy as np

from lab import aux_error  # noqa: E402

GROUPS = np.zeros(4000, int)  # one group: every row


def _data(seed: int = 0, n: int = 4000, f: int = 64):
    rng = np.random.default_rng(seed)
    features = rng.normal(size=(n, f)) * rng.uniform(0.01, 100.0, size=f)  # unequal scales: the probe standardises
    fit = np.arange(n) % 2 == 0
    return rng, features, fit


def test_probe_recovers_a_linear_read_out_on_the_held_out_rows():
    rng, features, fit = _data()
    truth = features[:, :3] / features[:, :3].std(0) + 0.1 * rng.normal(size=(len(features), 3))
    corr = aux_error.probe_correlation(features, truth, fit, GROUPS)[0]
    assert corr.shape == (3,) and np.all(corr > 0.98), corr


def test_probe_finds_nothing_in_features_unrelated_to_the_truth():
    rng, features, fit = _data(1)
    truth = rng.normal(size=(len(features), 3))
    corr = aux_error.probe_correlation(features, truth, fit, GROUPS)[0]
    assert np.all(np.abs(corr) < 0.1), corr  # 2000 held-out rows: chance correlations are about 0.02


def test_probe_is_scored_only_on_rows_it_was_not_fitted_on():
    """Truth that copies three features on the fit rows and is noise on the others: the probe fits the copy
    exactly, and scored on the rows it was not fitted on its correlation is near 0 (on its own rows it would be 1)."""
    rng, features, fit = _data(2)
    truth = rng.normal(size=(len(features), 3))
    truth[fit] = features[fit, :3]
    assert np.all(np.abs(aux_error.probe_correlation(features, truth, fit, GROUPS)[0]) < 0.1)


def test_one_probe_is_scored_per_group():
    """One read-out for every group, scored on each group's held-out rows: the group whose truth the features
    hold scores near 1, the group whose truth is noise near 0."""
    rng, features, fit = _data(3)
    groups = np.arange(len(features)) // 2000  # rows 0-1999 group 0, the rest group 1
    truth = features[:, :3] / features[:, :3].std(0)
    truth[groups == 1] = rng.normal(size=((groups == 1).sum(), 3))
    corr = aux_error.probe_correlation(features, truth, fit, groups)
    assert corr.shape == (2, 3) and np.all(corr[0] > 0.9) and np.all(np.abs(corr[1]) < 0.1), corr
