"""The tuning loop: batches, failed trials, and resuming from its log."""

import numpy as np
import pytest

from dcm.data.search import SearchSpace, make_search
from dcm.tuning.optimize import TrialLog, optimize
from dcm.tuning.run import pick_spread

SPACE = SearchSpace(n_phases=2, min_Npm=100.0, max_Npm=1500.0)


def quadratic(proposals: np.ndarray) -> np.ndarray:
    """A cheap two-objective stand-in: stiffer is more accurate but less compliant."""
    mean_k = proposals.mean(axis=(1, 2))
    scores = np.stack([1000.0 / mean_k, mean_k / 1000.0], axis=1)
    scores[mean_k > 1400.0] = np.nan  # pretend the stiffest trials diverged
    return scores


@pytest.mark.parametrize("strategy", ["random", "motpe"])
def test_batches_and_failures_are_logged(strategy, tmp_path):
    log = optimize(make_search(strategy, SPACE, seed=3), quadratic, n_trials=23, batch_size=5,
                   log_path=tmp_path / "log.npz")
    params, scores = log.arrays()
    assert params.shape == (23, 2, 3) and scores.shape == (23, 2)
    assert np.all((params >= 100.0) & (params <= 1500.0))
    np.testing.assert_allclose(TrialLog.load(tmp_path / "log.npz").arrays()[1], scores)


def test_a_resumed_run_matches_an_uninterrupted_one(tmp_path):
    full = optimize(make_search("motpe", SPACE, seed=1), quadratic, n_trials=20, batch_size=4)
    calls = []

    def counting(proposals):
        calls.append(len(proposals))
        return quadratic(proposals)

    path = tmp_path / "log.npz"
    optimize(make_search("motpe", SPACE, seed=1), counting, n_trials=12, batch_size=4, log_path=path)
    resumed = optimize(make_search("motpe", SPACE, seed=1), counting, n_trials=20, batch_size=4, log_path=path)
    assert calls == [4, 4, 4, 4, 4]  # the 12 logged trials were replayed, not evaluated again
    np.testing.assert_array_equal(resumed.arrays()[0], full.arrays()[0])


def test_a_changed_seed_does_not_replay(tmp_path):
    path = tmp_path / "log.npz"
    optimize(make_search("random", SPACE, seed=1), quadratic, n_trials=4, log_path=path)
    with pytest.raises(RuntimeError, match="does not replay"):
        optimize(make_search("random", SPACE, seed=2), quadratic, n_trials=8, log_path=path)


def test_pick_spread_takes_front_points_across_the_tradeoff():
    scores = np.array([[5.0, 1.0], [4.0, 2.0], [3.0, 3.0], [2.0, 4.0], [1.0, 5.0], [6.0, 6.0], [np.nan, np.nan]])
    assert pick_spread(scores, 3).tolist() == [0, 2, 4]
    assert pick_spread(scores, 10).tolist() == [0, 1, 2, 3, 4]
