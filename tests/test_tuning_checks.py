"""tune.py's settings are checked before any long work, each failure one line naming the setting."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
from hydra import compose, initialize_config_dir

from dcm.models.configuration import DataSpec
from dcm.tuning.checks import TuneConfigError, check_config, check_predictor, min_compliance_loss

REPO = Path(__file__).resolve().parents[1]
OK = ["ckpt=some.ckpt", "embodiment=tool"]


def _cfg(*overrides: str):
    with initialize_config_dir(config_dir=str(REPO / "conf")):
        return compose("tune", overrides=[*OK, *overrides])


def test_the_sampler_names_are_the_models():
    """The check keeps its own list, so tune.py refuses a bad sampler without importing torch."""
    from dcm.models.diffusion import SAMPLERS as MODEL_SAMPLERS
    from dcm.tuning.checks import SAMPLERS

    assert SAMPLERS == MODEL_SAMPLERS


def test_a_loss_over_samples_that_barely_differ_is_named():
    from dcm.tuning.diagnostics import spread_warning

    why = spread_warning("ddim_even", 16, "over_samples")
    assert why is not None and "robot_free.sampler=ddim robot_free.sampling_steps=3" in why
    for quiet in [("ddim", 16, "over_samples"), ("ddim_even", 1, "over_samples"), ("ddim_even", 16, "of_mean")]:
        assert spread_warning(*quiet) is None


def test_the_default_settings_pass():
    checked = check_config(_cfg())
    assert checked.spec.horizon(20.0) > 0 and checked.reference is None
    assert checked.space.min_Npm == 100.0 and checked.space.max_Npm == 1500.0


@pytest.mark.parametrize("overrides, message", [
    (["stiffness.max_Npm=1e+06"], "stiffness.max_Npm = 1e+06 is above the controller's limit 3000 N/m"),
    (["stiffness.min_Npm=5"], "stiffness.min_Npm = 5 is below the controller's limit 10 N/m"),
    (["stiffness.min_Npm=900", "stiffness.max_Npm=800"],
     "stiffness.min_Npm = 900 must be below stiffness.max_Npm = 800"),
    (["stiffness.rot_Nmprad=1000"], "stiffness.rot_Nmprad = 1000 is above the controller's limit 300 N·m/rad"),
    (["stiffness.damping=heavy"], "stiffness.damping = 'heavy'"),
    (["stiffness.phases=halves"], "stiffness.phases = 'halves'"),
    (["robot_free.n_validate=0"], "robot_free.n_validate = 0 must be an integer >= 1"),
    (["robot_free.n_trials=0"], "robot_free.n_trials = 0 must be an integer >= 1"),
    (["robot_free.batch_size=0"], "robot_free.batch_size = 0 must be an integer >= 1"),
    (["robot_free.n_samples=0"], "robot_free.n_samples = 0 must be an integer >= 1"),
    (["robot_based.n_trials=-1"], "robot_based.n_trials = -1 must be an integer >= 0 (0 skips the robot-based search)"),
    (["robot_based.n_trials=10"], "robot_based.n_trials = 10 is not above search.options.n_startup_trials = 10"),
    (["robot_free.n_trials=8"], "robot_free.n_trials = 8 is not above search.options.n_startup_trials = 10"),
    (["robot_free.sampler=euler"], "robot_free.sampler = 'euler'; expected null"),
    (["robot_free.sampling_steps=0"], "robot_free.sampling_steps = 0 must be an integer >= 1 or null"),
    (["robot_free.task_loss=median"], "robot_free.task_loss = 'median'; expected null"),
    (["robot_free.shared_steps=-1"], "robot_free.shared_steps = -1 must be an integer >= 0 or auto"),
    (["reference_point=[0.0,2.0]"], "reference_point = [0, 2]: nothing can dominate it: L_task >= 0 N"),
    (["reference_point=[3.0,0.1]"], "reference_point = [3, 0.1]: nothing can dominate it: L_comp >= 0.1732 kN/m"),
    (["reference_point=[3.0]"], "reference_point = [3.0] must be null or [L_task_N, L_comp_kNpm]"),
    (["embodiment=ur5"], "embodiment = 'ur5'; known:"),
    (["torch_threads=0"], "torch_threads = 0 must be an integer >= 1 or null"),
    (["overwrite=yes"], "overwrite = 'yes' must be true or false"),
    (["control_hz=1000"], "control_hz = 1000 is outside [1, 500] Hz"),
    (["search=random", "+search.options.n_startup_trials=3", "robot_based.n_trials=2"], "search=random with options"),
    (["prior_weight=0.7"], "prior_weight = 0.7 needs prior=<stiffness reference JSON> to blend with"),
    (["prior=ridge.json", "prior_weight=1.5"], "prior_weight = 1.5 must be a number in [0, 1]"),
])
def test_each_bad_setting_is_one_line_naming_it(overrides, message):
    with pytest.raises(ValueError) as err:
        check_config(_cfg(*overrides))
    assert message in str(err.value) and "\n" not in str(err.value)


def test_a_prior_at_weight_zero_warns_that_the_model_ranks_alone():
    """A weight sweep's w = 0 point asks for just that, so it is not refused."""
    from dcm.models.prior_blend import PriorWeightWarning

    with pytest.warns(PriorWeightWarning, match="prior = ridge.json at prior_weight = 0 ranks with the model alone"):
        check_config(_cfg("prior=ridge.json"))


def test_zero_robot_trials_skip_rather_than_fail_and_a_reachable_reference_point_passes():
    checked = check_config(_cfg("robot_based.n_trials=0", "reference_point=[3.0,0.5]"))
    assert checked.reference.tolist() == [3.0, 0.5]
    assert min_compliance_loss(checked.space) == pytest.approx(3**0.5 * 0.1)


def test_a_missing_checkpoint_setting_is_named():
    with initialize_config_dir(config_dir=str(REPO / "conf")):
        cfg = compose("tune", overrides=["embodiment=tool"])
    with pytest.raises(TuneConfigError, match="ckpt is required"):
        check_config(cfg)


def test_a_predictor_of_other_channels_or_rate_is_refused():
    cfg = _cfg()
    other_channels = SimpleNamespace(data_spec=DataSpec(cond_channels=["x_demo.x_m"] * 24))
    with pytest.raises(ValueError, match="condition channels .* differ from the model's"):
        check_predictor(other_channels, cfg)
    other_rate = SimpleNamespace(data_spec=DataSpec(control_hz=50.0))
    with pytest.raises(ValueError, match="control rate 20.0 Hz, but the model was trained at 50.0 Hz"):
        check_predictor(other_rate, cfg)
    check_predictor(SimpleNamespace(data_spec=DataSpec()), cfg)  # the tuner's own layout passes


def test_tune_py_reports_a_bad_setting_in_one_line(tmp_path: Path):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONWARNINGS"}
    env.update(HYDRA_FULL_ERROR="0", MUJOCO_GL="egl")
    proc = subprocess.run([sys.executable, str(REPO / "tune.py"), "ckpt=none.ckpt", "robot_based.n_trials=-1",
                           f"hydra.run.dir={tmp_path / 'run'}"], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode != 0
    assert proc.stderr.strip().splitlines() == [  # no library or deprecation chatter around it
        "error: robot_based.n_trials = -1 must be an integer >= 0 (0 skips the robot-based search)"]
    assert proc.stdout == ""


# ----------------------------------------------------------------------------------------------- the skill
def _waypoints(tmp_path: Path, span_s: float = 10.0, last_xy: str = "0.03,0.03") -> Path:
    path = tmp_path / "my_path.csv"
    path.write_text(f"t,x,y,press\n0,0.0,0.0,0.01\n{span_s / 2:g},0.03,0.0,0.01\n{span_s:g},{last_xy},0.01\n")
    return path


def test_a_waypoint_file_without_the_waypoints_family_is_refused_naming_both(tmp_path: Path):
    """What Hydra suggests when `demo=waypoints` is forgotten: the run would tune the wavelike stroke."""
    csv = _waypoints(tmp_path)
    with pytest.raises(ValueError) as err:
        check_config(_cfg(f"+demo.waypoints={csv}"))
    assert "family = 'wavelike'" in str(err.value) and str(csv) in str(err.value)


def test_a_waypoint_demo_is_what_its_file_says_or_an_error_naming_the_option(tmp_path: Path):
    csv = _waypoints(tmp_path, 10.0)
    checked = check_config(_cfg("demo=waypoints", f"demo.waypoints={csv}", "+demo.lead=true"))
    assert checked.spec.duration_s == 10.0 and checked.spec.lead  # recorded, and recorded as results.json says
    with initialize_config_dir(config_dir=str(REPO / "conf")):
        quick = compose("quickstart", overrides=["embodiment=tool", "demo=waypoints", f"demo.waypoints={csv}"])
    with pytest.raises(ValueError, match=rf"duration_s = 12 s, but the waypoint file {csv} spans 10 s"):
        check_config(quick)
    with initialize_config_dir(config_dir=str(REPO / "conf")):
        quick = compose("quickstart", overrides=["embodiment=tool", "demo=waypoints", f"demo.waypoints={csv}",
                                                 "demo.duration_s=null"])
    assert check_config(quick).spec.duration_s == 10.0


def test_waypoint_file_errors_say_what_is_wrong_without_a_misleading_suffix(tmp_path: Path):
    outside = _waypoints(tmp_path, 10.0, last_xy="0.5,0.0")
    with pytest.raises(ValueError) as err:
        check_config(_cfg("demo=waypoints", f"demo.waypoints={outside}"))
    assert f"{outside}, row 4: (x, y) = (0.5, 0) m lies outside" in str(err.value)
    assert "demo's length" not in str(err.value)
    with pytest.raises(ValueError) as err:
        check_config(_cfg("demo=waypoints", f"demo.waypoints={_waypoints(tmp_path, 10.0)}", "task_from_s=11"))
    assert "task_from_s = 11" in str(err.value) and "demo's length" not in str(err.value)


def test_a_failed_run_s_log_holds_its_error(tmp_path: Path):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONWARNINGS"}
    env.update(HYDRA_FULL_ERROR="0", MUJOCO_GL="egl")
    run_dir = tmp_path / "run"
    proc = subprocess.run([sys.executable, str(REPO / "tune.py"), "ckpt=none.ckpt", "robot_free.n_validate=0",
                           f"hydra.run.dir={run_dir}"], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=300, check=False)
    line = "error: robot_free.n_validate = 0 must be an integer >= 1"
    assert proc.returncode == 1 and proc.stderr.strip() == line
    assert line in (run_dir / "tune.log").read_text()


def test_a_refused_resume_writes_nothing_beside_or_inside_the_run(tmp_path: Path):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONWARNINGS"}
    env.update(HYDRA_FULL_ERROR="0", MUJOCO_GL="egl")
    run_dir = tmp_path / "run"
    run_dir.mkdir()  # not a loop run: refused, leaving the run as it was
    proc = subprocess.run([sys.executable, str(REPO / "tune.py"), f"resume={run_dir}"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 1 and "no loop/config.yaml there" in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no outputs/ beside it
    assert not any(run_dir.iterdir())  # and no resumed/<time>/ inside it


def _help_groups(*command: str) -> set[str]:
    env = {**os.environ, "MUJOCO_GL": "egl"}
    proc = subprocess.run([sys.executable, *command, "--help"], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    section = proc.stdout.split("== Configuration groups ==")[1].split("== Config ==")[0]
    return {line.split(":")[0] for line in section.splitlines()[1:] if ": " in line}


@pytest.mark.parametrize("command, groups", [
    (["tune.py"], {"demo", "domain", "objective", "search", "stiffness"}),
    (["tune.py", "--config-name", "quickstart"], {"demo", "domain", "objective", "search", "stiffness"}),
    (["-m", "dcm.data.generate"], {"dataset", "objective", "search", "stiffness"}),
    (["train.py"], {"model", "net", "objective", "schedule", "dataset", "trainer"}),
])
def test_help_lists_only_the_config_groups_the_entry_uses(command, groups):
    assert _help_groups(*command) == groups
