"""Multi-objective stiffness search strategies, shared by dataset generation and tuning.

Every strategy proposes per-phase translational stiffness (P, axes) in N/m, the axes of the space's frame
(world: x, y, z; surface: tangent, normal), through ask/tell and minimises (L_task, L_comp). Strategies are
seeded: the same (seed, outcomes) give the same proposals, which is what makes a resumed or sharded run
reproduce an uninterrupted one.

=========  ======================================  ============================================
name       strategy                                when
=========  ======================================  ============================================
motpe      Optuna's MOTPE (the paper's optimiser)  default; cheap per trial at any budget
random     seeded (log-)uniform sampling           ablation baseline
botorch    BoTorch qLogNEHVI on a GP               expensive trials, at most ``max_trials``
=========  ======================================  ============================================
"""

from __future__ import annotations

from typing import Any

from dcm.search.space import SearchSpace, StiffnessSearch, space_from_settings

STRATEGIES = ("motpe", "random", "botorch")


def make_search(name: str, space: SearchSpace, seed: int, **options: Any) -> StiffnessSearch:
    """Build a strategy by its config name (``conf/search/<name>.yaml``)."""
    if name == "motpe":
        from dcm.search.motpe import MOTPESearch

        return MOTPESearch(space, seed, **options)
    if name == "random":
        from dcm.search.random_search import RandomSearch

        return RandomSearch(space, seed, **options)
    if name == "botorch":
        from dcm.search.qnehvi import BoTorchSearch

        return BoTorchSearch(space, seed, **options)
    raise ValueError(f"unknown search strategy {name!r}; choose one of {', '.join(STRATEGIES)}")


def check_budget(search: StiffnessSearch, n_trials: int) -> None:
    """Raise before a run if ``n_trials`` exceeds the strategy's budget (only ``botorch`` has one)."""
    check = getattr(search, "check_budget", None)
    if check is not None:
        check(n_trials)


def __getattr__(name: str) -> Any:  # the classes, without importing optuna/botorch until they are used
    if name == "MOTPESearch":
        from dcm.search.motpe import MOTPESearch

        return MOTPESearch
    if name == "RandomSearch":
        from dcm.search.random_search import RandomSearch

        return RandomSearch
    if name in ("BoTorchSearch", "SearchBudgetError"):
        from dcm.search import qnehvi

        return getattr(qnehvi, name)
    raise AttributeError(f"module 'dcm.search' has no attribute {name!r}")


__all__ = ["STRATEGIES", "BoTorchSearch", "MOTPESearch", "RandomSearch", "SearchBudgetError", "SearchSpace",
           "StiffnessSearch", "check_budget", "make_search", "space_from_settings"]
