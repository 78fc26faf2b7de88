"""MOTPE's batched mode: one TPE fit per batch, the same proposal as Optuna's for a batch of one, seeded."""

from __future__ import annotations

import numpy as np
import pytest

from dcm.search import SearchSpace, make_search
from dcm.search.motpe import MOTPESearch, _log_gauss_mass, _log_pdf
from dcm.tuning.optimize import optimize

SPACE = SearchSpace(n_phases=2, min_Npm=100.0, max_Npm=1500.0)


def two_objectives(k: np.ndarray) -> tuple[float, float]:
    mean = float(k.mean())
    return 1000.0 / mean + float(np.abs(k[:, 0] - k[:, 1]).mean()) / 1000.0, mean / 1000.0


def batched_objective(proposals: np.ndarray, first: int = 0) -> np.ndarray:
    return np.array([two_objectives(k) for k in proposals])


@pytest.mark.parametrize("log", [False, True])
def test_a_batch_of_one_proposes_what_optunas_sampler_proposes(log: bool):
    """A robot-based search asks one proposal at a time: batched or not, it gets the same trials."""
    space = SearchSpace(n_phases=2, min_Npm=100.0, max_Npm=1500.0, log=log)
    plain, batched = MOTPESearch(space, 5, n_startup_trials=4), MOTPESearch(space, 5, n_startup_trials=4, batched=True)
    for _ in range(16):
        a, b = plain.ask(), batched.ask_batch(1)[0]
        np.testing.assert_array_equal(a, b)
        plain.tell(two_objectives(a))
        batched.tell(two_objectives(b))


def test_batched_proposals_are_seeded_distinct_and_inside_the_box(tmp_path):
    runs = [optimize(make_search("motpe", SPACE, 3, n_startup_trials=4, batched=True), batched_objective, 40, 10,
                     log_path=tmp_path / f"{i}.npz") for i in range(2)]
    params = runs[0].arrays()[0]
    np.testing.assert_array_equal(params, runs[1].arrays()[0])
    assert np.all((params >= 100.0) & (params <= 1500.0))
    assert len(np.unique(params[10:20].reshape(10, -1), axis=0)) == 10  # one fit, ten different proposals
    # a killed run resumes into the trials of an uninterrupted one: its batches replay from one fit each
    path = tmp_path / "resumed.npz"
    optimize(make_search("motpe", SPACE, 3, n_startup_trials=4, batched=True), batched_objective, 20, 10, log_path=path)
    resumed = optimize(make_search("motpe", SPACE, 3, n_startup_trials=4, batched=True), batched_objective, 40, 10,
                       log_path=path)
    np.testing.assert_array_equal(resumed.arrays()[0], params)


def test_batched_search_moves_towards_the_front():
    """After start-up, a batch's proposals are nearer the front (x and y stiffness equal) than random ones."""
    search = MOTPESearch(SPACE, 0, n_startup_trials=10, batched=True)
    for _ in range(8):
        for k in search.ask_batch(25):
            search.tell(two_objectives(k))
    late = search.ask_batch(50)
    random = np.random.default_rng(0).uniform(100.0, 1500.0, late.shape)
    def uneven(k):
        return np.median(np.abs(k[..., 0] - k[..., 1]))
    assert uneven(late) < 0.7 * uneven(random)


def test_the_vectorised_density_is_optunas():
    from optuna.samplers._tpe import sampler as tpe
    from optuna.samplers._tpe._truncnorm import _log_gauss_mass as optuna_mass
    from optuna.trial import TrialState

    a = np.random.default_rng(0).normal(0.0, 4.0, 2000)
    b = a + np.abs(np.random.default_rng(1).normal(0.0, 3.0, 2000)) + 1e-3
    np.testing.assert_allclose(_log_gauss_mass(a, b), optuna_mass(a, b), atol=1e-10)

    search = MOTPESearch(SPACE, 1, n_startup_trials=4, batched=True)
    for _ in range(30):
        k = search.ask()
        search.tell(two_objectives(k))
    study, sampler = search.study, search.study.sampler
    trials = study._get_trials(deepcopy=False, states=(TrialState.COMPLETE,), use_cache=False)
    space = {name: search._distribution for name in SPACE.param_names()}
    below, above = tpe._split_trials(study, trials, 3)
    for group, is_below in ((below, True), (above, False)):
        estimator = sampler._build_parzen_estimator(study, space, group, handle_below=is_below)
        samples = estimator.sample(np.random.RandomState(0), 300)
        np.testing.assert_allclose(_log_pdf(estimator, samples), estimator.log_pdf(samples), atol=1e-8)
