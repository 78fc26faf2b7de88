"""Stiffness search strategies that produce the dataset's trials (the paper's robot-based optimisation).

Every strategy proposes per-phase translational stiffness (P, 3) in N/m through ask/tell, so the generator
can store each proposal with its outcome. Strategies are seeded per demo: the same (seed, outcomes) give
the same proposals, which is what makes a resumed or sharded run reproduce an uninterrupted one.
"""

from __future__ import annotations

import warnings
from collections import deque
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

AXES = ("x", "y", "z")


@dataclass(frozen=True)
class SearchSpace:
    """Box of per-phase translational stiffness: ``n_phases`` × 3 values in [min_Npm, max_Npm]."""

    n_phases: int = 3
    min_Npm: float = 100.0
    max_Npm: float = 1500.0
    log: bool = False  # sample log-uniformly (spreads trials over the soft end too)

    def __post_init__(self) -> None:
        if self.n_phases < 1:
            raise ValueError(f"search space n_phases={self.n_phases} must be >= 1")
        if not 0 < self.min_Npm < self.max_Npm:
            raise ValueError(f"stiffness bounds must satisfy 0 < min_Npm < max_Npm, got {self.min_Npm}, {self.max_Npm}")

    def param_names(self) -> list[str]:
        return [f"K{axis}_phase{p}" for p in range(self.n_phases) for axis in AXES]

    def to_array(self, params: dict[str, float]) -> np.ndarray:
        return np.array([params[name] for name in self.param_names()], dtype=np.float64).reshape(self.n_phases, 3)


class StiffnessSearch(Protocol):
    """ask() proposes (P, 3) stiffness in N/m; tell() reports (L_task, L_comp), or None for a failed trial."""

    def ask(self) -> np.ndarray: ...

    def tell(self, objectives: tuple[float, float] | None) -> None: ...


class RandomSearch:
    """Seeded uniform (or log-uniform) sampling; the ablation baseline, ignores outcomes."""

    def __init__(self, space: SearchSpace, seed: int):
        self.space = space
        self.rng = np.random.default_rng(seed)

    def ask(self) -> np.ndarray:
        shape = (self.space.n_phases, 3)
        if self.space.log:
            low, high = np.log(self.space.min_Npm), np.log(self.space.max_Npm)
            return np.exp(self.rng.uniform(low, high, size=shape))
        return self.rng.uniform(self.space.min_Npm, self.space.max_Npm, size=shape)

    def tell(self, objectives: tuple[float, float] | None) -> None:
        return None


class MOTPESearch:
    """Optuna's multi-objective TPE (Ozaki et al.'s MOTPE) minimising (L_task, L_comp) via ask/tell."""

    def __init__(self, space: SearchSpace, seed: int, n_startup_trials: int = 10, multivariate: bool = True,
                 n_ei_candidates: int = 24):
        import optuna

        optuna.logging.set_verbosity(optuna.logging.WARNING)
        with warnings.catch_warnings():  # multivariate TPE is flagged experimental; behaviour is what we want
            warnings.simplefilter("ignore")
            sampler = optuna.samplers.TPESampler(seed=seed, n_startup_trials=n_startup_trials,
                                                 multivariate=multivariate, n_ei_candidates=n_ei_candidates)
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


def make_search(name: str, space: SearchSpace, seed: int, **options: Any) -> StiffnessSearch:
    """Build a strategy by its config name (``conf/search/<name>.yaml``)."""
    if name == "motpe":
        return MOTPESearch(space, seed, **options)
    if name == "random":
        return RandomSearch(space, seed)
    raise ValueError(f"unknown search strategy {name!r}; choose 'motpe' or 'random'")
