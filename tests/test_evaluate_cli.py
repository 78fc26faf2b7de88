"""python -m dcm.evaluate: the table is its result (stdout), and the JSON goes only where ``out=`` says."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest
from test_models_synthetic import write_synthetic_dataset

from dcm.console import QUIET_LOGGERS
from dcm.evaluate import main as evaluate_main


@pytest.fixture()
def synthetic(tmp_path: Path) -> Path:
    return write_synthetic_dataset(tmp_path / "synth.h5", n_train=6, n_valid=3, n_test=3)


def test_the_table_goes_to_stdout_and_no_file_is_written_unasked(
        synthetic: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    result = evaluate_main(["ckpt=copy_demo", f"dataset={synthetic}", "split=test"])
    captured = capsys.readouterr()
    assert not list(work.iterdir())  # nothing written where the user happens to stand
    lines = captured.out.splitlines()
    assert lines[0] == "n=3 trajectories, 3 skills (test split)"
    assert lines[1].split()[:3] == ["predictor", "R_within", "90%"]
    assert lines[2].split()[0] == "copy_demo"
    assert "nan" not in lines[2] and lines[2].count("n/a") == 6  # one trial per skill; copy_demo ranks no L_task
    assert lines[3:] == ["n/a: R_within, 90% interval, Spearman: needs >= 3 trials per skill; this split has 1",
                         "n/a: top3_regret: needs >= 4 trials per skill; this split has 1",
                         "n/a: R_pooled: the predicted or the true L_task is constant"]
    assert "predictor" not in captured.err and result["n"] == 3


def test_out_writes_the_metrics_there(synthetic: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "runs" / "metrics.json"
    result = evaluate_main(["ckpt=copy_demo", f"dataset={synthetic}", "split=test", f"out={out}"])
    assert json.loads(out.read_text()) == json.loads(json.dumps(result))
    assert capsys.readouterr().out.splitlines()[-1] == f"wrote {out}"


def test_library_chatter_is_hushed(synthetic: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for name in QUIET_LOGGERS:
        logging.getLogger(name).setLevel(logging.NOTSET)
    evaluate_main(["ckpt=copy_demo", f"dataset={synthetic}", "split=test"])
    assert all(logging.getLogger(name).level == logging.WARNING for name in QUIET_LOGGERS)


def test_an_out_that_cannot_be_written_is_refused_before_evaluating(
        synthetic: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A directory, a path under a file or an input as out= ends in one line naming out= and the path, before the
    evaluation (which would then be lost) starts; the input is left whole."""
    import dcm.evaluate

    def no_evaluation(*args, **kwargs):
        raise AssertionError("evaluated before checking out=")

    monkeypatch.setattr(dcm.evaluate, "evaluate", no_evaluation)
    (tmp_path / "a_file").write_text("")
    dataset = synthetic.read_bytes()
    for out, message in [(tmp_path, f"error: out={tmp_path} cannot be written: {tmp_path} is a directory"),
                         (tmp_path / "a_file" / "m.json",
                          f"error: out={tmp_path / 'a_file' / 'm.json'} cannot be written: {tmp_path / 'a_file'} is "
                          "not a writable directory (File exists)"),
                         (synthetic, f"error: out={synthetic} is also dataset=; writing the metrics there would "
                                     "replace it")]:
        with pytest.raises(SystemExit) as exit_info:
            evaluate_main(["ckpt=copy_demo", f"dataset={synthetic}", "split=test", f"out={out}"])
        assert str(exit_info.value) == message
    assert synthetic.read_bytes() == dataset


def test_a_failed_write_of_the_metrics_is_one_line(synthetic: Path, tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    import contextlib

    import dcm.evaluate

    @contextlib.contextmanager
    def full_disk(target):
        raise OSError(28, "No space left on device")
        yield target

    monkeypatch.setattr(dcm.evaluate, "atomic_path", full_disk)
    out = tmp_path / "metrics.json"
    with pytest.raises(SystemExit) as exit_info:
        evaluate_main(["ckpt=copy_demo", f"dataset={synthetic}", "split=test", f"out={out}"])
    assert str(exit_info.value) == f"error: out={out}: cannot write the metrics: [Errno 28] No space left on device"


def test_a_prior_weight_without_a_prior_is_refused(synthetic: Path) -> None:
    """It would rank with the model alone while the blend was asked for."""
    with pytest.raises(SystemExit) as exit_info:
        evaluate_main(["ckpt=copy_demo", f"dataset={synthetic}", "split=test", "prior_weight=0.5"])
    assert str(exit_info.value) == ("error: prior_weight = 0.5 needs prior=<stiffness reference JSON> to blend with; "
                                    "without it the model ranks alone (prior_weight=0)")


@pytest.mark.parametrize(("setting", "message"), [("seed=abc", "seed = 'abc' must be an integer >= 0"),
                                                  ("seed=-1", "seed = -1 must be an integer >= 0"),
                                                  ("task_from_s=abc", "task_from_s = 'abc' must be a finite number")])
def test_a_bad_number_is_one_line_naming_its_key(synthetic: Path, setting: str, message: str) -> None:
    with pytest.raises(SystemExit) as exit_info:
        evaluate_main(["ckpt=copy_demo", f"dataset={synthetic}", "split=test", setting])
    assert str(exit_info.value) == f"error: {message}"


def test_a_file_that_records_no_phase_count_fits_the_ridge_on_n_phases(synthetic: Path) -> None:
    """Imported robot logs record no phase_stiffness_Npm: the ridge is skipped with the setting that fits it."""
    from dcm.data.datamodule import TrajectoryDataset
    from dcm.data.schema import load_dataset
    from dcm.evaluate import reference_scores

    loaded = load_dataset(synthetic, split="test")
    test = TrajectoryDataset.from_loaded(loaded)
    skipped = reference_scores(synthetic, test, loaded.demo_ids, None)["stiffness_ridge"]
    assert "pass n_phases=<the phases of their stiffness schedules> or reference=<json>" in skipped["skipped"]
    fitted = reference_scores(synthetic, test, loaded.demo_ids, None, n_phases=2)["stiffness_ridge"]
    assert "skipped" not in fitted and fitted["n_phases"] == 2 and "L_task_mae_N" in fitted
