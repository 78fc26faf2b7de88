"""studies.task_checks.sensor_check: the ranking ceiling that a robot's F/T sensor noise sets, on cases with
known answers."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dcm.control.objectives import task_loss
from dcm.sim.domain import DomainSpec
from studies.task_checks.sensor_check import main, sensed_task_losses, skill_rows


def _skill(rng: np.random.Generator, spread: float, n: int = 40, H: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """n trials of one demo whose force error is a constant offset of size 0.1 + spread * U(0, 1) N on Fz."""
    demo = np.zeros((H, 6))
    demo[:, 2] = 5.0 + np.sin(np.linspace(0, 6, H))
    offsets = 0.1 + spread * rng.uniform(size=n)
    trials = np.repeat(demo[None], n, axis=0)
    trials[:, :, 2] += offsets[:, None]
    return trials, np.repeat(demo[None], n, axis=0)


def test_a_sensor_blurs_small_differences_and_keeps_large_ones() -> None:
    rng = np.random.default_rng(0)
    small, big = _skill(rng, 0.002), _skill(rng, 3.0)
    F_obs, F_demo = np.concatenate([small[0], big[0]]), np.concatenate([small[1], big[1]])
    skills = np.repeat(["small", "big"], 40)
    realistic = DomainSpec.preset("realistic")
    L = sensed_task_losses(F_obs, F_demo, skills, realistic, 0.05, 6, np.random.default_rng(1))
    truth = np.abs(F_obs - F_demo)[:, :, 2].mean(axis=1)  # a constant offset: L_task is its size
    rows = {r["skill"]: r for r in skill_rows(truth, L, skills)}
    assert rows["big"]["R_label_truth"] > 0.98 and rows["big"]["R_label_label"] > 0.98
    assert abs(rows["small"]["R_label_truth"]) < 0.5 and rows["small"]["label_noise_sd_N"] > 5 * rows["small"]["L_task_sd_N"]
    # the bias is tared away: the same session with and without it reads the same L_task
    biased = replace(realistic, ft_bias=(5.0,) * 6)
    same = sensed_task_losses(F_obs, F_demo, skills, biased, 0.05, 2, np.random.default_rng(1))
    assert np.array_equal(same, L[:2])
    # no sensing effects: every reading is the stored force, both Rs are 1
    quiet = sensed_task_losses(F_obs, F_demo, skills, DomainSpec.preset("nominal"), 0.05, 2, np.random.default_rng(1))
    assert np.array_equal(quiet, np.stack([task_loss(F_obs, F_demo)] * 2))


def test_cli_on_a_dataset_file(tiny_dataset_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "check"
    results = main(["--sets", f"{tiny_dataset_path}:valid", "--domain", "nominal", "--draws", "3", "--out", str(out)])
    (row,) = results[0]["skills"]
    assert row["R_label_truth"] == pytest.approx(1.0) and row["R_label_label"] == pytest.approx(1.0)
    assert row["label_noise_sd_N"] == pytest.approx(0.0, abs=1e-12)
    saved = json.loads(out.with_suffix(".json").read_text())
    assert saved["sets"][0]["skills"][0]["n"] == row["n"] and "R: two readings" in out.with_suffix(".md").read_text()
    noisy = main(["--sets", f"{tiny_dataset_path}:valid", "--draws", "3", "--seed", "4"])
    assert noisy == main(["--sets", f"{tiny_dataset_path}:valid", "--draws", "3", "--seed", "4"])  # seeded
    assert noisy[0]["skills"][0]["label_noise_sd_N"] > 0
    capsys.readouterr()


@pytest.mark.parametrize("args, named", [
    (["--sets", "nowhere.h5"], "FILE.h5:SPLIT"),
    (["--sets", "nowhere.h5:valid"], "nowhere.h5:valid"),
    (["--draws", "1"], "--draws 1"),
    (["--noise-scale", "-1"], "--noise-scale -1"),
    (["--domain", "moon"], "moon"),
])
def test_bad_input_is_named(args: list[str], named: str, tiny_dataset_path: Path,
                            capsys: pytest.CaptureFixture[str]) -> None:
    argv = args if args[0] == "--sets" else ["--sets", f"{tiny_dataset_path}:valid", *args]
    with pytest.raises(SystemExit):
        main(argv)
    assert named in capsys.readouterr().err
