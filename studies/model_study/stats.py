"""Statistics over seeds for the model studies: a summary per cell and Welch's t-test between two cells.

Runs of two settings are trained with independent seeds (seed s of one setting shares nothing with seed s
of another but the data split), so two cells are compared as independent samples with unequal variances:
Welch's t-test, not a paired test.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from studies.tuning_study.study_stats import summarize

ALPHA = 0.05  # significance level: p below it is printed in bold


def finite(values: Sequence[float | None]) -> np.ndarray:
    """The finite values as float64 (None and NaN dropped)."""
    return np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=np.float64)


def describe(values: Sequence[float | None]) -> dict[str, float | int]:
    """n, mean, std (n − 1), median, min, max (and quartiles) of the finite values; NaN where undefined."""
    kept = finite(values)
    out = summarize(kept.tolist())
    out["std"] = float(kept.std(ddof=1)) if len(kept) > 1 else math.nan
    return out


def welch_test(first: Sequence[float | None], second: Sequence[float | None]) -> dict[str, float | int | None]:
    """Two-sided Welch t-test of mean(first) vs mean(second); ``p`` is None when no test is possible.

    Needs two finite values on each side and some spread; ``df`` is the Welch–Satterthwaite degrees of freedom.
    """
    from scipy.stats import ttest_ind

    a, b = finite(first), finite(second)
    result: dict[str, float | int | None] = {
        "n": int(len(a)), "n_against": int(len(b)),
        "mean": float(a.mean()) if len(a) else math.nan, "mean_against": float(b.mean()) if len(b) else math.nan,
        "difference": float(a.mean() - b.mean()) if len(a) and len(b) else math.nan,
        "t": None, "df": None, "p": None,
    }
    if len(a) < 2 or len(b) < 2:
        return result
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    if va + vb == 0:
        return result
    test = ttest_ind(a, b, equal_var=False)
    df = (va + vb) ** 2 / (va**2 / (len(a) - 1) + vb**2 / (len(b) - 1))
    result.update(t=float(test.statistic), df=float(df), p=float(test.pvalue))
    return result


def p_text(p: float | None) -> str:
    """A test's p for a Markdown table: three significant digits, bold below :data:`ALPHA`."""
    if p is None:
        return "– (n < 2 or no spread)"
    return f"**{p:.3g}**" if p < ALPHA else f"{p:.3g}"
