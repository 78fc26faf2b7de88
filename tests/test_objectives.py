"""The configured L_task (conf/objective/): known answers of the paper's and the wipe's, the surface normal it
measures the path in, and the one-line errors of a bad setting at every stage that takes one."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from dcm.control import equal_time_phases, schedule_from_phases
from dcm.control.objectives import (
    PAPER,
    ObjectiveError,
    TaskObjective,
    path_error,
    path_error_over_samples,
    surface_normals,
    task_loss,
)
from dcm.data.generate import GenerationError, compose_config, generate
from dcm.data.schema import load_dataset, read_root_attrs
from dcm.tuning.checks import TuneConfigError, check_config, check_objective

WIPE = TaskObjective("wipe", force_tolerance_N=1.0, path_tolerance_m=0.005)


def _arrays(path: Path) -> tuple[np.ndarray, ...]:
    arrays = load_dataset(path).arrays
    return tuple(np.asarray(arrays[k], np.float64) for k in ("F_obs", "F_demo", "x_obs", "x_demo"))


def test_paper_reproduces_the_force_rmse_bit_for_bit_on_a_stored_dataset(tiny_dataset_path: Path) -> None:
    F_obs, F_demo, x_obs, x_demo = _arrays(tiny_dataset_path)
    for start in (0, 7):
        np.testing.assert_array_equal(PAPER.task_loss(F_obs, F_demo, x_obs, x_demo, start),
                                      task_loss(F_obs, F_demo, start))
    assert read_root_attrs(tiny_dataset_path)["objective"] == PAPER.to_dict()


def test_a_wipe_without_a_path_tolerance_and_with_1_N_is_the_paper_s(tiny_dataset_path: Path) -> None:
    F_obs, F_demo, x_obs, x_demo = _arrays(tiny_dataset_path)
    force_only = TaskObjective("wipe", force_tolerance_N=1.0, path_tolerance_m=math.inf)
    np.testing.assert_array_equal(force_only.task_loss(F_obs, F_demo, x_obs, x_demo, 3), task_loss(F_obs, F_demo, 3))
    as_tensors = [torch.as_tensor(a) for a in (F_obs, F_demo, x_obs, x_demo)]
    assert torch.equal(force_only.task_loss(*as_tensors), task_loss(as_tensors[0], as_tensors[1]))


def test_a_perfectly_tracked_path_costs_nothing_and_a_normal_offset_is_not_a_path_error(tiny_dataset_path: Path
                                                                                       ) -> None:
    F_obs, F_demo, x_obs, x_demo = _arrays(tiny_dataset_path)
    assert np.all(path_error(x_demo, x_demo, F_demo) == 0.0)
    np.testing.assert_array_equal(WIPE.task_loss(F_obs, F_demo, x_demo, x_demo), task_loss(F_obs, F_demo))
    normals = surface_normals(x_demo, F_demo)
    pushed = x_demo.copy()
    pushed[..., :3] += 0.004 * normals  # the tool 4 mm off along the normal: a re-placed bowl's offset
    np.testing.assert_allclose(path_error(pushed, x_demo, F_demo), 0.0, atol=1e-12)
    tangent = np.cross(normals, [1.0, 0.0, 0.0])
    tangent /= np.linalg.norm(tangent, axis=-1, keepdims=True)
    slid = x_demo.copy()
    slid[..., :3] += 0.003 * tangent  # 3 mm along the surface
    np.testing.assert_allclose(path_error(slid, x_demo, F_demo), 0.003, rtol=1e-9)
    expected = np.sqrt(task_loss(F_obs, F_demo) ** 2 + (0.003 / 0.005) ** 2)
    np.testing.assert_allclose(WIPE.task_loss(F_obs, F_demo, slid, x_demo), expected, rtol=1e-12)
    # over samples: no spread is the mean's error; a spread along the normal alone adds nothing
    spread = np.zeros_like(x_demo)
    np.testing.assert_allclose(path_error_over_samples(slid, spread, x_demo, F_demo), path_error(slid, x_demo, F_demo))
    spread[..., :3] = 0.002 * np.abs(normals)
    spread[..., :3] *= (np.abs(normals) > 0.999)  # only where the normal is a bowl axis
    assert np.all(path_error_over_samples(slid, spread, x_demo, F_demo) < path_error(slid, x_demo, F_demo) + 1e-3)


def test_the_normal_from_the_demo_s_force_and_motion_is_the_bowl_s_where_the_tool_slides() -> None:
    from dcm.data.sim_logs import load_demo_spec
    from dcm.sim.rollout import Simulator

    spec = load_demo_spec("line", None)
    demo = Simulator("tool", bowl=spec.bowl).record_demo(spec)
    normals = surface_normals(demo.x_demo, demo.force_demo)
    true = spec.bowl.normal(demo.x_demo[:, 0], demo.x_demo[:, 1])
    wiping = np.arange(demo.horizon) >= int(round(spec.approach_s * 20.0)) + 5
    angle_deg = np.degrees(np.arccos(np.clip((normals * true).sum(-1), -1.0, 1.0)))[wiping]
    tilt_deg = np.degrees(np.arccos(true[wiping, 2]))
    assert tilt_deg.max() > 10.0  # the path climbs the wall, where z is not the normal
    assert np.median(angle_deg) < 2.0 and np.percentile(angle_deg, 90) < 10.0
    np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0)
    assert np.allclose(surface_normals(demo.x_demo[:3], np.zeros((3, 6))), [0.0, 0.0, 1.0])  # no contact: bowl z


def test_a_rollout_is_scored_by_the_configured_objective() -> None:
    from dcm.data.sim_logs import load_demo_spec
    from dcm.sim.rollout import Simulator

    spec = load_demo_spec("wavelike", 2.0)
    sim = Simulator("tool", bowl=spec.bowl)
    demo = sim.record_demo(spec)
    schedule = schedule_from_phases(np.full((2, 3), 300.0), equal_time_phases(demo.horizon, 2), 20.0)
    trial = sim.rollout(demo, schedule)
    assert PAPER.trial_task_loss(trial, demo.x_demo, demo.force_demo) == trial.L_task
    wipe = WIPE.trial_task_loss(trial, demo.x_demo, demo.force_demo)
    assert wipe > trial.L_task  # the path adds to the force term of 1 N tolerance
    trial.failed = True
    assert WIPE.trial_task_loss(trial, demo.x_demo, demo.force_demo) == math.inf


@pytest.mark.parametrize("setting, message", [
    ({"name": "wipe", "force_tolerance_N": 0.0}, "objective.force_tolerance_N = 0.0 must be a number > 0"),
    ({"name": "wipe", "path_tolerance_m": -0.001}, "objective.path_tolerance_m = -0.001 must be a number > 0"),
    ({"name": "wipe", "path_tolerance_m": float("nan")}, "objective.path_tolerance_m = nan must be a number > 0"),
    ({"name": "sweep"}, "objective = 'sweep' is not one of paper, wipe"),
    ({"name": "wipe", "force_tol": 1.0}, "objective.force_tol is not a field"),
    ({"name": "paper", "path_tolerance_m": 0.005}, "objective=paper is the force RMSE in N and takes no tolerances"),
])
def test_a_bad_objective_is_one_line_naming_it(setting: dict, message: str) -> None:
    with pytest.raises(ObjectiveError, match="^" + message.replace("(", r"\(").replace(")", r"\)")):
        TaskObjective.from_config(setting)
    with pytest.raises(GenerationError, match=message.split(" ")[0].replace(".", r"\.")):
        generate(_tiny_with_objective(setting))


def _tiny_with_objective(setting: dict):
    from omegaconf import OmegaConf

    cfg = compose_config("tiny", ["workers=1", "progress=false"])
    OmegaConf.set_struct(cfg, False)
    cfg.objective = setting
    return cfg


def test_tune_refuses_a_bad_objective() -> None:
    from hydra import compose, initialize_config_dir

    from dcm.configs import CONF_DIR

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        bad = compose("tune", overrides=["ckpt=x.ckpt", "objective=wipe", "objective.path_tolerance_m=0"])
        wipe = compose("tune", overrides=["ckpt=x.ckpt", "objective=wipe"])
    with pytest.raises(TuneConfigError, match=r"^objective.path_tolerance_m = 0 must be a number > 0$"):
        check_config(bad)
    assert check_config(wipe).objective == WIPE



def test_tune_refuses_a_predictor_of_another_objective(tiny_checkpoint: Path) -> None:
    from dcm.models.predict import load_model

    model = load_model(tiny_checkpoint)  # a force model trained for the paper's objective
    with pytest.raises(TuneConfigError, match=r"^ckpt=m.ckpt: objective wipe \(force over 1 N, path over 5 mm\) differs "
                                              r"from paper \(force RMSE, N\) of checkpoint .*; use objective=paper, or a "
                                              r"predictor trained for objective=wipe$"):
        check_objective(model, WIPE, "m.ckpt")
    check_objective(model, PAPER, "m.ckpt")


def test_a_wipe_dataset_stores_its_objective_and_its_l_task(tmp_path: Path) -> None:
    cfg = compose_config("tiny", ["workers=1", "progress=false", "objective=wipe", f"out={tmp_path / 'w.h5'}",
                                  "skills=[wavelike]"])
    path = generate(cfg)
    data = load_dataset(path)
    assert read_root_attrs(path)["objective"] == WIPE.to_dict()
    F_obs, F_demo, x_obs, x_demo = _arrays(path)
    np.testing.assert_allclose(data.L_task, WIPE.task_loss(F_obs, F_demo, x_obs, x_demo), rtol=1e-5)
    assert np.all(data.L_task > task_loss(F_obs, F_demo))
