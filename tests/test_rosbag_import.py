"""ROS bag import: simulated trials written as ROS 1 / ROS 2 bags come back as the trials, and as the CSV route
gives; a bag without a needed topic, or with the wrong message on it, is refused in one line."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from dcm.data.import_logs import LogFormatError, import_logs, main
from dcm.data.log_writer import RobotConventions
from dcm.data.schema import FIELDS, load_dataset
from dcm.data.sim_logs import load_demo_spec, random_schedules, trial_signals, write_episode
from dcm.sim.rollout import Simulator

# ROS 2 layouts: the episode folder is the bag directory itself (sqlite3); a lone .mcap next to meta.json.
SOURCES = [("ros1", "sqlite3"), ("ros2", "sqlite3"), ("ros2", "mcap")]


def _relayout(episode: Path, storage: str) -> None:
    bag_dir = episode / "trial"
    if storage == "sqlite3":
        for path in bag_dir.iterdir():
            path.rename(episode / path.name)
    else:
        (bag_dir / "trial.mcap").rename(episode / "trial.mcap")
        for path in bag_dir.iterdir():
            path.unlink()
    bag_dir.rmdir()


@pytest.fixture(scope="module")
def sim_trials() -> tuple[object, list[object]]:
    """Two simulated trials of a 2 s wavelike demo on the tool (well under a second)."""
    sim = Simulator("tool")
    demo = sim.record_demo(load_demo_spec("wavelike", 2.0))
    schedules = random_schedules(demo.horizon, 2, np.random.default_rng(0))
    return demo, [sim.rollout(demo, schedule) for schedule in schedules]


def _write(root: Path, fmt: str, storage: str, demo: object, trials: list[object], conventions: RobotConventions,
           seed: int = 5) -> Path:
    rng = np.random.default_rng(seed)
    for i, trial in enumerate(trials):
        meta = {"demo_id": 0, "trial": i, "split": "train"}
        write_episode(root / f"episode_{i:03d}", trial_signals(demo, trial, 20.0, meta), fmt, conventions, rng, storage)
    return root


@pytest.mark.parametrize(("fmt", "storage"), SOURCES)
def test_bag_round_trip_returns_the_simulated_trial(tmp_path: Path, sim_trials: tuple, fmt: str, storage: str) -> None:
    """Without bias, noise, jitter or low-pass the import is exact up to float32 storage and the quaternion of
    the equilibrium pose; the conversions (base frame turned 90°, 0.1 m tool, column-major O_T_EE, wrench about
    the end effector, base-axis stiffness) all run and must cancel."""
    demo, trials = sim_trials
    logs = _write(tmp_path / "logs", fmt, storage, demo, trials, RobotConventions.clean())
    if fmt == "ros2":
        for episode in logs.iterdir():
            _relayout(episode, storage)
    out = tmp_path / "real.h5"
    assert import_logs(logs, out, lowpass_hz=0.0) == 2
    data = load_dataset(out, split="train", expect_control_hz=20.0)
    assert data.horizon == demo.horizon
    for k, trial in enumerate(trials):
        np.testing.assert_allclose(data.arrays["x_obs"][k], trial.x_obs, atol=1e-6)
        np.testing.assert_allclose(data.arrays["F_obs"][k], trial.force_obs, atol=1e-4)
        np.testing.assert_allclose(data.arrays["K"][k], trial.stiffness, rtol=1e-6)
        np.testing.assert_allclose(data.arrays["x_attr"][k], trial.x_attr, atol=1e-6)
        np.testing.assert_allclose(data.arrays["x_demo"][k], demo.x_demo, atol=1e-6)
        np.testing.assert_allclose(data.arrays["F_demo"][k], demo.force_demo, atol=1e-4)
        assert data.meta[k]["demo"]["family"] == "wavelike"


def test_csv_and_bag_routes_give_the_same_dataset(tmp_path: Path, sim_trials: tuple) -> None:
    """The same robot-side streams (bias, noise, jitter), imported with the default low-pass, from a CSV folder,
    a ROS 1 bag and a ROS 2 MCAP bag."""
    demo, trials = sim_trials
    loaded = {}
    for fmt, storage in [("csv", "sqlite3"), ("ros1", "sqlite3"), ("ros2", "mcap")]:
        logs = _write(tmp_path / fmt, fmt, storage, demo, trials, RobotConventions())
        import_logs(logs, tmp_path / f"{fmt}.h5")
        loaded[fmt] = load_dataset(tmp_path / f"{fmt}.h5", split="train")
    csv_data = loaded["csv"]
    assert np.abs(csv_data.arrays["F_obs"] - np.stack([t.force_obs for t in trials])).mean() < 0.5  # sanity
    for fmt in ("ros1", "ros2"):
        for name in FIELDS:
            np.testing.assert_allclose(loaded[fmt].arrays[name], csv_data.arrays[name], atol=1e-6, err_msg=f"{fmt} {name}")
        np.testing.assert_allclose(loaded[fmt].L_task, csv_data.L_task, rtol=1e-6)
        for meta_bag, meta_csv in zip(loaded[fmt].meta, csv_data.meta):
            np.testing.assert_allclose(meta_bag["bias_removed"], meta_csv["bias_removed"], atol=1e-9)
            assert meta_bag["episode"] == meta_csv["episode"]


def test_a_ros2_bag_without_message_definitions_decodes_with_the_registered_ones(tmp_path: Path,
                                                                                sim_trials: tuple) -> None:
    """ROS 2 Humble's .db3 stores no message definitions: the franka_msgs definitions of the package decode it."""
    import sqlite3

    import yaml

    demo, trials = sim_trials
    logs = _write(tmp_path / "logs", "ros2", "sqlite3", demo, trials[:1], RobotConventions.clean())
    bag = logs / "episode_000" / "trial"
    with sqlite3.connect(bag / "trial.db3") as db:
        db.execute("DELETE FROM message_definitions")
    metadata = yaml.safe_load((bag / "metadata.yaml").read_text())
    for topic in metadata["rosbag2_bagfile_information"]["topics_with_message_count"]:
        topic["topic_metadata"].pop("type_description_hash")
    (bag / "metadata.yaml").write_text(yaml.safe_dump(metadata))
    import_logs(logs, tmp_path / "real.h5", lowpass_hz=0.0)
    data = load_dataset(tmp_path / "real.h5", split="train")
    np.testing.assert_allclose(data.arrays["F_obs"][0], trials[0].force_obs, atol=1e-4)


def test_a_bag_without_a_needed_topic_is_refused_in_one_line(tmp_path: Path, sim_trials: tuple,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    demo, trials = sim_trials
    logs = _write(tmp_path / "logs", "ros1", "sqlite3", demo, trials[:1], RobotConventions.clean())
    bag = logs / "episode_000" / "trial.bag"
    out = tmp_path / "real.h5"
    assert main([str(logs), "--out", str(out), "--stiffness-topic", "/my_controller/stiffness"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{bag}: no stiffness topic '/my_controller/stiffness'" in err
    assert not out.exists()
    with pytest.raises(LogFormatError, match=r"trial.bag topic /franka_state_controller/franka_states: type "
                                             r"franka_msgs/msg/FrankaState is not a stiffness message"):
        import_logs(logs, out, topics={"stiffness": "/franka_state_controller/franka_states"})
    (logs / "episode_000" / "extra.bag").write_bytes(b"")
    with pytest.raises(LogFormatError, match=r"episode_000: holds 2 bags \(extra.bag, trial.bag\)"):
        import_logs(logs, out)
    (logs / "episode_000" / "extra.bag").unlink()
    bag.write_bytes(bag.read_bytes()[:5000])  # a truncated recording
    with pytest.raises(LogFormatError, match=r"trial.bag: not a readable ROS bag"):
        import_logs(logs, out)


def test_a_topic_without_messages_is_refused(tmp_path: Path) -> None:
    from rosbags.rosbag1 import Writer

    from dcm.data.franka_msgs import STATE_TYPE, franka_typestore
    from dcm.data.log_writer import write_csv
    from dcm.data.rosbag_logs import DEFAULT_TOPICS

    episode = tmp_path / "logs" / "episode_000"
    episode.mkdir(parents=True)
    (episode / "meta.json").write_text('{"demo_id": 0, "split": "train", '
                                       '"bowl_in_base": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]], '
                                       '"free_motion_s": [0, 1], "base_frame": "panda_link0"}')
    write_csv(episode / "demo.csv", ["t"] + ["v"] * 12, np.array([0.0, 1.0]), np.zeros((2, 12)))
    store = franka_typestore(False)
    with Writer(episode / "trial.bag") as writer:
        writer.add_connection(DEFAULT_TOPICS["state"], STATE_TYPE, typestore=store)
    with pytest.raises(LogFormatError, match=r"trial.bag topic /franka_state_controller/franka_states: no messages"):
        import_logs(tmp_path / "logs", tmp_path / "real.h5")


def test_topics_from_a_yaml_map(tmp_path: Path) -> None:
    from argparse import ArgumentParser

    from dcm.data.rosbag_logs import add_topic_arguments, topics_from_arguments

    parser = ArgumentParser()
    add_topic_arguments(parser)
    (tmp_path / "topics.yaml").write_text("state: /robot/state\nequilibrium: null\n")
    topics = topics_from_arguments(parser.parse_args(["--topics", str(tmp_path / "topics.yaml"),
                                                      "--stiffness-topic", "/robot/K"]))
    assert topics == {"state": "/robot/state", "stiffness": "/robot/K", "equilibrium": None}
    (tmp_path / "bad.yaml").write_text("pose: /robot/state\n")
    with pytest.raises(LogFormatError, match=r"bad.yaml: expected a map with keys among"):
        topics_from_arguments(parser.parse_args(["--topics", str(tmp_path / "bad.yaml")]))


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q"]))
