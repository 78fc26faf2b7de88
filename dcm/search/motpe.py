"""Optuna's multi-objective TPE (Ozaki et al.'s MOTPE): the paper's optimiser, cheap per trial at any budget."""

from __future__ import annotations

import warnings
from collections import deque
from typing import Any

import numpy as np

from dcm.search.space import SearchSpace


class MOTPESearch:
    """Optuna's multi-objective TPE (Ozaki et al.'s MOTPE) minimising (L_task, L_comp) via ask/tell."""

    def __init__(self, space: SearchSpace, seed: int, n_startup_trials: int = 10, multivariate: bool = True,
                 n_ei_candidates: int = 24):
        import optuna

        optuna.logging.set_verbosity(optuna.logging.WARNING)
        with warnings.catch_warnings():  # multivariate TPE is flagged experimental; behaviour is what we want
            warnings.simplefilter("ignore")
            sampler = optuna.samplers.TPESampler(seed=seed, n_startup_trials=n_startup_trials,
                                                 multivariate=multivariate, n_ei_candidates=n_ei_candidates,
                                                 constant_liar=True)
        self.space = space
        self.study = optuna.create_study(directions=["minimize", "minimize"], sampler=sampler)
        self._distribution = optuna.distributions.FloatDistribution(space.min_Npm, space.max_Npm, log=space.log)
        self._pending: deque[Any] = deque()  # asked, not yet told; constant_liar spreads a batch

    def ask(self) -> np.ndarray:
        names = self.space.param_names()
        trial = self.study.ask({name: self._distribution for name in names})
        self._pending.append(trial)
        return self.space.to_array(trial.params)

    def tell(self, objectives: tuple[float, float] | None) -> None:
        """Report the outcome of the oldest proposal not yet told (asks may run ahead, for batching)."""
        import optuna

        if not self._pending:
            raise RuntimeError("MOTPESearch.tell() called before ask()")
        trial = self._pending.popleft()
        if objectives is None:
            self.study.tell(trial, state=optuna.trial.TrialState.FAIL)
        else:
            self.study.tell(trial, [float(objectives[0]), float(objectives[1])])
