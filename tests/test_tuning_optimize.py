"""The tuning loop: batches, failed trials, and resuming from its log."""

import numpy as np
import pytest

from dcm.search import SearchSpace, make_search
from dcm.tuning.optimize import TrialLog, TrialLogMismatch, optimize
from dcm.tuning.pareto import pick_spread

SPACE = SearchSpace(n_phases=2, min_Npm=100.0, max_Npm=1500.0)


def quadratic(proposals: np.ndarray, first: int = 0) -> np.ndarray:
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

    def counting(proposals, first):
        calls.append((first, len(proposals)))
        return quadratic(proposals)

    path = tmp_path / "log.npz"
    optimize(make_search("motpe", SPACE, seed=1), counting, n_trials=12, batch_size=4, log_path=path)
    resumed = optimize(make_search("motpe", SPACE, seed=1), counting, n_trials=20, batch_size=4, log_path=path)
    # the 12 logged trials were replayed, not evaluated again; every batch is told where it starts
    assert calls == [(0, 4), (4, 4), (8, 4), (12, 4), (16, 4)]
    np.testing.assert_array_equal(resumed.arrays()[0], full.arrays()[0])


def test_a_changed_seed_does_not_replay(tmp_path):
    path = tmp_path / "log.npz"
    optimize(make_search("random", SPACE, seed=1), quadratic, n_trials=4, log_path=path)
    with pytest.raises(TrialLogMismatch, match="does not replay"):
        optimize(make_search("random", SPACE, seed=2), quadratic, n_trials=8, log_path=path)


def test_pick_spread_takes_front_points_across_the_tradeoff():
    scores = np.array([[5.0, 1.0], [4.0, 2.0], [3.0, 3.0], [2.0, 4.0], [1.0, 5.0], [6.0, 6.0], [np.nan, np.nan]])
    assert pick_spread(scores, 3).tolist() == [0, 2, 4]
    assert pick_spread(scores, 10).tolist() == [0, 1, 2, 3, 4]


def test_a_log_of_other_settings_is_refused_unless_overwritten(tmp_path):
    path = tmp_path / "log.npz"
    ours = {"seed": 1, "demo": {"press_m": 0.01}, "predictor_sha256": "a" * 64}
    optimize(make_search("random", SPACE, seed=1), quadratic, n_trials=4, log_path=path, fingerprint=ours,
             notes={"predictor": "dcm.ckpt"})
    assert TrialLog.load(path).fingerprint == ours
    # the same settings resume
    assert len(optimize(make_search("random", SPACE, seed=1), quadratic, n_trials=6, log_path=path,
                        fingerprint=ours)) == 6
    theirs = {**ours, "demo": {"press_m": 0.02}, "predictor_sha256": "b" * 64}
    with pytest.raises(TrialLogMismatch) as err:
        optimize(make_search("random", SPACE, seed=1), quadratic, n_trials=8, log_path=path, fingerprint=theirs,
                 notes={"predictor": "baseline.ckpt"})
    message = str(err.value)
    assert "\n" not in message and str(path) in message and "cannot resume its 6 trials" in message
    assert "demo.press_m: 0.01 -> 0.02" in message
    assert "predictor: dcm.ckpt (sha256 aaaaaaaaaaaa) -> baseline.ckpt (sha256 bbbbbbbbbbbb)" in message
    assert "overwrite=true" in message
    log = optimize(make_search("random", SPACE, seed=1), quadratic, n_trials=3, log_path=path, fingerprint=theirs,
                   overwrite=True)
    assert len(log) == 3 and TrialLog.load(path).fingerprint == theirs


def test_a_log_without_fingerprint_is_refused(tmp_path):
    path = tmp_path / "old.npz"
    optimize(make_search("random", SPACE, seed=1), quadratic, n_trials=2, log_path=path)  # no fingerprint
    with pytest.raises(TrialLogMismatch, match="holds no fingerprint"):
        optimize(make_search("random", SPACE, seed=1), quadratic, n_trials=4, log_path=path, fingerprint={"seed": 1})
