"""The model comparison table: medians and ranges over seeds, references beside the models."""

import numpy as np

from dcm.model_study.stats import p_text
from dcm.model_table import cell, significance, table


def test_cell_median_and_range() -> None:
    assert cell([0.5]) == "0.500"
    assert cell([0.2, 0.9, 0.5]) == "0.500 [0.200–0.900]"
    assert cell([float("nan"), None]) == "–"  # type: ignore[list-item]


def test_table_rows_and_columns() -> None:
    runs = {"DCM": {"valid": [{"R_within": 0.8, "force_rmse_N": 0.5}, {"R_within": 0.6, "force_rmse_N": 0.7}]},
            "copy-F_demo": {"valid": [{"force_rmse_N": 1.0, "R_within": np.nan}]}}
    text = table(runs, ["valid"])
    lines = text.splitlines()
    assert lines[0].startswith("| model | seeds | valid: force RMSE [N]")
    assert "| DCM | 2 | 0.600 [0.500–0.700] |" in lines[2]
    assert "0.700 [0.600–0.800]" in lines[2]
    assert lines[3].startswith("| copy-F_demo | 1 | 1.000 |")


def test_significance_compares_every_model_with_the_first() -> None:
    from scipy.stats import ttest_ind

    dcm = [{"R_within": 0.80, "force_rmse_N": 0.50}, {"R_within": 0.84, "force_rmse_N": 0.52},
           {"R_within": 0.82, "force_rmse_N": 0.49}]
    base = [{"R_within": 0.90, "force_rmse_N": 0.40}, {"R_within": 0.93, "force_rmse_N": 0.41},
            {"R_within": 0.91, "force_rmse_N": 0.43}]
    rows = {"DCM": {"valid": dcm}, "baseline": {"valid": base}, "copy-F_demo": {"valid": [{"force_rmse_N": 1.0}]}}
    text = significance(rows, ["DCM", "baseline"], ["valid"])
    p = ttest_ind([r["R_within"] for r in base], [r["R_within"] for r in dcm], equal_var=False).pvalue
    line = next(row for row in text.splitlines() if row.startswith("| baseline | valid |"))
    assert line.split(" | ")[2] == "+0.093"  # baseline − DCM, means
    assert line.split(" | ")[3] == p_text(p)
    assert significance(rows, ["DCM"], ["valid"]) == ""  # one model: nothing to compare
    one_seed = {"DCM": {"valid": dcm[:1]}, "baseline": {"valid": base}}
    assert "– (n < 2 or no spread)" in significance(one_seed, ["DCM", "baseline"], ["valid"])
