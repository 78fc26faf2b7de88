"""Seeded uniform (or log-uniform) random search: the ablation baseline, blind to outcomes."""

from __future__ import annotations

import numpy as np

from dcm.search.space import SearchSpace


class RandomSearch:
    """Seeded uniform (or log-uniform) sampling; the ablation baseline, ignores outcomes."""

    def __init__(self, space: SearchSpace, seed: int):
        self.space = space
        self.rng = np.random.default_rng(seed)

    def ask(self) -> np.ndarray:
        shape = (self.space.n_phases, len(self.space.axes))
        if self.space.log:
            low, high = np.log(self.space.min_Npm), np.log(self.space.max_Npm)
            return np.exp(self.rng.uniform(low, high, size=shape))
        return self.rng.uniform(self.space.min_Npm, self.space.max_Npm, size=shape)

    def tell(self, objectives: tuple[float, float] | None) -> None:
        return None
