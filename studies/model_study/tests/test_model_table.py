"""The model comparison table: medians and ranges over seeds, references beside the models."""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from studies.model_study.model_table import REGRET_KEY, cached_eval, cell, per_skill_table, significance, table
from studies.model_study.stats import p_text


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


def test_cached_eval_reevaluates_a_checkpoint_rewritten_under_the_same_path(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import dcm.evaluate

    ckpt = tmp_path / "checkpoints" / "last.ckpt"
    ckpt.parent.mkdir()
    ckpt.write_bytes(b"epoch 1")
    calls: list[Path] = []

    def evaluate(path: Path, dataset: Path, split: str) -> dict:
        calls.append(path)
        return {"ckpt": str(Path(path).resolve()), REGRET_KEY: 0.0, "R_within": float(len(calls)), "per_skill": []}

    monkeypatch.setattr(dcm.evaluate, "evaluate", evaluate)
    dataset = tmp_path / "set.h5"
    assert cached_eval(tmp_path, dataset, "valid")["R_within"] == 1.0
    assert cached_eval(tmp_path, dataset, "valid")["R_within"] == 1.0 and len(calls) == 1  # cached
    cache = tmp_path / "eval_set_valid.json"
    assert json.loads(cache.read_text())["R_within"] == 1.0
    later = cache.stat().st_mtime_ns + 1_000_000_000
    ckpt.write_bytes(b"epoch 2")  # the run went on training
    os.utime(ckpt, ns=(later, later))
    assert cached_eval(tmp_path, dataset, "valid")["R_within"] == 2.0 and len(calls) == 2


def test_runs_still_training_are_left_out_and_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from studies.model_study.model_table import main

    (tmp_path / "dcm_s0" / "checkpoints").mkdir(parents=True)  # no summary.json yet: the run is not over
    with pytest.raises(SystemExit):
        main(["--dataset", str(tmp_path / "set.h5"), "--runs", f"DCM={tmp_path / 'dcm_s*'}"])
    err = capsys.readouterr().err
    assert "no summary.json" in err and str(tmp_path / "dcm_s0") in err and "no finished run" in err


def test_task_from_s_reaches_evaluate_and_keeps_its_own_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import dcm.evaluate
    from studies.model_study.model_table import main

    run = tmp_path / "dcm_s0"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "last.ckpt").write_bytes(b"weights")
    (run / "summary.json").write_text("{}")
    seen: list[dict] = []

    def evaluate(path: Path, dataset: Path, split: str, **overrides: object) -> dict:
        seen.append(overrides)
        return {"ckpt": str(Path(path).resolve()), REGRET_KEY: 0.0, "R_within": 0.5, "references": {}}

    monkeypatch.setattr(dcm.evaluate, "evaluate", evaluate)
    main(["--dataset", str(tmp_path / "set.h5"), "--splits", "valid", "--task-from-s", "1.0", "--runs", f"DCM={run}"])
    assert seen == [{"task_from_s": 1.0}] and (run / "eval_set_valid_task_from_s1.0.json").is_file()


def test_per_skill_table_gives_each_skill_its_spread_and_each_predictor_its_median() -> None:
    def skill(name: str, r: float, error: float) -> dict:
        return {"skill": name, "n": 20, "L_task_mean_N": 0.5, "L_task_sd_N": 0.02, "error_sd_N": error, "R": r}

    rows = {"DCM": {"valid": [{"per_skill": [skill("3", 0.2, 0.03), skill("7", 0.9, 0.01)]},
                              {"per_skill": [skill("3", 0.4, 0.05), skill("7", 0.8, 0.01)]}]},
            "copy-F_demo": {"valid": [{"force_rmse_N": 1.0}]},  # ranks nothing: no columns
            "stiffness-only ridge": {"valid": [{"per_skill": [skill("3", 0.6, 0.02)]}]}}
    lines = per_skill_table(rows, ["valid"]).splitlines()
    assert lines[0] == ("| split | skill | trials | L_task mean [N] | L_task sd [N] | DCM: R | DCM: error sd [N] "
                        "| stiffness-only ridge: R | stiffness-only ridge: error sd [N] |")
    assert lines[2] == "| valid | 3 | 20 | 0.5000 | 0.0200 | 0.300 | 0.0400 | 0.600 | 0.0200 |"
    assert lines[3] == "| valid | 7 | 20 | 0.5000 | 0.0200 | 0.850 | 0.0100 | – | – |"


def test_a_sampler_applies_to_dcm_runs_and_a_one_pass_model_says_it_ran_without(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A table of DCMs beside a baseline with --sampler ddim: the baseline has no sampler, so it is scored in
    its one pass, under the cache name of a plain evaluation, and the table says so."""
    from dcm.models.baseline import Baseline
    from studies.model_study.model_table import main
    from tests.conftest import train_tiny
    from tests.test_models_synthetic import write_synthetic_dataset

    data = write_synthetic_dataset(tmp_path / "synth.h5", n_train=6, n_valid=3, n_test=3)
    run = tmp_path / "baseline_s0"
    (run / "checkpoints").mkdir(parents=True)
    train_tiny(Baseline, data, run / "checkpoints" / "last.ckpt", 2)
    (run / "summary.json").write_text("{}")
    out = tmp_path / "table.md"
    text = main(["--dataset", str(data), "--splits", "test", "--sampler", "ddim", "--sampling-steps", "5",
                 "--runs", f"baseline={run}", "--out", str(out)])
    assert "| baseline | 1 |" in text and (run / "eval_synth_test.json").is_file()
    note = "baseline: a one-pass model, scored without --sampler ddim --sampling-steps 5 (DCM options)"
    assert note in text and note in out.read_text() and note in capsys.readouterr().out
