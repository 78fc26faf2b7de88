"""The robot in the loop on the fast tool embodiment: a full round with the simulator as the robot, the
controller schedule files a real robot gets, resuming with its trials, and the refusals that leave the run as
it was."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from hydra import compose, initialize_config_dir

from dcm.control import damping_from_stiffness, damping_mass
from dcm.data.schema import write_dataset
from dcm.tuning.checks import TuneConfigError, check_config
from dcm.tuning.loop import resume_config
from dcm.tuning.loop_state import LoopState
from dcm.tuning.objectives import OBSERVED_BATCH, PLOT_BATCH, SEARCH_TRIALS_LIMIT, round_batch
from dcm.tuning.observations import ObservationMismatch
from dcm.tuning.robot import SimulatorRobot, trial_record
from dcm.tuning.run import tune
from dcm.tuning.schedule_files import SCHEDULE_COLUMNS
from dcm.tuning.setup import record_skill
from tests.conftest import short_wave_demo

REPO = Path(__file__).resolve().parents[1]


def _config(ckpt: Path, demo: Path, out_dir: Path, *extra: str):
    with initialize_config_dir(config_dir=str(REPO / "conf")):
        return compose("tune", overrides=[
            f"ckpt={ckpt}", f"demo_file={demo}", "embodiment=tool", f"out_dir={out_dir}",
            "robot_free.n_trials=16", "robot_free.batch_size=8", "robot_free.sampling_steps=5",
            "search.options.n_startup_trials=4", "robot_based.n_trials=0", "loop.batch=3", "loop.n_trials=8",
            *extra,
        ])


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _observe(cfg, proposals: np.ndarray, path: Path, **changes) -> Path:
    """The simulator's trials of ``proposals`` as the dataset file a robot's imported logs would be."""
    simulator, demo, skill = record_skill(cfg, check_config(cfg))
    trials = SimulatorRobot(simulator, demo, skill).trials(proposals)
    records = [{**trial_record(t, demo, simulator, i), **changes} for i, t in enumerate(trials)]
    write_dataset(path, records, {"test": [r["name"] for r in records]},
                  {"control_hz": 20.0, "embodiment": "franka_real", "domain": {"name": "real"}})
    return path


def test_the_simulator_robot_runs_rounds_until_the_budget_and_the_same_seed_gives_the_same_bytes(
        tiny_checkpoint: Path, tmp_path: Path):
    demo = short_wave_demo(tmp_path)
    loop = tune(_config(tiny_checkpoint, demo, tmp_path / "a", "robot=sim", "loop.rounds=2", "loop.tolerance_N=0"),
                tmp_path / "a")["loop"]
    # The same run stopped by a budget of one round, then resumed with a budget of two, ends in the same bytes.
    first = tune(_config(tiny_checkpoint, demo, tmp_path / "b", "robot=sim", "loop.rounds=1", "loop.tolerance_N=0"),
                 tmp_path / "b")["loop"]
    assert first["stopped"]["reason"] == "budget" and len(first["rounds"]) == 1
    tune(resume_config(tmp_path / "b", ["loop.rounds=2"]), tmp_path / "b")
    assert [r["n_trials"] for r in loop["rounds"]] == [3, 3]
    assert loop["stopped"]["reason"] == "budget" and loop["observed"]["n_trials"] == 6
    assert loop["observed"]["hypervolume"] >= loop["rounds"][0]["hypervolume_observed"] >= 0.0
    assert loop["rounds"][1]["correction"]["kind"] == "gp"
    state = json.loads((tmp_path / "a/loop/state.json").read_text())
    assert LoopState.from_json(state).to_json() == state  # loop/state.json keeps the format older loops wrote
    first, second = (np.asarray(r["proposals"]) for r in state["rounds"])
    assert not any(np.allclose(k, seen) for k in second for seen in first)  # no schedule is run twice
    for name in ("loop.json", "loop/state.json", "proposals/round_2/round.yaml", "proposals/round_2/p01.csv"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name


def test_files_robot_writes_a_round_and_resuming_with_its_trials_proposes_the_next(tiny_checkpoint: Path,
                                                                                   tmp_path: Path):
    demo, out = short_wave_demo(tmp_path), tmp_path / "run"
    bowl_in_base = "loop.bowl_in_base=[[0,-1,0,0.5],[1,0,0,0.1],[0,0,1,0.2],[0,0,0,1]]"
    cfg = _config(tiny_checkpoint, demo, out, "robot=files", bowl_in_base)
    loop = tune(cfg, out)["loop"]
    assert loop["next"] == {"round": 1, "folder": "proposals/round_1", "n_schedules": 3}
    folder = out / "proposals/round_1"
    spec = yaml.safe_load((folder / "round.yaml").read_text())
    assert spec["round"] == 1 and spec["frame"] == "bowl" and spec["control_hz"] == 20.0
    assert spec["embodiment"] == "tool" and spec["demo"]["duration_s"] == 2.0 and len(spec["proposals"]) == 3
    simulator, recorded, skill = record_skill(cfg, check_config(cfg))
    boundaries = spec["phase_boundaries_steps"]
    for proposal in spec["proposals"]:
        with open(folder / proposal["file"]) as fh:
            assert next(csv.reader(fh)) == SCHEDULE_COLUMNS
        rows = np.loadtxt(folder / proposal["file"], delimiter=",", skiprows=1)
        assert rows.shape == (40, 19)
        np.testing.assert_allclose(rows[:, 0], np.arange(40) / 20.0)
        stiffness, damping = rows[:, 7:13], rows[:, 13:19]
        for p, (start, stop) in enumerate(zip(boundaries[:-1], boundaries[1:])):
            np.testing.assert_allclose(stiffness[start:stop, :3], np.tile(proposal["phase_stiffness_Npm"][p],
                                                                          (stop - start, 1)), rtol=1e-8)
        mass = damping_mass("critical", simulator.apparent_mass)
        np.testing.assert_allclose(damping, damping_from_stiffness(stiffness, mass), rtol=1e-7)
        np.testing.assert_allclose(rows[:, 1:7], simulator.attractor(recorded, stiffness[None])[0], atol=1e-8)
        base = np.loadtxt(folder / proposal["file_base_frame"], delimiter=",", skiprows=1)
        np.testing.assert_allclose(base[:, 1:4], rows[:, 1:4] @ np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]]).T
                                   + [0.5, 0.1, 0.2], atol=1e-8)
        np.testing.assert_allclose(base[:, 8:10], rows[:, [8, 7]], rtol=1e-8)  # Kx, Ky swap on the base axes

    # The robot's trials come back as a dataset file; resuming with them proposes round 2.
    proposals = np.asarray([p["phase_stiffness_Npm"] for p in spec["proposals"]])
    trials = _observe(cfg, proposals, tmp_path / "trials.h5")
    stored = resume_config(out, [f"resume={out}", f"observations={trials}", "loop.rounds=4"])
    assert stored.loop.rounds == 4 and stored.robot == "files"
    with pytest.raises(TuneConfigError, match="seed cannot change"):
        resume_config(out, ["seed=3"])
    loop = tune(stored, out, trials)["loop"]
    assert loop["rounds"][0]["n_trials"] == 3 and loop["next"]["round"] == 2
    assert (out / "proposals/round_2/round.yaml").is_file()
    assert loop["observed"]["hypervolume"] == loop["rounds"][0]["hypervolume_observed"]

    # The same trials again, or trials of another demo or control rate, are refused; the run stays as it was.
    before = _snapshot(out)
    other_demo = _observe(cfg, proposals, tmp_path / "other.h5",
                          demo={**recorded.spec.to_dict(), "press_m": 0.02})
    for path, match in ((trials, "already added as round 1"), (other_demo, r"another demo .*press_m")):
        with pytest.raises(ObservationMismatch, match=match):
            tune(stored, out, path)
        assert _snapshot(out) == before


def test_observations_of_other_phases_or_rates_are_refused_naming_what_differs(tiny_checkpoint: Path,
                                                                              tmp_path: Path):
    demo, out = short_wave_demo(tmp_path), tmp_path / "run"
    cfg = _config(tiny_checkpoint, demo, out, "robot=files")
    spec = tune(cfg, out)["loop"]
    proposals = np.asarray(yaml.safe_load((out / "proposals/round_1/round.yaml").read_text())["proposals"][0]
                           ["phase_stiffness_Npm"])[None]
    before = _snapshot(out)
    simulator, recorded, skill = record_skill(cfg, check_config(cfg))
    trial = SimulatorRobot(simulator, recorded, skill).trials(proposals)[0]
    record = trial_record(trial, recorded, simulator, 0)
    ramp = record["K"].copy()
    ramp[:, 0] = np.linspace(200.0, 900.0, len(ramp))
    cases = {
        "rate.h5": ([record], {"control_hz": 10.0}, "control rate 10 Hz, this run's is 20 Hz"),
        "phases.h5": ([{**record, "K": ramp}], {"control_hz": 20.0}, "Kx changes within phase 1"),
        "domain.h5": ([record], {"control_hz": 20.0, "domain": {"name": "realistic", "friction_scale": 2.0}},
                      "another domain"),
    }
    for name, (records, attrs, match) in cases.items():
        write_dataset(tmp_path / name, records, {"test": ["traj_000000"]}, attrs)
        with pytest.raises(ObservationMismatch, match=match):
            tune(cfg, out, tmp_path / name)
        assert _snapshot(out) == before
    assert spec["next"]["round"] == 1


def test_loop_settings_are_checked_naming_the_key(tiny_checkpoint: Path, tmp_path: Path):
    demo = short_wave_demo(tmp_path)
    for override, match in (("robot=ros", "robot = 'ros'"), ("loop.correction=mlp", "loop.correction"),
                            ("loop.batch=0", "loop.batch = 0"), ("loop.n_trials=3", "loop.n_trials = 3"),
                            ("loop.bowl_in_base=[1,2]", "loop.bowl_in_base"),
                            ("observations=x.h5", "needs resume")):
        with pytest.raises(TuneConfigError, match=match):
            check_config(_config(tiny_checkpoint, demo, tmp_path, override))


def test_the_loop_s_model_seeds_share_batch_seed_s_index_space_without_colliding():
    """Round r's search, the re-prediction of unproposed trials and the figure's prediction are seeded like batches
    no search's own trials reach, and apart from each other."""
    searches = (0, SEARCH_TRIALS_LIMIT - 1)
    rounds = [round_batch(r, first) for r in (2, 3) for first in searches]
    offsets = [*rounds, OBSERVED_BATCH, PLOT_BATCH]
    assert len(set(offsets)) == len(offsets) and min(offsets) >= SEARCH_TRIALS_LIMIT
    assert round_batch(2, SEARCH_TRIALS_LIMIT - 1) < round_batch(3, 0)
    with pytest.raises(ValueError, match="outside"):
        round_batch(2, SEARCH_TRIALS_LIMIT)
