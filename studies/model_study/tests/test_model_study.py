"""A model study end to end on the tiny data: the experiment's sweep, its report, a re-run, the submitit launcher."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from dcm.configs import config_diff
from dcm.training.train import with_added_option_defaults
from studies.model_study.__main__ import main as study_main
from studies.model_study.stats import welch_test
from tests.test_train_cli import TINY, _run

REPO = Path(__file__).resolve().parents[3]
STUDY_CONF = ["--config-dir", str(REPO / "studies" / "conf")]  # the experiments, beside the product's conf
# 2 settings x 2 seeds of the diffusion-steps study, 1 epoch each; T = 30 is the study's reference setting
SWEEP = ["-m", *STUDY_CONF, "+experiment=diffusion_steps", "model.diffusion_steps=1,30", "seed=0,1"]


@pytest.fixture(scope="module")
def study(tiny_dataset_path: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str]]:
    root = tmp_path_factory.mktemp("study")
    args = [str(REPO / "train.py"), *SWEEP, f"data.path={tiny_dataset_path}", *TINY,
            f"hydra.sweep.dir={root / 'sweep'}"]
    _run(args, cwd=root)
    return root, args


def test_report_aggregates_seeds_beside_references_with_tests(study: tuple[Path, list[str]]) -> None:
    root, _ = study
    paths = study_main([str(root / "sweep"), "--out", str(root / "report")])
    result = json.loads(paths["json"].read_text())
    assert [c["label"] for c in result["cells"]] == ["model.diffusion_steps=30", "model.diffusion_steps=1"]
    for cell in result["cells"]:
        assert cell["n_seeds"] == 2 and sorted(r["seed"] for r in cell["runs"]) == [0, 1]
        for split in ("valid", "test"):
            assert cell["summary"][split]["force_rmse_N"]["n"] == 2
            assert {"mean", "std", "median", "min", "max"} <= set(cell["summary"][split]["L_MSE"])
    assert result["references"]["test"]["copy-F_demo"]["force_rmse_N"] > 0
    tests = [t for t in result["tests"] if t["split"] == "valid" and t["metric"] == "R_within"]
    assert len(tests) == 1 and tests[0]["against"] == "model.diffusion_steps=30" and tests[0]["n_against"] == 2
    md = paths["md"].read_text()
    assert "| model.diffusion_steps=1 | 2 |" in md and "| copy-F_demo |" in md and "+experiment=diffusion_steps" in md
    assert "Evaluations ran on:" in md and paths["png"].stat().st_size > 10_000
    # each setting names the command that trains it, from its runs' own overrides, not the sweep's last launch
    commands = {c["label"]: c["command"] for c in result["cells"]}
    assert "model.diffusion_steps=1 " in commands["model.diffusion_steps=1"]
    assert all("seed=0,1" in c and f"hydra.sweep.dir={root / 'sweep'}" in c for c in commands.values())
    assert all(f"`{c}`" in md for c in commands.values())
    assert list((root / "sweep").glob("*/eval_tiny_valid.json")), "evaluations are cached next to the runs"


def test_rerun_skips_finished_runs_and_submitit_runs_the_new_ones(study: tuple[Path, list[str]]) -> None:
    root, args = study
    before = {p: p.stat().st_mtime_ns for p in (root / "sweep").glob("*/checkpoints/last.ckpt")}
    for saved in (root / "sweep").glob("*/config.yaml"):  # runs launched before the study block was edited
        saved.write_text(saved.read_text().replace("title: ", "title: Before an edit, "))
    proc = _run(args, cwd=root)  # the study block says how to report, not what to train
    assert proc.stdout.count("with the same config (summary.json): skipped") == 4, proc.stdout[-2000:]
    # extend the sweep by T = 2 with the submitit launcher's local executor: T = 1 is skipped, T = 2 trains
    extended = [a if a != "model.diffusion_steps=1,30" else "model.diffusion_steps=1,2" for a in args]
    _run([*[a for a in extended if a != "seed=0,1"], "seed=0", "hydra/launcher=submitit_local",
          "hydra.launcher.timeout_min=5"], cwd=root)
    after = {p: p.stat().st_mtime_ns for p in before}
    assert after == before, "a finished run was trained again"
    new = [p for p in (root / "sweep").glob("*diffusion_steps-2__*") if p.is_dir()]
    assert len(new) == 1 and (new[0] / "summary.json").is_file()


def test_a_run_older_than_a_model_or_net_option_is_reused_while_the_option_keeps_its_default(
        study: tuple[Path, list[str]]) -> None:
    root, args = study
    config = next((root / "sweep").glob("*diffusion_steps-30__*seed-0__*")) / "config.yaml"
    saved = OmegaConf.load(config)
    del saved.model["cond_encoding"], saved.net["bidirectional"]  # as written before the options existed
    OmegaConf.save(saved, config)
    one_run = [a for a in args if a not in ("model.diffusion_steps=1,30", "seed=0,1")]
    proc = _run([*one_run, "model.diffusion_steps=30", "seed=0"], cwd=root)
    assert "with the same config (summary.json): skipped" in proc.stdout, proc.stdout[-2000:]
    # the same old run asked for with the options away from their defaults is another config
    planned = OmegaConf.to_container(saved)
    planned["model"] = {**planned["model"], "cond_encoding": "physical"}
    planned["net"] = {**planned["net"], "bidirectional": True}
    old = with_added_option_defaults(OmegaConf.to_container(saved), planned)
    assert config_diff(old, planned) == ["model.cond_encoding: (absent) -> physical",
                                         "net.bidirectional: (absent) -> True"]


def test_bad_sweep_dir_is_one_line_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        study_main([str(tmp_path / "nosuch")])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and len(err.splitlines()) == 1
    assert err.startswith("error: ") and str(tmp_path / "nosuch") in err


def test_welch_test_known_answer() -> None:
    # means 2 and 5, both variances 1, n = 3: t = -3 / sqrt(2/3) = -3.674, df = 4, two-sided p = 0.0213
    result = welch_test([1.0, 2.0, 3.0], [4.0, 5.0, 6.0])
    assert result["t"] == pytest.approx(-3.6742, abs=1e-4) and result["df"] == pytest.approx(4.0)
    assert result["p"] == pytest.approx(0.021312, abs=1e-5) and result["difference"] == pytest.approx(-3.0)
    assert welch_test([1.0], [2.0, 3.0])["p"] is None  # one seed: no test
    assert welch_test([1.0, float("nan"), 1.0], [1.0, 1.0])["p"] is None  # NaN dropped; no spread: no test


def test_usage_rate_study_fits_the_ridge_on_each_runs_own_training_subset(tiny_dataset_path: Path,
                                                                           tmp_path: Path) -> None:
    from dcm.data.datamodule import DCMDataModule

    _run([str(REPO / "train.py"), "-m", *STUDY_CONF, "+experiment=usage_rate", "model=baseline", "usage_rate=0.5,1.0",
          "seed=3", f"data.path={tiny_dataset_path}", *TINY, f"hydra.sweep.dir={tmp_path / 'sweep'}"],
         cwd=tmp_path)
    result = json.loads(study_main([str(tmp_path / "sweep"), "--out", str(tmp_path / "report")])["json"].read_text())
    ridges = {c["values"]["usage_rate"]: c for c in result["cells"] if c["values"]["model"] == "stiffness_ridge"}
    assert set(ridges) == {0.5, 1.0} and all(c["n_seeds"] == 1 and c["command"] == "" for c in ridges.values())
    fitted = json.loads((tmp_path / "sweep" / "ridge" / "usage_rate-0.5__seed-3" / "stiffness_ridge.json").read_text())
    dm = DCMDataModule(tiny_dataset_path, usage_rate=0.5, seed=3)
    dm.setup("fit")  # the subset the baseline trained on, and the one the ridge was fitted on
    assert fitted["fit"]["n_trajectories"] == len(dm.split("train")) < dm.n_train_total
    assert fitted["fit"]["subset"] == f"{len(dm.split('train'))} of {dm.n_train_total} trajectories"
    md = (tmp_path / "report" / "study.md").read_text()
    assert "| model=stiffness_ridge, usage_rate=0.5 | 1 |" in md and "each run's own training subset" in md
    tests = [t for t in result["tests"] if t["cell"] == "model=stiffness_ridge, usage_rate=0.5"]
    assert tests and all(t["against"] == "model=baseline, usage_rate=0.5" for t in tests)


def test_small_values_keep_their_digits_in_the_report() -> None:
    """A normalised L_MSE of ~1e-3 must not print as 0.001 ± 0.000 for every setting."""
    from studies.model_study.report import _cell_text

    small = {"n": 3, "mean": 1.234e-3, "std": 5.6e-5, "min": 1.17e-3, "max": 1.3e-3}
    assert _cell_text(small) == "1.23e-03 ± 5.60e-05 [1.17e-03–1.30e-03]"
    assert _cell_text({"n": 3, "mean": 0.8456, "std": 0.02, "min": 0.82, "max": 0.87}) == "0.846 ± 0.020 [0.820–0.870]"
    assert _cell_text({"n": 1, "mean": 0.0}) == "0.000"


def test_the_figure_draws_a_numeric_sweep_in_x_order(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The compared-against setting comes first in the cells (T = 30 before T = 1); the line must not zigzag."""
    import matplotlib.axes

    from studies.model_study.report import figure

    drawn: list[list[float]] = []
    original = matplotlib.axes.Axes.errorbar
    monkeypatch.setattr(matplotlib.axes.Axes, "errorbar",
                        lambda self, x, y, **kw: (drawn.append(list(x)), original(self, x, y, **kw))[1])
    summary = {"R_within": {"n": 3, "mean": 0.5, "std": 0.1}}
    cells = [{"values": {"T": t}, "summary": {"valid": summary}} for t in (30, 1, 5, 100)]
    study = {"study": {"x": "T", "series": None, "metrics": ["R_within"], "title": "T", "name": "T", "log_x": True},
             "cells": cells, "splits": {"valid": {}}, "references": {}}
    figure(study, tmp_path / "study.png")
    assert drawn == [[1, 5, 30, 100]] and (tmp_path / "study.png").is_file()

    # categorical x, two series: the reference net first on the axis, each series' line in axis order
    drawn.clear()
    cells = [{"values": {"model": m, "net": n}, "summary": {"valid": summary}}
             for m, n in (("baseline", "unet1d"), ("dcm", "retnet"), ("dcm", "lstm"), ("dcm", "unet1d"))]
    study["study"] = {**study["study"], "x": "net", "series": "model", "log_x": False,
                      "comparisons": [["net", "retnet"], ["model", "baseline"]]}
    study["cells"] = cells
    figure(study, tmp_path / "study.png")
    assert drawn == [[1.0], [0.08, 1.08, 2.08]]  # axis: retnet, unet1d, lstm (cell order after the reference)


def test_a_study_tests_along_each_of_its_comparisons_and_takes_the_newest_runs_spec(tmp_path: Path) -> None:
    """The score-net study tests every net against the RetNet and, per net, the DCM against the baseline; a
    run launched after the experiment's study block gained the second comparison carries it."""
    import os

    import yaml

    from studies.model_study.collect import compare, make_cells
    from studies.model_study.runs import StudyError, read_run, setting_keys, study_spec

    old = {"name": "nets", "title": "", "x": "net", "series": None, "compare": {"key": "net", "against": "retnet"}}
    new = {**old, "series": "model", "compare": [{"key": "net", "against": "retnet"},
                                                 {"key": "model", "against": "baseline"}]}
    settings = [("dcm", "retnet", old), ("dcm", "unet1d", old), ("baseline", "unet1d", new)]
    runs = []
    for i, (model, net, block) in enumerate(settings * 2):
        seed = i // len(settings)
        path = tmp_path / f"{model}-{net}-{seed}"
        (path / ".hydra").mkdir(parents=True)
        overrides = [f"net={net}", f"seed={seed}"] + (["model=baseline"] if model == "baseline" else [])
        (path / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(overrides))
        (path / ".hydra" / "hydra.yaml").write_text(
            yaml.safe_dump({"hydra": {"runtime": {"choices": {"model": model, "net": net}}}}))
        (path / "config.yaml").write_text(yaml.safe_dump({"seed": seed, "study": block}))
        os.utime(path / "config.yaml", ns=(i, i))  # launched in this order, the baseline runs last
        runs.append(read_run(path))
    spec = study_spec(runs)
    assert spec.series == "model" and spec.comparisons == (("net", "retnet"), ("model", "baseline"))
    keys = setting_keys(spec, runs)
    cells = make_cells(runs, keys, spec)
    for cell in cells:
        cell.scores["valid"] = [{"R_within": 0.5 + 0.01 * r.seed} for r in cell.runs]
    tests = {(t["cell"], t["against"]) for t in compare(cells, spec, ["valid"], keys)}
    assert tests == {("model=dcm, net=unet1d", "model=dcm, net=retnet"),
                     ("model=dcm, net=unet1d", "model=baseline, net=unet1d")}
    runs[-1].config["study"]["compare"] = "model"  # neither {key, against} nor a list of them
    with pytest.raises(StudyError, match=rf"{runs[-1].path.name}/config.yaml: study.compare must be"):
        study_spec(runs)
