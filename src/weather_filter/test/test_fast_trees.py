"""FastTrees: scikit-learn's gradient-boosted trees' scores bit for bit, their decisions exactly."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.ensemble import HistGradientBoostingClassifier

from weather_filter.obstacle.fast_trees import FastTrees


@pytest.fixture(scope="module")
def fitted():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(6000, 6)).astype(np.float32)
    x[rng.random(x.shape) < 0.05] = np.nan  # missing values go where each node learned
    y = ((np.nan_to_num(x[:, 0]) + 0.5 * np.nan_to_num(x[:, 1]) ** 2 + rng.normal(0, 0.5, 6000)) > 0.8).astype(int)
    model = HistGradientBoostingClassifier(max_iter=60, max_leaf_nodes=15, early_stopping=False, random_state=0)
    model.fit(x, y, sample_weight=np.where(y == 1, 1.0, 0.2))
    test = rng.normal(size=(5000, 6)).astype(np.float32)
    test[rng.random(test.shape) < 0.05] = np.nan
    return model, test


def test_scores_are_scikit_learns_bit_for_bit(fitted):
    model, x = fitted
    assert np.array_equal(FastTrees(model).decision_function(x), model.decision_function(x))


def test_decisions_at_a_threshold_are_the_whole_sums(fitted):
    model, x = fitted
    trees, scores = FastTrees(model), model.decision_function(x)
    # levels where most rows are decided early, and levels equal to rows' own scores (ties: >= is True)
    for level in (*np.quantile(scores, [0.05, 0.5, 0.9, 0.99]), scores[0], scores[17], 0.0):
        got = trees.above(x, level)
        assert got.dtype == bool and np.array_equal(got, scores >= level)
    assert 0 < trees.above(x, 0.0).sum() < len(x)


def test_bad_input_is_named(fitted):
    model, x = fitted
    with pytest.raises(ValueError, match=r"shape \(5000, 5\).*takes 6"):
        FastTrees(model).decision_function(x[:, :5])
