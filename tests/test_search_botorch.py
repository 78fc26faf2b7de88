"""search=botorch: proposals inside the box, deterministic for a seed, and a budget it refuses to exceed."""

from __future__ import annotations

import numpy as np
import pytest

from dcm.search import SearchBudgetError, SearchSpace, check_budget, make_search

TINY = {"n_startup_trials": 4, "batch_size": 3, "max_trials": 10, "num_restarts": 2, "raw_samples": 16,
        "mc_samples": 16, "maxiter": 10}


def _objectives(k: np.ndarray) -> tuple[float, float] | None:
    mean = float(k.mean())
    if mean > 1400.0:
        return None  # a failed trial
    return 1000.0 / mean + float(np.abs(k[:, 0] - k[:, 2]).mean()) / 500.0, mean / 1000.0


def _run(space: SearchSpace, seed: int, n_trials: int, ask_ahead: int = 2) -> np.ndarray:
    """Asks ``ask_ahead`` proposals before telling them, as the tuner's batched loop does."""
    search = make_search("botorch", space, seed, **TINY)
    proposals = []
    while len(proposals) < n_trials:
        batch = [search.ask() for _ in range(min(ask_ahead, n_trials - len(proposals)))]
        for k in batch:
            search.tell(_objectives(k))
        proposals += batch
    return np.stack(proposals)


@pytest.mark.parametrize("log", [False, True])
def test_proposals_stay_inside_the_box_and_repeat_for_a_seed(log: bool):
    space = SearchSpace(n_phases=2, min_Npm=100.0, max_Npm=1500.0, log=log)
    first = _run(space, seed=3, n_trials=9)
    assert first.shape == (9, 2, 3)
    assert np.all((first >= 100.0) & (first <= 1500.0))
    np.testing.assert_array_equal(first, _run(space, seed=3, n_trials=9))
    assert not np.allclose(first, _run(space, seed=4, n_trials=9))
    assert len({tuple(k.ravel()) for k in first}) == 9  # the GP batch does not repeat itself


def test_the_unit_cube_round_trips():
    space = SearchSpace(n_phases=2, log=True)
    k = np.array([[100.0, 700.0, 1500.0], [250.0, 1000.0, 1499.0]])
    np.testing.assert_allclose(space.from_unit(space.to_unit(k)), k)


def test_more_trials_than_the_budget_are_refused_naming_the_setting():
    space = SearchSpace(n_phases=1)
    search = make_search("botorch", space, 0, **{**TINY, "max_trials": 2, "n_startup_trials": 2})
    for _ in range(2):
        search.ask()
        search.tell((1.0, 1.0))
    with pytest.raises(SearchBudgetError,
                       match=r"search=botorch supports at most 2 trials \(search.options.max_trials"):
        search.ask()
    with pytest.raises(SearchBudgetError, match="use search=motpe for the model's 1,000 virtual trials"):
        check_budget(make_search("botorch", space, 0), 1000)
    check_budget(make_search("motpe", space, 0), 1000)  # MOTPE has no budget


def test_bad_options_name_the_setting():
    with pytest.raises(ValueError, match="search.options.batch_size=0"):
        make_search("botorch", SearchSpace(), 0, batch_size=0)
    with pytest.raises(ValueError, match="unknown search strategy 'cmaes'"):
        make_search("cmaes", SearchSpace(), 0)
