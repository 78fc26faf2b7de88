"""Comparing tune runs on one reference point (studies.tuning_study.compare), on tiny runs of tune.py."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from dcm.tuning.run import tune
from studies.tuning_study.compare import compare
from tests.conftest import short_wave_demo

REPO = Path(__file__).resolve().parents[3]


def _tune(ckpt: Path, tmp_path: Path, name: str, *extra: str) -> tuple[Path, dict]:
    """A tiny tune run of a 2 s wavelike demo in the tool simulator: 8 virtual and 5 robot-based trials."""
    demo = short_wave_demo(tmp_path)
    out_dir = tmp_path / name
    with initialize_config_dir(config_dir=str(REPO / "conf")):
        cfg = compose("tune", overrides=[
            f"ckpt={ckpt}", f"demo_file={demo}", "embodiment=tool", f"out_dir={out_dir}", "robot_free.n_trials=8",
            "robot_free.batch_size=8", "robot_free.n_validate=3", "robot_based.n_trials=5",
            "robot_free.sampling_steps=5",  # DDIM steps must divide the tiny checkpoint's T = 5
            "search.options.n_startup_trials=4", *extra])
    return out_dir, tune(cfg, out_dir)


def test_one_run_reproduces_its_own_numbers_and_runs_of_another_skill_are_refused(tiny_checkpoint: Path,
                                                                                    tmp_path: Path):
    out_dir, results = _tune(tiny_checkpoint, tmp_path, "run")
    report = compare([out_dir], robot_trials=[2, 5])
    assert report["robot_free"][str(out_dir)] == pytest.approx(results["robot_free"]["hypervolume"])
    assert report["robot_based"]["N=5"] == pytest.approx(results["robot_based"]["hypervolume"])
    assert report["robot_based"]["N=2"] <= report["robot_based"]["N=5"]
    with pytest.raises(ValueError, match="first 6"):
        compare([out_dir], robot_trials=[6])

    # Runs of another skill do not share a reference point.
    other = tmp_path / "other"
    other.mkdir()
    changed = json.loads((out_dir / "results.json").read_text())
    changed["skill"]["demo"]["press_m"] = 0.5
    (other / "results.json").write_text(json.dumps(changed))
    with pytest.raises(ValueError, match="tuned another skill .*demo.press_m"):
        compare([out_dir, other], robot_trials=[])


def test_robot_based_prefixes_are_refused_when_solutions_are_judged_over_several_rollouts(tiny_checkpoint: Path,
                                                                                          tmp_path: Path):
    """Validated over 3 rollouts, a run's solutions are judged by their mean; its robot-based trials are one
    draw each, so their prefixes would be judged on other terms."""
    out_dir, _ = _tune(tiny_checkpoint, tmp_path, "run", "validation_rollouts=3", "domain=bowl_offset")
    assert compare([out_dir], robot_trials=[])["robot_free"][str(out_dir)] >= 0.0
    with pytest.raises(ValueError, match="over 3 rollouts each, but its robot-based trials are one draw each"):
        compare([out_dir], robot_trials=[5])
