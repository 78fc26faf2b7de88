"""dcm-sim-logs: simulated trials as robot logs, random or a tuner's round of proposals, refusals in one line."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
import yaml

from dcm.data.import_logs import import_logs
from dcm.data.schema import load_dataset
from dcm.data.sim_logs import PROPOSAL_K, load_demo_spec, main
from dcm.sim.rollout import Simulator

HEADER = (["t_s", "x_m", "y_m", "z_m", "rx_rad", "ry_rad", "rz_rad"] + PROPOSAL_K
          + ["Dx_Nspm", "Dy_Nspm", "Dz_Nspm", "Drx_Nmsprad", "Dry_Nmsprad", "Drz_Nmsprad"])


def _round(tmp_path: Path, levels: list[list[float]]) -> tuple[Path, list[np.ndarray]]:
    """A proposals/round_1 folder as the tuner writes it: round.yaml and one CSV per proposal."""
    spec = load_demo_spec("wavelike", 2.0)
    sim = Simulator("tool")
    demo = sim.record_demo(spec)
    round_dir = tmp_path / "run" / "proposals" / "round_1"
    round_dir.mkdir(parents=True)
    proposals, schedules = [], []
    for i, phase_levels in enumerate(levels):
        K = np.full((demo.horizon, 6), 20.0)
        for phase, rows in enumerate(np.array_split(np.arange(demo.horizon), len(phase_levels))):
            K[rows, :3] = phase_levels[phase]
        attractor = sim.attractor(demo, K)
        table = np.column_stack([np.arange(demo.horizon) / 20.0, attractor, K, 2 * np.sqrt(K)])
        with (round_dir / f"p{i}.csv").open("w", newline="") as handle:
            csv.writer(handle).writerows([HEADER] + table.tolist())
        proposals.append({"id": f"p{i}", "file": f"p{i}.csv", "phase_stiffness_Npm": [[v] * 3 for v in phase_levels]})
        schedules.append(K)
    (round_dir / "round.yaml").write_text(yaml.safe_dump({
        "round": 1, "control_hz": 20.0, "demo": spec.to_dict(), "embodiment": "tool", "frame": "bowl",
        "proposals": proposals}))
    return round_dir, schedules


def test_a_round_of_proposals_becomes_one_episode_per_proposal(tmp_path: Path) -> None:
    round_dir, schedules = _round(tmp_path, [[300.0, 900.0], [1200.0, 500.0]])
    out = tmp_path / "logs"
    assert main(["--schedules", str(round_dir), "--format", "ros2", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["p0", "p1"]
    import_logs(out, tmp_path / "observed.h5")
    data = load_dataset(tmp_path / "observed.h5", split="train")
    assert [m["proposal"] for m in data.meta] == ["p0", "p1"] and {m["round"] for m in data.meta} == {1}
    for k, K in enumerate(schedules):
        np.testing.assert_allclose(data.arrays["K"][k], K)
    assert data.meta[0]["demo"]["duration_s"] == 2.0


def test_bad_rounds_and_outputs_are_refused_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    round_dir, _ = _round(tmp_path, [[300.0, 900.0]])
    out = tmp_path / "logs"
    assert main(["--schedules", str(round_dir), "--trials", "3", "--out", str(out)]) == 1
    assert "drop --trials" in capsys.readouterr().err
    assert main(["--seed", "-1", "--out", str(out)]) == 1
    assert capsys.readouterr().err == "error: --seed -1: must be an integer >= 0\n"
    rows = (round_dir / "p0.csv").read_text().splitlines()
    shifted = np.array([r.split(",") for r in rows[1:]], dtype=float)
    shifted[20:, 1] += 0.005  # another demo's attractor from step 20 on
    (round_dir / "p0.csv").write_text("\n".join([rows[0]] + [",".join(map(repr, r)) for r in shifted.tolist()]) + "\n")
    assert main(["--schedules", str(round_dir), "--out", str(out)]) == 1
    assert "p0: attractor at step 20 is 5.0 mm from the one the simulator computes" in capsys.readouterr().err
    (round_dir / "p0.csv").write_text("\n".join(rows[:-5]) + "\n")
    assert main(["--schedules", str(round_dir), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "p0: 35 rows, the round's demo has 40 control steps" in err
    assert not out.exists()
    out.mkdir()
    (out / "keep.txt").write_text("earlier logs")
    assert main(["--trials", "1", "--duration-s", "2", "--out", str(out)]) == 1
    assert "exists and is not empty" in capsys.readouterr().err
    assert (out / "keep.txt").read_text() == "earlier logs" and len(list(out.iterdir())) == 1
    surface = yaml.safe_load((round_dir / "round.yaml").read_text())
    (round_dir / "round.yaml").write_text(yaml.safe_dump({**surface, "stiffness_frame": "surface"}))
    assert main(["--schedules", str(round_dir), "--out", str(tmp_path / "surface")]) == 1
    assert "stiffness_frame 'surface'; the simulated logs record a diagonal K" in capsys.readouterr().err


def test_same_seed_same_bytes(tmp_path: Path) -> None:
    for name in ("a", "b"):
        assert main(["--trials", "2", "--duration-s", "2", "--seed", "3", "--out", str(tmp_path / name)]) == 0
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert len(files) == 12
    assert all((tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes() for f in files)


def test_a_trial_that_diverged_in_the_simulator_is_imported_as_failed(tmp_path: Path) -> None:
    """dcm-sim-logs records a diverged rollout as sim_failure; the import stores it as generation stores a failed
    trial: kept with its reason and L_task = inf, out of the splits, so training skips it and a tuner sees NaN."""
    import json

    out = tmp_path / "logs"
    assert main(["--trials", "4", "--duration-s", "2", "--out", str(out)]) == 0
    meta_path = out / "episode_001" / "meta.json"
    meta = json.loads(meta_path.read_text())
    assert meta["split"] == "train" and "sim_failure" not in meta
    meta["sim_failure"] = "step 12 (t = 0.60 s): tool left the bowl"
    meta_path.write_text(json.dumps(meta))
    import_logs(out, tmp_path / "observed.h5")
    everything = load_dataset(tmp_path / "observed.h5", include_failed=True)
    by_episode = {m["episode"]: m for m in everything.meta}
    assert by_episode["episode_001"]["failed"] and not by_episode["episode_000"]["failed"]
    assert by_episode["episode_001"]["failure_reason"] == "step 12 (t = 0.60 s): tool left the bowl"
    assert by_episode["episode_001"]["L_task"] == float("inf")
    train = load_dataset(tmp_path / "observed.h5", split="train")
    assert [m["episode"] for m in train.meta] == ["episode_000"]


def test_random_trials_split_a_fifth_each_to_valid_and_test(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """20 trials give valid and test 4 each, as many as every ranking metric needs; 5 give 1 each and say so."""
    import json

    from dcm.data.sim_logs import RANKING_TRIALS
    from dcm.models.metrics import REGRET_TRIALS

    assert RANKING_TRIALS == REGRET_TRIALS  # the copy this command keeps to load without torch
    for trials, counts in ((20, {"train": 12, "valid": 4, "test": 4}), (5, {"train": 3, "valid": 1, "test": 1})):
        out = tmp_path / f"logs{trials}"
        assert main(["--trials", str(trials), "--duration-s", "1", "--out", str(out)]) == 0
        splits = [json.loads((episode / "meta.json").read_text())["split"] for episode in sorted(out.iterdir())]
        assert {split: splits.count(split) for split in set(splits)} == counts
        assert splits == sorted(splits, key=["train", "valid", "test"].index)  # the last trials are held out
        note = [line for line in capsys.readouterr().err.splitlines() if line.startswith("note:")]
        assert note == ([] if trials == 20 else [
            "note: valid and test get 1 trial(s) each; the ranking metrics (R within skill, top-3 regret) need >= 4 "
            "trials of a skill per split: --trials 18 gives 4 each"])


@pytest.mark.parametrize("fmt", ["ros1", "csv"])
def test_a_bag_storage_for_a_format_without_one_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                           fmt: str) -> None:
    out = tmp_path / "logs"
    assert main(["--format", fmt, "--storage", "mcap", "--trials", "1", "--duration-s", "1", "--out", str(out)]) == 1
    assert capsys.readouterr().err == (f"error: --storage mcap: the storage of a ROS 2 bag (sqlite3, mcap); --format "
                                       f"{fmt} has none: drop --storage or use --format ros2\n")
    assert not out.exists() and not list(tmp_path.iterdir())
