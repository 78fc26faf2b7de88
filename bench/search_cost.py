"""Cost per proposal of the search strategies (MOTPE, BoTorch qLogNEHVI, random) as the history grows.

    python bench/search_cost.py [--trials 100] [--batch 5] [--phases 3] [--strategies motpe botorch random]

Each strategy minimises a cheap synthetic two-objective problem over the default search space (3 phases ×
3 axes in 100–1500 N/m) in batches of ``--batch`` asks followed by their tells, as the tuner's loop does. For
every batch it records the wall time of the asks (the strategy's own cost: fitting, acquisition) and prints
the mean seconds per proposal over windows of the history, plus the total. Wall time, so a busy machine
inflates the figures; run it twice and compare orders of magnitude, not percentages.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from dcm.search import SearchSpace, make_search


def synthetic(k: np.ndarray) -> tuple[float, float]:
    """Stiffer is more accurate, less compliant; uneven axes cost accuracy (a non-trivial front)."""
    mean = float(k.mean())
    return 1000.0 / mean + float(np.abs(k[:, 0] - k[:, 1]).mean()) / 1000.0, mean * np.sqrt(3.0) / 1000.0


def measure(name: str, space: SearchSpace, trials: int, batch: int, seed: int = 0) -> list[tuple[int, float]]:
    """(history length before the batch, seconds per proposal of that batch) for each batch."""
    options = {"max_trials": max(trials, 200)} if name == "botorch" else {}
    search = make_search(name, space, seed, **options)
    costs, told = [], 0
    while told < trials:
        count = min(batch, trials - told)
        start = time.perf_counter()
        proposals = [search.ask() for _ in range(count)]
        costs.append((told, (time.perf_counter() - start) / count))
        for proposal in proposals:
            search.tell(synthetic(proposal))
        told += count
    return costs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--batch", type=int, default=5)
    parser.add_argument("--phases", type=int, default=3)
    parser.add_argument("--strategies", nargs="+", default=["motpe", "botorch", "random"])
    args = parser.parse_args()
    space = SearchSpace(n_phases=args.phases)
    edges = sorted({0, 10, 25, 50, 100, 150, 200, args.trials} & set(range(args.trials + 1)))
    print(f"seconds per proposal, batches of {args.batch}, history length window:")
    print("strategy  " + "  ".join(f"[{a},{b})".rjust(10) for a, b in zip(edges, edges[1:])) + "     total s")
    for name in args.strategies:
        start = time.perf_counter()
        costs = measure(name, space, args.trials, args.batch)
        total = time.perf_counter() - start
        cells = []
        for a, b in zip(edges, edges[1:]):
            window = [c for n, c in costs if a <= n < b]
            cells.append(f"{np.mean(window):10.4f}" if window else " " * 10)
        print(f"{name:8s}  " + "  ".join(cells) + f"  {total:10.1f}", flush=True)


if __name__ == "__main__":
    main()
