"""BoTorch's qLogNEHVI: Gaussian-process multi-objective Bayesian optimisation (``search=botorch``).

Why a second Bayesian optimiser next to MOTPE: a GP models the objectives jointly over the whole box and
plans a batch of ``q`` proposals together, which makes it the stronger choice when every trial is expensive
(a robot-based search of a few dozen trials). The price is an exact GP, whose fit and acquisition grow with
the cube of the observations, so this strategy refuses more than ``max_trials`` trials
(``search.options.max_trials``): the model's many virtual trials stay with ``search=motpe``.

The strategy
* works on the unit cube (:meth:`SearchSpace.to_unit`, log space when ``stiffness.log``);
* starts with ``n_startup_trials`` scrambled Sobol points seeded from ``seed``;
* then fits one :class:`~botorch.models.SingleTaskGP` with two independent outputs (standardised) to the
  negated objectives (BoTorch maximises) and maximises qLogNEHVI for ``q = batch_size`` points at once,
  conditioned on the proposals asked but not told yet (``X_pending``); :meth:`ask` hands them out one at a
  time from a queue, so it plugs into the same ask/tell loops as MOTPE and random search;
* scores a failed trial (``tell(None)``) at the worst value seen of each objective, so the GP learns to
  avoid the region instead of proposing it again;
* is deterministic: the same seed and the same outcomes (in the same ask/tell order) give the same
  proposals, because every random draw (Sobol, MC samples, restarts, fitting) is seeded from
  ``(seed, number of observations)`` inside a forked torch RNG;
* fits and optimises with ``threads`` torch threads (restored afterwards): its matrices are tiny, and on a
  machine whose cores are busy more threads make an acquisition many times slower.
"""

from __future__ import annotations

import warnings
from collections import deque

import numpy as np

from dcm.search.space import SearchSpace

DEFAULT_MAX_TRIALS = 200


class SearchBudgetError(ValueError):
    """More trials were asked of a strategy than its documented budget allows."""


class BoTorchSearch:
    """qLogNEHVI over per-phase stiffness, minimising (L_task, L_comp), through ask/tell."""

    def __init__(
        self,
        space: SearchSpace,
        seed: int,
        n_startup_trials: int = 10,
        batch_size: int = 5,
        max_trials: int = DEFAULT_MAX_TRIALS,
        ref_point: list[float] | None = None,
        num_restarts: int = 8,
        raw_samples: int = 256,
        mc_samples: int = 64,
        maxiter: int = 100,
        threads: int = 1,
    ):
        for name, value, low in (("n_startup_trials", n_startup_trials, 1), ("batch_size", batch_size, 1),
                                 ("max_trials", max_trials, 1), ("num_restarts", num_restarts, 1),
                                 ("raw_samples", raw_samples, 1), ("mc_samples", mc_samples, 1),
                                 ("maxiter", maxiter, 1), ("threads", threads, 1)):
            if int(value) != value or value < low:
                raise ValueError(f"search.options.{name}={value!r} must be an integer >= {low}")
        if ref_point is not None and len(ref_point) != 2:
            raise ValueError(f"search.options.ref_point={ref_point!r} must be [L_task_N, L_comp_kNpm] or null")
        self.space = space
        self.seed = int(seed)
        self.n_startup_trials = int(n_startup_trials)
        self.batch_size = int(batch_size)
        self.max_trials = int(max_trials)
        self.ref_point = None if ref_point is None else [float(v) for v in ref_point]
        self.num_restarts, self.raw_samples = int(num_restarts), int(raw_samples)
        self.mc_samples, self.maxiter = int(mc_samples), int(maxiter)
        self.threads = int(threads)
        self._sobol_drawn = 0
        self._queue: deque[np.ndarray] = deque()  # generated, not asked yet (unit cube)
        self._pending: deque[np.ndarray] = deque()  # asked, not told yet (unit cube)
        self._x: list[np.ndarray] = []  # told proposals (unit cube)
        self._y: list[np.ndarray | None] = []  # their objectives (minimised), None if the trial failed
        self.n_asked = 0

    # --- budget -------------------------------------------------------------------------------------------
    def check_budget(self, n_trials: int) -> None:
        """Raise before a run of ``n_trials`` trials starts if it would exceed ``max_trials``."""
        if n_trials > self.max_trials:
            raise SearchBudgetError(
                f"search=botorch supports at most {self.max_trials} trials (search.options.max_trials; exact GPs "
                f"cost O(n^3)), not {n_trials}; use search=motpe for the model's 1,000 virtual trials")

    # --- ask/tell -----------------------------------------------------------------------------------------
    def ask(self) -> np.ndarray:
        """The next proposal (P, axes) in N/m; a new batch of ``batch_size`` is planned when the queue is empty."""
        self.check_budget(self.n_asked + 1)
        if not self._queue:
            self._queue.extend(self._plan())
        unit = self._queue.popleft()
        self._pending.append(unit)
        self.n_asked += 1
        return self.space.from_unit(unit)

    def tell(self, objectives: tuple[float, float] | None) -> None:
        """Report the outcome of the oldest proposal not yet told; None marks a failed trial."""
        if not self._pending:
            raise RuntimeError("BoTorchSearch.tell() called before ask()")
        self._x.append(self._pending.popleft())
        if objectives is None or not np.all(np.isfinite(objectives)):
            self._y.append(None)
        else:
            self._y.append(np.array([float(objectives[0]), float(objectives[1])]))

    # --- planning -----------------------------------------------------------------------------------------
    def _plan(self) -> list[np.ndarray]:
        """The next batch on the unit cube: Sobol points during start-up (or with nothing to model), else qLogNEHVI."""
        if self.n_asked < self.n_startup_trials:  # the queue is empty here: asked = everything planned so far
            return self._sobol(min(self.batch_size, self.n_startup_trials - self.n_asked))
        train_x, train_y = self._training_data()
        if train_x is None:
            return self._sobol(self.batch_size)
        return self._acquire(train_x, train_y)

    def _sobol(self, count: int) -> list[np.ndarray]:
        import torch

        engine = torch.quasirandom.SobolEngine(self.space.dim, scramble=True, seed=self.seed)
        points = engine.draw(self._sobol_drawn + count, dtype=torch.float64)[self._sobol_drawn:]
        self._sobol_drawn += count
        return list(points.numpy())

    def _training_data(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Told proposals and their objectives; failed trials take the worst value seen of each objective."""
        finite = [y for y in self._y if y is not None]
        if len(finite) < 2:  # a GP on fewer than two outcomes cannot standardise them
            return None, None
        worst = np.max(np.stack(finite), axis=0)
        y = np.stack([worst if y is None else y for y in self._y])
        return np.stack(self._x), y

    def _reference(self, neg_y: torch.Tensor) -> torch.Tensor:  # noqa: F821
        import torch
        from botorch.utils.multi_objective.hypervolume import infer_reference_point
        from botorch.utils.multi_objective.pareto import is_non_dominated

        if self.ref_point is not None:
            return -torch.tensor(self.ref_point, dtype=torch.float64)
        return infer_reference_point(neg_y[is_non_dominated(neg_y)])

    def _acquire(self, train_x: np.ndarray, train_y: np.ndarray) -> list[np.ndarray]:
        import torch

        step_seed = self.seed * 1_000_003 + len(self._x)  # same seed and history -> same draws
        x = torch.as_tensor(train_x, dtype=torch.float64)
        neg_y = -torch.as_tensor(train_y, dtype=torch.float64)  # BoTorch maximises
        pending = torch.as_tensor(np.stack(self._pending), dtype=torch.float64) if self._pending else None
        bounds = torch.stack([torch.zeros(self.space.dim), torch.ones(self.space.dim)]).to(torch.float64)
        threads = torch.get_num_threads()
        with torch.random.fork_rng(), warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=RuntimeWarning)  # optimiser chatter, not errors
            torch.manual_seed(step_seed)
            torch.set_num_threads(self.threads)  # see ``threads`` in the class docstring
            try:
                return self._optimize(x, neg_y, pending, bounds, step_seed)
            finally:
                torch.set_num_threads(threads)

    def _optimize(self, x: torch.Tensor, neg_y: torch.Tensor, pending: torch.Tensor | None,  # noqa: F821
                  bounds: torch.Tensor, step_seed: int) -> list[np.ndarray]:  # noqa: F821
        import torch
        from botorch.acquisition.multi_objective.logei import qLogNoisyExpectedHypervolumeImprovement
        from botorch.fit import fit_gpytorch_mll
        from botorch.models import SingleTaskGP
        from botorch.models.transforms.outcome import Standardize
        from botorch.optim import optimize_acqf
        from botorch.sampling.normal import SobolQMCNormalSampler
        from gpytorch.mlls import ExactMarginalLogLikelihood

        model = SingleTaskGP(x, neg_y, outcome_transform=Standardize(m=2))
        fit_gpytorch_mll(ExactMarginalLogLikelihood(model.likelihood, model))
        acquisition = qLogNoisyExpectedHypervolumeImprovement(
            model=model, ref_point=self._reference(neg_y), X_baseline=x, X_pending=pending, prune_baseline=True,
            sampler=SobolQMCNormalSampler(sample_shape=torch.Size([self.mc_samples]), seed=step_seed))
        candidates, _ = optimize_acqf(
            acquisition, bounds=bounds, q=self.batch_size, num_restarts=self.num_restarts,
            raw_samples=self.raw_samples, sequential=True,
            options={"batch_limit": 5, "maxiter": self.maxiter, "seed": step_seed})
        return list(candidates.detach().clamp(0.0, 1.0).numpy())
