"""The model comparison table: medians and ranges over seeds, references beside the models."""

import numpy as np

from dcm.model_table import cell, table


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
