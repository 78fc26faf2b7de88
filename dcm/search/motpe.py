"""Optuna's multi-objective TPE (Ozaki et al.'s MOTPE): the paper's optimiser, cheap per trial at any budget.

Two ways to propose a batch (``batched``):

* ``false``: Optuna's sampler as it is, one TPE fit per proposal, with a constant liar spreading the proposals
  of a batch. Each fit builds Parzen estimators over the whole history, so a proposal costs more the longer
  the history, and 1,000 virtual trials spend more time in the optimiser than in a small model.
* ``true``: one fit per batch (:meth:`MOTPESearch.ask_batch`). The history is split and the two estimators are
  built once; each of the batch's proposals is the best of its own ``n_ei_candidates`` candidates drawn from
  that fit, as Optuna picks one proposal. Asked one at a time (a robot-based search), it proposes what
  ``batched: false`` does: nothing is pending when a single proposal is planned.
"""

from __future__ import annotations

import math
import warnings
from collections import deque
from typing import Any

import numpy as np

from dcm.search.space import SearchSpace


class MOTPESearch:
    """Optuna's multi-objective TPE (Ozaki et al.'s MOTPE) minimising (L_task, L_comp) via ask/tell."""

    def __init__(self, space: SearchSpace, seed: int, n_startup_trials: int = 10, multivariate: bool = True,
                 n_ei_candidates: int = 24, batched: bool = False):
        import optuna

        optuna.logging.set_verbosity(optuna.logging.WARNING)
        options = {"seed": seed, "n_startup_trials": n_startup_trials, "multivariate": multivariate,
                   "n_ei_candidates": n_ei_candidates}
        with warnings.catch_warnings():  # multivariate TPE is flagged experimental; behaviour is what we want
            warnings.simplefilter("ignore")
            sampler = _batch_sampler(**options) if batched else optuna.samplers.TPESampler(constant_liar=True,
                                                                                            **options)
        self.space = space
        self.batched = bool(batched)
        self.study = optuna.create_study(directions=["minimize", "minimize"], sampler=sampler)
        self._distribution = optuna.distributions.FloatDistribution(space.min_Npm, space.max_Npm, log=space.log)
        self._pending: deque[Any] = deque()  # asked, not yet told; constant_liar spreads a batch

    def ask(self) -> np.ndarray:
        names = self.space.param_names()
        trial = self.study.ask({name: self._distribution for name in names})
        self._pending.append(trial)
        return self.space.to_array(trial.params)

    def ask_batch(self, count: int) -> np.ndarray:
        """``count`` proposals (count, P, axes) to be evaluated together; batched, from one TPE fit."""
        if self.batched:
            self.study.sampler.plan(count)
        return np.stack([self.ask() for _ in range(count)])

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


def _batch_sampler(**options: Any) -> Any:
    """A TPESampler that fits once per planned batch (Optuna's own ``_sample``, vectorised over the batch)."""
    import optuna
    from optuna.samplers._tpe import sampler as tpe
    from optuna.trial import TrialState

    class BatchTPESampler(optuna.samplers.TPESampler):
        def __init__(self, **kwargs: Any) -> None:
            super().__init__(constant_liar=False, **kwargs)
            self._planned = 1
            self._queue: deque[dict[str, Any]] = deque()
            self._queue_space: tuple[str, ...] = ()

        def plan(self, count: int) -> None:
            """The next ``count`` relative samples come from one fit on the history as it is now."""
            self._planned = max(1, int(count))
            self._queue.clear()

        def _sample(self, study: Any, trial: Any, search_space: dict[str, Any]) -> dict[str, Any]:
            if not self._queue or self._queue_space != tuple(search_space):
                self._queue = deque(self._sample_batch(study, search_space, self._planned))
                self._queue_space = tuple(search_space)
                self._planned = 1  # a plan covers one batch; asks beyond it fit again
            return self._queue.popleft()

        def _sample_batch(self, study: Any, search_space: dict[str, Any], count: int) -> list[dict[str, Any]]:
            trials = study._get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED),
                                       use_cache=True)
            if self._gamma is None:
                self._gamma = tpe.default_gamma_multiobjective
            below, above = tpe._split_trials(study, trials, self._gamma(len(trials)))
            mpe_below = self._build_parzen_estimator(study, search_space, below, handle_below=True)
            mpe_above = self._build_parzen_estimator(study, search_space, above, handle_below=False)
            n = self._n_ei_candidates
            if count == 1:  # Optuna's own draws and acquisition: the proposal of an unbatched fit
                samples = mpe_below.sample(self._rng.rng, n)
                acquisition = self._compute_acquisition_func(samples, mpe_below, mpe_above)
            else:
                samples = _sample(mpe_below, self._rng.rng, n * count)
                acquisition = _log_pdf(mpe_below, samples) - _log_pdf(mpe_above, samples)
            best = np.argmax(acquisition.reshape(count, n), axis=1) + n * np.arange(count)
            return [{name: dist.to_external_repr(samples[name][i]) for name, dist in search_space.items()}
                    for i in best]

    return BatchTPESampler(**options)


def _continuous(estimator: Any) -> bool:
    """Whether every parameter of a Parzen estimator is continuous (a stiffness search's are)."""
    from optuna.samplers._tpe.probability_distributions import (
        _BatchedTruncLogNormDistributions,
        _BatchedTruncNormDistributions,
    )

    kinds = (_BatchedTruncNormDistributions, _BatchedTruncLogNormDistributions)
    return all(isinstance(d, kinds) and d.step == 0.0 for d in estimator._mixture_distribution.distributions)


def _log_gauss_mass(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """log(Phi(b) - Phi(a)) for a < b, computed in the left tail where it is accurate (as Optuna does)."""
    from scipy.special import log_ndtr, ndtr

    a, b = np.broadcast_arrays(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    right = a > 0
    a, b = np.where(right, -b, a), np.where(right, -a, b)  # mirror the right tail into the left one
    out = np.empty_like(a)
    left = b <= 0
    with np.errstate(divide="ignore"):
        log_b, log_a = log_ndtr(b[left]), log_ndtr(a[left])
        out[left] = log_b + np.log1p(-np.exp(log_a - log_b))
        central = ~left
        out[central] = np.log1p(-ndtr(a[central]) - ndtr(-b[central]))
    return out


def _sample(estimator: Any, rng: np.random.RandomState, size: int) -> dict[str, np.ndarray]:
    """``size`` draws of a Parzen estimator, vectorised (Optuna's draw for other parameter kinds)."""
    from scipy.special import ndtr, ndtri

    if not _continuous(estimator):
        return estimator.sample(rng, size)
    mixture = estimator._mixture_distribution
    active = rng.choice(len(mixture.weights), p=mixture.weights, size=size)
    columns = []
    for d in mixture.distributions:
        mu, sigma = d.mu[active], d.sigma[active]
        lo, hi = ndtr((d.adapted_low - mu) / sigma), ndtr((d.adapted_high - mu) / sigma)
        quantile = np.clip(lo + rng.rand(size) * (hi - lo), 1e-300, 1.0 - 1e-16)
        value = np.clip(mu + sigma * ndtri(quantile), d.adapted_low, d.adapted_high)
        columns.append(np.exp(value) if d.is_log else value)
    return estimator._untransform(np.stack(columns, axis=1))


def _log_pdf(estimator: Any, samples: dict[str, np.ndarray]) -> np.ndarray:
    """log p(x) of a Parzen estimator of continuous parameters at many points at once.

    Optuna's ``log_pdf`` recomputes each kernel's truncation mass for every point; here it is computed once per
    kernel, and the squared distances of all points to all kernels come from two matrix products, so a batch's
    candidates cost little more than one proposal's. Other parameter kinds fall back to Optuna's.
    """
    if not _continuous(estimator):
        return estimator.log_pdf(samples)
    mixture = estimator._mixture_distribution
    x = estimator._transform(samples)  # (N, D) in the order of the distributions
    x = np.where([d.is_log for d in mixture.distributions], np.log(np.maximum(x, 1e-300)), x)
    low = np.array([d.adapted_low for d in mixture.distributions])
    span = np.array([d.adapted_high for d in mixture.distributions]) - low
    mu = np.stack([d.mu for d in mixture.distributions], axis=1)  # (K, D)
    sigma = np.stack([d.sigma for d in mixture.distributions], axis=1)
    # Distances in units of each parameter's range keep the expanded squares well conditioned.
    x, mu, sigma = (x - low) / span, (mu - low) / span, sigma / span
    inv_var = 1.0 / sigma**2
    squared = (x**2) @ inv_var.T - 2.0 * x @ (mu * inv_var).T + (mu**2 * inv_var).sum(axis=1)  # (N, K)
    mass = _log_gauss_mass(-mu / sigma, (1.0 - mu) / sigma)  # (K, D): truncation to the box
    per_kernel = (np.log(mixture.weights) - np.log(sigma).sum(axis=1) - mass.sum(axis=1)
                  - 0.5 * mu.shape[1] * math.log(2 * math.pi))
    log_terms = -0.5 * squared + per_kernel - np.log(span).sum()
    top = log_terms.max(axis=1, keepdims=True)
    top[np.isneginf(top)] = 0.0
    with np.errstate(divide="ignore"):
        return (np.log(np.exp(log_terms - top).sum(axis=1)) + top[:, 0]).astype(np.float64)
