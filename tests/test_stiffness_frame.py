"""Stiffness in the surface's frame: known answers of the frame, the matrix controller and its schedule files."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from dcm.control import (
    StiffnessFrameError,
    StiffnessOutOfRange,
    StiffnessSchedule,
    attractor_from_demo,
    compliance_loss,
    equal_time_phases,
    schedule_from_phases,
    surface_axes,
)
from dcm.control.schedule import axes_from_normals
from dcm.search import space_from_settings
from dcm.sim.demos import DemoSpec
from dcm.sim.domain import DomainSpec
from dcm.sim.geometry import BowlSpec
from dcm.sim.rollout import Simulator

FIXTURE = Path(__file__).parent / "fixtures" / "world_frame_trial.npz"
STIFFNESS = {"n_phases": 2, "phases": "equal_time", "min_Npm": 100.0, "max_Npm": 1500.0, "log": False,
             "rot_Nmprad": 20.0, "damping": "critical"}


def _recorded(bowl: BowlSpec, domain: DomainSpec | None = None, embodiment: str = "tool"):
    sim = Simulator(embodiment=embodiment, bowl=bowl, control_hz=20.0, seed=3, domain=domain)
    return sim, sim.record_demo(DemoSpec(family="spiral", press_m=0.01, bowl=bowl, duration_s=4.0))


def _schedule(demo, tangent_normal):
    """Per-phase (K_t, K_n) as a diagonal (H, 6), phases of equal time."""
    phases = np.asarray(tangent_normal, dtype=np.float64)[:, [0, 0, 1]]
    return schedule_from_phases(phases, equal_time_phases(demo.horizon, len(phases)))


def test_the_world_frame_rolls_out_the_stored_trial_bit_for_bit():
    """The trial was stored by the controller before the frame existed (tool, a spread bowl, a per-phase
    per-axis schedule): the world frame must keep every byte of it."""
    stored = np.load(FIXTURE)
    sim, demo = _recorded(BowlSpec(), DomainSpec(bowl_offset_std_m=0.002, bowl_friction_std=0.2))
    schedule = schedule_from_phases(np.array([[300., 800., 200.], [1200., 400., 600.]]),
                                    equal_time_phases(demo.horizon, 2))
    trial = sim.rollout(demo, schedule)
    assert np.array_equal(demo.x_demo, stored["x_demo"]) and np.array_equal(demo.force_demo, stored["force_demo"])
    for key in ("x_attr", "x_obs", "force_obs", "stiffness_applied"):
        assert np.array_equal(getattr(trial, key), stored[key]), key
    assert trial.stiffness_axes is None and trial.stiffness_applied_axes is None


def test_on_a_flat_plate_the_surface_frame_is_the_world_frame():
    """The plate's normal is bowl z, so a frame following it has the bowl's axes and rolls out the world's
    trial; the normal the frame takes from the demo's force is bowl z within 2 degrees (median) there."""
    bowl = BowlSpec(shape="flat", depth_m=0.0)
    sim, demo = _recorded(bowl)
    diagonal = _schedule(demo, [[1200.0, 200.0], [300.0, 900.0]])
    plate = axes_from_normals(bowl.normal(demo.x_demo[:, 0], demo.x_demo[:, 1]))
    world, turned = sim.rollout(demo, diagonal), sim.rollout(demo, StiffnessSchedule(diagonal, plate))
    np.testing.assert_allclose(plate, np.broadcast_to(np.eye(3), plate.shape), atol=1e-15)
    np.testing.assert_allclose(turned.force_obs, world.force_obs, atol=1e-9)
    np.testing.assert_allclose(turned.x_obs, world.x_obs, atol=1e-12)
    # Where the tool does not slide, friction stays in the force and tilts it by up to atan(mu).
    tilt_deg = np.degrees(np.arccos(surface_axes(demo.x_demo, demo.force_demo)[demo.contact, 2, 2]))
    assert np.median(tilt_deg) < 2.0 and tilt_deg.max() < np.degrees(np.arctan(bowl.friction)) + 0.5


@pytest.mark.parametrize("embodiment", ["tool", "panda"])
def test_a_rotated_isotropic_stiffness_is_the_unrotated_one(embodiment: str):
    sim, demo = _recorded(BowlSpec(), embodiment=embodiment)
    diagonal = _schedule(demo, [[500.0, 500.0], [900.0, 900.0]])
    surface = StiffnessSchedule.for_demo(diagonal, "surface", demo.x_demo, demo.force_demo)
    assert np.abs(surface.axes[:, :, 2] - [0.0, 0.0, 1.0]).max() > 0.1  # the frame does turn on the bowl's wall
    world, turned = sim.rollout(demo, diagonal, common_draws=True), sim.rollout(demo, surface, common_draws=True)
    np.testing.assert_allclose(turned.x_attr, world.x_attr, atol=1e-12)
    np.testing.assert_allclose(turned.force_obs, world.force_obs, atol=1e-8)


def test_the_matrix_attractor_balances_the_demo_force_at_any_stiffness():
    """A static demo: the spring R diag(k) Rᵀ pulled to the attractor presses exactly the demo's force."""
    rng = np.random.default_rng(0)
    horizon = 5
    x_demo = np.tile(rng.normal(size=6) * 0.01, (horizon, 1))
    force_demo = np.tile(rng.normal(size=6) * 5.0, (horizon, 1))
    for _ in range(3):
        axes = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        diagonal = np.tile(np.r_[rng.uniform(100, 1500, 3), 20.0, 20.0, 20.0], (horizon, 1))
        x_attr = attractor_from_demo(x_demo, force_demo, diagonal, 0.05, inertia=1.0, mass=np.ones(6),
                                     axes=np.broadcast_to(axes, (horizon, 3, 3)))
        matrix = StiffnessSchedule(diagonal, np.broadcast_to(axes, (horizon, 3, 3))).translational_matrix()
        pull = np.einsum("hij,hj->hi", matrix, x_attr[:, :3] - x_demo[:, :3])
        np.testing.assert_allclose(pull, -force_demo[:, :3], atol=1e-9)


def test_a_surface_schedule_soft_along_the_normal_still_reproduces_the_demo_force():
    """The matrix attractor compensates K and D along every axis: a stiffness soft along the normal and ten
    times stiffer along the surface misses the demo's force by no more than the same diagonal on bowl axes
    (the residual of a 20 Hz attractor on a 4 s spiral, about 4 % of the demo's RMS force)."""
    sim, demo = _recorded(BowlSpec())
    diagonal = _schedule(demo, [[1500.0, 150.0], [1200.0, 300.0]])
    surface = StiffnessSchedule.for_demo(diagonal, "surface", demo.x_demo, demo.force_demo)
    trial = sim.rollout(demo, surface)
    assert not trial.failed, trial.failure_reason
    assert trial.L_task < 0.05 * np.sqrt(np.mean(demo.force_demo[:, :3] ** 2))
    assert trial.L_task < 1.1 * sim.rollout(demo, diagonal).L_task
    # L_comp is frame-invariant: the norm of the diagonal is the Frobenius norm of R diag Rᵀ.
    frobenius = np.linalg.norm(surface.translational_matrix(), axis=(1, 2)).mean() / 1000.0
    assert trial.L_comp == pytest.approx(frobenius) == pytest.approx(float(compliance_loss(surface.diagonal)))


def test_a_surface_schedule_file_read_as_franka_ros_matrices_rolls_out_the_same(tmp_path: Path):
    from dcm.tuning.schedule_files import read_surface_schedule, write_round

    sim, demo = _recorded(BowlSpec())
    boundaries = equal_time_phases(demo.horizon, 2)
    proposals = np.array([[[1400.0, 200.0], [600.0, 800.0]]])
    diagonal = schedule_from_phases(proposals[0][:, [0, 0, 1]], boundaries)[None]
    axes = surface_axes(demo.x_demo, demo.force_demo)
    attractors = sim.attractor(demo, diagonal, axes)
    content = write_round(tmp_path, 1, proposals, diagonal, attractors, sim.damping_mass, demo,
                          {"control_hz": 20.0}, np.array([[1.0, 0.5]]), bowl_in_base=np.eye(4), axes=axes)
    assert content["stiffness_frame"] == "surface"
    read = read_surface_schedule(tmp_path / "p01.csv")
    np.testing.assert_allclose(read.translational_matrix(),  # written with 9 significant digits
                               StiffnessSchedule(diagonal[0], axes).translational_matrix(), atol=1e-5)
    original, replayed = sim.rollout(demo, StiffnessSchedule(diagonal[0], axes)), sim.rollout(demo, read)
    np.testing.assert_allclose(replayed.x_attr, original.x_attr, atol=1e-8)
    np.testing.assert_allclose(replayed.force_obs, original.force_obs, atol=1e-4)
    base = np.loadtxt(tmp_path / "p01_base.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(base[:, 8:17].reshape(-1, 3, 3), read.translational_matrix(), atol=1e-5)


def test_bad_frames_and_matrices_are_one_line_errors():
    with pytest.raises(ValueError, match=r"^stiffness.frame = 'tool' is unknown; expected one of world, surface$"):
        space_from_settings({**STIFFNESS, "frame": "tool"})
    hover = np.zeros((10, 6))
    with pytest.raises(StiffnessFrameError, match="demo 'hover' never presses more than 1 N, so it has none"):
        StiffnessSchedule.for_demo(hover, "surface", hover, hover, "demo 'hover'")
    skew = np.tile(np.diag([500.0, 500.0, 500.0]), (4, 1, 1))
    skew[2, 0, 1] = 50.0
    with pytest.raises(StiffnessOutOfRange, match=r"^p01.csv\[t=2\]: the translational stiffness matrix is not symmetric$"):
        StiffnessSchedule.from_matrix(skew, np.full((4, 3), 20.0), where="p01.csv")
    soft = np.tile(np.diag([500.0, 5.0, 500.0]), (4, 1, 1))
    with pytest.raises(StiffnessOutOfRange, match=r"p01.csv eigenvalues\[t=0, x\] = 5 N/m is outside \[10, 3000\]"):
        StiffnessSchedule.from_matrix(soft, np.full((4, 3), 20.0), where="p01.csv")


def test_a_surface_dataset_records_its_frame_and_a_world_one_keeps_its_fingerprint(tmp_path: Path):
    import h5py

    from dcm.data.generate import compose_config, ensure_dataset
    from dcm.data.generate_checks import build_settings

    assert "frame" not in build_settings(compose_config("tiny", []))["stiffness"]  # as before the frame existed
    assert build_settings(compose_config("tiny", ["stiffness.frame=surface"]))["stiffness"]["frame"] == "surface"
    path = ensure_dataset("tiny", tmp_path / "surface.h5",
                          ["workers=1", "progress=false", "stiffness.frame=surface", "dataset.skills.1.n_trials=1"])
    with h5py.File(path, "r") as f:
        assert f.attrs["stiffness_frame"] == "surface"
        trial = f["data"][sorted(f["data"])[0]]
        phases = np.asarray(json.loads(trial.attrs["phase_stiffness_Npm"]))
        stiffness = trial["K"][:]
    assert phases.shape[1] == 2  # (K_tangent, K_normal) per phase
    assert np.allclose(stiffness[:, 0], stiffness[:, 1])  # the two tangents share one stiffness


def test_the_tuner_refuses_a_model_of_another_frame(tiny_checkpoint: Path):
    """A model reads its stiffness channels as diagonals in the frame it was trained on."""
    from omegaconf import OmegaConf

    from dcm.models.predict import load_model
    from dcm.tuning.checks import check_predictor

    cfg = OmegaConf.load(Path(__file__).parents[1] / "conf" / "stiffness" / "default.yaml")
    cfg.frame = "surface"
    settings = OmegaConf.create({"ckpt": str(tiny_checkpoint), "objective": None, "stiffness": cfg, "control_hz": 20.0,
                                 "task_from_s": 0.0})
    with pytest.raises(ValueError, match=r"stiffness in the surface frame, but the model was trained on stiffness in "
                                         r"the world frame \(stiffness.frame=world\)$"):
        check_predictor(load_model(tiny_checkpoint), settings)


def test_a_model_of_surface_data_tunes_in_the_surface_frame_with_the_robot_in_the_loop(tmp_path: Path):
    """Generation, training and the robot loop in the surface frame: the proposals are (K_t, K_n) per phase, the
    round's files carry the frame, and the simulated robot's trials come back as the search's values."""
    from hydra import compose, initialize_config_dir

    from dcm.data.generate import ensure_dataset
    from dcm.models.dcm import DCM
    from dcm.tuning.run import tune
    from tests.conftest import short_wave_demo, train_tiny

    data = ensure_dataset("tiny", tmp_path / "surface.h5", ["workers=1", "progress=false", "stiffness.frame=surface"])
    ckpt = train_tiny(DCM, data, tmp_path / "dcm.ckpt", 5, diffusion_steps=5)
    with initialize_config_dir(config_dir=str(Path(__file__).parents[1] / "conf")):
        cfg = compose("tune", overrides=[
            f"ckpt={ckpt}", f"demo_file={short_wave_demo(tmp_path)}", "embodiment=tool", f"out_dir={tmp_path / 'run'}",
            "stiffness.frame=surface", "robot_free.n_trials=16", "robot_free.batch_size=8",
            "robot_free.sampling_steps=5", "search.options.n_startup_trials=4", "robot_based.n_trials=0",
            "robot=sim", "loop.rounds=2", "loop.batch=3", "loop.n_trials=8", "loop.tolerance_N=0"])
    loop = tune(cfg, tmp_path / "run")["loop"]
    assert [r["n_trials"] for r in loop["rounds"]] == [3, 3] and loop["observed"]["n_trials"] == 6
    state = json.loads((tmp_path / "run" / "loop" / "state.json").read_text())
    assert all(np.asarray(r["proposals"]).shape[1:] == (3, 2) for r in state["rounds"])  # (K_t, K_n) per phase
    round_1 = yaml.safe_load((tmp_path / "run" / "proposals" / "round_1" / "round.yaml").read_text())
    assert round_1["stiffness_frame"] == "surface"


def test_the_panda_s_frame_actuators_agree_with_the_python_law_r_diag_r_transposed():
    """The in-engine actuators along the mocap frame against the reference controller, which evaluates
    R (k ∘ Rᵀ e - d ∘ Rᵀ v) in Python at every physics step: as close as in the world frame, and far from the
    law of a transposed frame (what a quaternion of Rᵀ would apply)."""
    from dcm.control import task_loss
    from dcm.sim.panda import PandaEmbodiment

    bowl = BowlSpec()
    sim, demo = _recorded(bowl, embodiment="panda")
    diagonal = schedule_from_phases(np.array([[1500.0, 1500.0, 150.0], [300.0, 300.0, 1200.0]]),
                                    equal_time_phases(demo.horizon, 2))
    surface = StiffnessSchedule.for_demo(diagonal, "surface", demo.x_demo, demo.force_demo)
    transposed = StiffnessSchedule(diagonal, np.swapaxes(surface.axes, 1, 2))
    engine = [sim.rollout(demo, s).force_obs for s in (diagonal, surface, transposed)]
    sim._embodiments[next(iter(sim._embodiments))] = PandaEmbodiment(bowl, DomainSpec(), visual=False,
                                                                     controller="python")
    reference = [sim.rollout(demo, s).force_obs for s in (diagonal, surface)]
    world_gap, surface_gap = (float(task_loss(a, b)) for a, b in zip(engine, reference))
    assert surface_gap < 1.5 * world_gap
    assert float(task_loss(engine[2], reference[1])) > 2.0 * surface_gap
