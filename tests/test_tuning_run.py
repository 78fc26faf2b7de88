"""tune.py end to end on the fast tool embodiment: virtual trials, validation, hypervolume, resume,
reproducibility with a seed, trial-log fingerprints and the sampler override."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from dcm.models.checkpoint import CARD_KEY, checkpoint_card, read_checkpoint
from dcm.models.predict import load_model
from dcm.sim.demos import DemoSpec
from dcm.tuning.checks import TuneConfigError, check_config
from dcm.tuning.cli import summary_lines
from dcm.tuning.diagnostics import recording_mismatch
from dcm.tuning.objectives import SimulatorObjective, batch_seed
from dcm.tuning.optimize import TrialLog, TrialLogMismatch
from dcm.tuning.predictor import use_sampler
from dcm.tuning.run import tune
from dcm.tuning.setup import record_skill
from tests.conftest import short_wave_demo

REPO = Path(__file__).resolve().parents[1]


def _config(ckpt: Path, demo: Path, out_dir: Path, robot_free_trials: int, *extra: str):
    with initialize_config_dir(config_dir=str(REPO / "conf")):
        return compose("tune", overrides=[
            f"ckpt={ckpt}", f"demo_file={demo}", "embodiment=tool", f"out_dir={out_dir}",
            f"robot_free.n_trials={robot_free_trials}", "robot_free.batch_size=8", "robot_free.n_validate=3",
            "robot_free.sampling_steps=5",  # DDIM steps must divide the tiny checkpoint's T = 5
            "robot_based.n_trials=5", "search.options.n_startup_trials=4", *extra,
        ])


def _numbers(results: dict) -> dict:
    """results.json without what depends on the invocation: its timings, and how many trials it replayed."""
    if isinstance(results, dict):
        return {k: _numbers(v) for k, v in results.items()
                if "seconds" not in k and k not in ("n_replayed", "n_computed")}
    if isinstance(results, list):
        return [_numbers(v) for v in results]
    return results


DDPM = ["robot_free.sampler=ddpm", "robot_free.sampling_steps=null"]  # noise at every step: the hardest to reproduce


def test_tune_validates_the_predicted_front_and_resumes(tiny_checkpoint: Path, tmp_path: Path):
    demo = short_wave_demo(tmp_path)
    out_dir = tmp_path / "run"

    first = tune(_config(tiny_checkpoint, demo, out_dir, 16, *DDPM), out_dir)
    assert first["robot_free"]["n_virtual_trials"] == 16
    assert 1 <= first["robot_free"]["n_validated"] <= 3
    for solution in first["robot_free"]["solutions"]:
        assert np.all(np.array(solution["phase_stiffness_Npm"]) >= 100.0)
        assert solution["validated"]["L_comp_kNpm"] == pytest.approx(solution["predicted"]["L_comp_kNpm"])
    assert first["robot_based"]["n_trials"] == 5
    assert first["robot_free"]["hypervolume"] >= 0.0 and first["robot_based"]["hypervolume"] >= 0.0
    for name in ("results.json", "overview.png", "pareto.png", "solution_forces.png"):
        assert (out_dir / name).stat().st_size > 0

    # Extending the run replays the logged virtual trials and only evaluates the new ones.
    logged = TrialLog.load(out_dir / "robot_free_trials.npz").arrays()[0]
    second = tune(_config(tiny_checkpoint, demo, out_dir, 24, *DDPM), out_dir)
    extended = TrialLog.load(out_dir / "robot_free_trials.npz").arrays()[0]
    assert second["robot_free"]["n_virtual_trials"] == 24
    np.testing.assert_array_equal(extended[:16], logged)
    assert json.loads((out_dir / "results.json").read_text())["robot_free"]["n_virtual_trials"] == 24
    assert (first["robot_free"]["n_replayed"], first["robot_free"]["n_computed"]) == (0, 16)
    assert (second["robot_free"]["n_replayed"], second["robot_free"]["n_computed"]) == (16, 8)
    assert (second["robot_based"]["n_replayed"], second["robot_based"]["n_computed"]) == (5, 0)

    # A re-run into the finished run directory replays every trial: its printout says so and reports the model
    # time of the trials it computed (none), not a speed of the whole search.
    replayed = tune(_config(tiny_checkpoint, demo, out_dir, 24, *DDPM), out_dir)
    assert (replayed["robot_free"]["n_replayed"], replayed["robot_free"]["n_computed"]) == (24, 0)
    assert replayed["robot_free"]["seconds_model"] == 0.0 and _numbers(replayed) == _numbers(second)
    assert json.loads((out_dir / "results.json").read_text())["robot_free"]["n_replayed"] == 24
    printed = summary_lines(replayed)
    assert "robot-free: 24 virtual trials (24 replayed from the run directory's log, 0 computed) in " in printed[1]
    assert "robot-based: 5 simulated trials (5 replayed from the run directory's log, 0 computed) in " in printed[-1]
    assert "x the time of a virtual trial" not in printed[-1]
    fresh = summary_lines(first)
    assert fresh[1].startswith("robot-free: 16 virtual trials in ") and "replayed" not in " ".join(fresh)
    assert "x the time of a virtual trial" in fresh[-1]

    # The same seed twice gives the same numbers, and the killed-and-resumed run (16, then 24 trials) gives
    # those of an uninterrupted 24-trial run: the DCM's samples are seeded per batch.
    uninterrupted = [tune(_config(tiny_checkpoint, demo, tmp_path / name, 24, *DDPM), tmp_path / name) for name in "ab"]
    assert _numbers(uninterrupted[0]) == _numbers(uninterrupted[1])
    assert _numbers(uninterrupted[0]) == _numbers(second)
    for name in "ab":
        np.testing.assert_array_equal(TrialLog.load(tmp_path / name / "robot_free_trials.npz").arrays()[1],
                                      TrialLog.load(out_dir / "robot_free_trials.npz").arrays()[1])
    assert uninterrupted[0]["predictor"]["sampler"] == "ddpm" and uninterrupted[0]["predictor"]["T"] == 5


@pytest.mark.parametrize("precision", [None, "bfloat16"])
def test_the_default_robot_free_search_gives_the_same_results_for_the_same_seed(tiny_checkpoint: Path,
                                                                               tmp_path: Path, precision: str | None):
    """conf/tune.yaml's robot-free defaults (a few DDIM steps, one MOTPE fit per batch, float32), and bfloat16
    when asked, give the same results.json for the same seed, and a killed-and-resumed run those of an
    uninterrupted one; results.json names the precision."""
    demo = short_wave_demo(tmp_path)
    extra = ("robot_based.n_trials=0", *([f"robot_free.precision={precision}"] if precision else []))
    runs = [tune(_config(tiny_checkpoint, demo, tmp_path / name, 24, *extra), tmp_path / name) for name in "ab"]
    assert _numbers(runs[0]) == _numbers(runs[1])
    assert runs[0]["predictor"]["sampling_steps"] == 5
    assert runs[0]["robot_free"]["precision"] == (precision or "float32")
    assert runs[0]["predictor"].get("precision", "float32") == (precision or "float32")
    tune(_config(tiny_checkpoint, demo, tmp_path / "resumed", 16, *extra), tmp_path / "resumed")
    resumed = tune(_config(tiny_checkpoint, demo, tmp_path / "resumed", 24, *extra), tmp_path / "resumed")
    assert _numbers(resumed) == _numbers(runs[0])


def test_samples_sharing_their_first_steps_give_the_same_results_for_the_same_seed(tiny_checkpoint: Path,
                                                                                  tmp_path: Path):
    """robot_free.shared_steps with several samples per trial: seeded like any run, and named in its record."""
    demo = short_wave_demo(tmp_path)
    extra = ("robot_free.n_samples=2", "robot_free.task_loss=over_samples", "robot_free.shared_steps=1",
             "robot_based.n_trials=0")
    runs = [tune(_config(tiny_checkpoint, demo, tmp_path / name, 12, *extra), tmp_path / name) for name in "ab"]
    assert _numbers(runs[0]) == _numbers(runs[1])
    assert runs[0]["predictor"]["shared_steps"] == 1 and runs[0]["predictor"]["n_samples"] == 2


def test_validation_rollouts_judge_every_front_by_its_mean_over_fresh_draws(tiny_checkpoint: Path, tmp_path: Path):
    """With a per-rollout spread (domain=bowl_offset) a solution is judged by its mean L_task over
    ``validation_rollouts`` draws, none of them the one a search trial got; the robot-based front's picks too."""
    demo, out_dir = short_wave_demo(tmp_path), tmp_path / "run"
    cfg = _config(tiny_checkpoint, demo, out_dir, 8, "validation_rollouts=3", "domain=bowl_offset")
    results = tune(cfg, out_dir)
    free, based = results["robot_free"], results["robot_based"]
    assert free["validation_rollouts"] == 3
    assert 1 <= len(based["solutions"]) <= 3 and based["hypervolume_validated"] >= 0.0

    simulator, recorded, skill = record_skill(cfg, check_config(cfg))
    for solution in (free["solutions"][0], based["solutions"][0]):
        stiffness = skill.schedules(np.asarray([solution["phase_stiffness_Npm"]]))[0]
        draws = [simulator.rollout(recorded, stiffness, repeat=r).L_task for r in (1, 2, 3)]
        assert solution["validated"]["L_task_N"] == pytest.approx(np.mean(draws))
    observed = based["solutions"][0]["observed"]["L_task_N"]  # the search trial's own draw (repeat 0)
    assert observed == pytest.approx(simulator.rollout(recorded, stiffness).L_task)
    assert observed != pytest.approx(based["solutions"][0]["validated"]["L_task_N"])

    with pytest.raises(TuneConfigError, match="validation_rollouts = 0"):
        check_config(_config(tiny_checkpoint, demo, out_dir, 8, "validation_rollouts=0"))


def test_task_from_s_scores_every_tuner_after_the_approach(tiny_checkpoint: Path, tmp_path: Path):
    """With task_from_s the predictor's L_task, the validation and the robot-based trials all count the force
    from that time on; the window is part of the skill a trial log belongs to."""
    from dcm.control import task_loss
    from dcm.models.predict import predict_task_loss

    demo, out_dir = short_wave_demo(tmp_path), tmp_path / "run"
    cfg = _config(tiny_checkpoint, demo, out_dir, 8, "task_from_s=0.4")
    results = tune(cfg, out_dir)
    assert results["skill"]["task_from_s"] == 0.4
    simulator, recorded, skill = record_skill(cfg, check_config(cfg))
    assert skill.task_from_step == 8
    window = slice(8, None)
    solution = results["robot_free"]["solutions"][0]
    phases = np.asarray([solution["phase_stiffness_Npm"]])
    stiffness = skill.schedules(phases)[0]
    trial = simulator.rollout(recorded, stiffness)
    after = float(task_loss(trial.force_obs[window], recorded.force_demo[window]))
    assert solution["validated"]["L_task_N"] == pytest.approx(after) and after != pytest.approx(trial.L_task)
    robot_based = SimulatorObjective(simulator, recorded, skill)
    assert robot_based(phases)[0, 0] == pytest.approx(after)
    model = load_model(tiny_checkpoint)
    inputs = (recorded.x_demo, recorded.force_demo, simulator.attractor(recorded, stiffness), stiffness)
    torch.manual_seed(0)
    whole = predict_task_loss(model, *inputs)
    torch.manual_seed(0)
    assert predict_task_loss(model, *inputs, from_step=8) != pytest.approx(whole)
    with pytest.raises(TuneConfigError, match="task_from_s = 2.0 s must be >= 0 and before the end of the 2 s"):
        check_config(_config(tiny_checkpoint, demo, out_dir, 8, "task_from_s=2.0"))


def test_tune_refuses_a_log_of_another_checkpoint_demo_or_sampler(tiny_checkpoint: Path, tmp_path: Path):
    demo, out_dir = short_wave_demo(tmp_path), tmp_path / "run"
    small = ["robot_based.n_trials=0"]
    first = tune(_config(tiny_checkpoint, demo, out_dir, 8, *small), out_dir)
    assert first["predictor"]["sampler"] == "ddim" and first["predictor"]["sampling_steps"] == 5
    # another checkpoint: the same model with one weight changed (as a baseline's file would differ)
    other_ckpt = tmp_path / "other.ckpt"
    saved = torch.load(tiny_checkpoint, map_location="cpu", weights_only=True)
    name = next(k for k, v in saved["state_dict"].items() if v.is_floating_point())
    saved["state_dict"][name] = saved["state_dict"][name] + 0.01
    torch.save(saved, other_ckpt)
    with pytest.raises(TrialLogMismatch) as err:
        tune(_config(other_ckpt, demo, out_dir, 8, *small), out_dir)
    message = str(err.value)
    assert "\n" not in message and f"{out_dir / 'robot_free_trials.npz'}: cannot resume its 8 trials" in message
    assert f"predictor: {tiny_checkpoint} (sha256 " in message and f"-> {other_ckpt} (sha256 " in message
    assert "overwrite=true" in message
    # another demo
    with pytest.raises(TrialLogMismatch, match=r"demo.press_m: 0.01 -> 0.012"):
        tune(_config(tiny_checkpoint, short_wave_demo(tmp_path, press_m=0.012), out_dir, 8, *small), out_dir)
    # another sampler, then overwrite=true proceeds and the log is rewritten with the new settings
    ddpm = ["robot_free.sampler=ddpm", "robot_free.sampling_steps=null"]
    with pytest.raises(TrialLogMismatch, match=r"predictor.sampler: ddim -> ddpm"):
        tune(_config(tiny_checkpoint, demo, out_dir, 8, *small, *ddpm), out_dir)
    redone = tune(_config(other_ckpt, demo, out_dir, 8, *small, *ddpm, "overwrite=true"), out_dir)
    assert redone["predictor"]["sampler"] == "ddpm" and redone["predictor"]["sampling_steps"] == 5
    assert redone["predictor"]["sha256"] != first["predictor"]["sha256"]
    logged = TrialLog.load(out_dir / "robot_free_trials.npz").fingerprint
    assert logged["predictor_sha256"] == redone["predictor"]["sha256"]


def test_the_sampler_override_changes_the_denoising_steps(tiny_checkpoint: Path):
    x = np.zeros((40, 6))
    K = np.full((40, 6), 500.0)

    def net_calls(model) -> int:
        calls = []
        hook = model.inference_net.register_forward_hook(lambda *args: calls.append(1))
        model.predict_forces(x, x, x, K, generator=torch.Generator().manual_seed(0))
        hook.remove()
        return len(calls)

    model = load_model(tiny_checkpoint)
    assert model.cfg.diffusion_steps == 5 and net_calls(model) == 5  # the checkpoint's DDPM over T = 5
    assert not use_sampler(model, None, None) and net_calls(model) == 5  # nothing asked: nothing changed
    assert use_sampler(model, "ddim", 1) and net_calls(model) == 1
    assert model.cfg.sampler == "ddim" and model.cfg.sampling_steps == 1
    fresh = load_model(tiny_checkpoint)
    assert use_sampler(fresh, "ddim", None) and net_calls(fresh) == 5  # another sampler, no steps given: T
    assert use_sampler(fresh, None, 1) and net_calls(fresh) == 1  # steps alone keep the sampler
    assert use_sampler(fresh, "ddim_even", 2) and net_calls(fresh) == 2  # any step count: t = 4, then t = 0
    with pytest.raises(TuneConfigError, match="robot_free.sampling_steps = 2 with robot_free.sampler = ddim: .*T=5"):
        use_sampler(model, "ddim", 2)
    assert not use_sampler(object(), "ddim", 1)  # predictors that do not diffuse are left alone


def test_tune_refuses_a_checkpoint_of_another_control_rate(tiny_checkpoint: Path, tmp_path: Path):
    cfg = _config(tiny_checkpoint, REPO / "data/demos/line.yaml", tmp_path, 8)
    cfg.control_hz = 50.0
    with pytest.raises(ValueError, match="50.0 Hz"):
        tune(cfg, tmp_path)


def test_the_demo_config_tunes_a_path_family_the_shipped_dcm_never_trained_on():
    """`make demo` runs tune.py --config-name quickstart: the shipped DCM on a path family absent from the
    train/valid skills of the dataset preset its card names, recorded as that preset recorded its demos."""
    with initialize_config_dir(config_dir=str(REPO / "conf")):
        cfg = compose("quickstart")
        card = checkpoint_card(REPO / cfg.ckpt)
        preset = compose("generate", overrides=[f"dataset={card['dataset']['dataset']}"]).dataset
    assert preset.demo_lead and preset.duration_s == 12.0  # recorded as quickstart.yaml records the new skill
    assert card["kind"] == "dcm" and card["stage"] == "pretrain"
    trained_families = {skill["spec"]["family"] for skill in preset["skills"] if skill["split"] != "test"}
    assert trained_families and cfg.demo.family not in trained_families
    assert recording_mismatch(cfg.ckpt, DemoSpec.from_dict(OmegaConf.to_container(cfg.demo))) is None
    assert cfg.robot_free.n_trials == 1000 and cfg.robot_based.n_trials > 0


def test_the_demo_s_robot_free_search_gives_the_readme_s_figures_under_the_default_precision(tmp_path: Path):
    """`make demo`'s robot-free hypervolume and predicted -> validated pairs are the figures README.md prints, on
    any CPU: float32 is the default precision (bfloat16, where the CPU has it, gives others)."""
    import re

    from dcm.shipped import with_shipped_paths

    readme = (REPO / "README.md").read_text()
    quoted_hypervolume = float(re.search(r"robot-free: 1000 virtual trials .* hypervolume ([0-9.]+)", readme)[1])
    pairs = re.search(r"robot-free L_task predicted -> validated \[N\]: (.*?);", readme)[1]
    quoted_pairs = [tuple(float(v) for v in pair.split(" -> ")) for pair in pairs.split(", ")]
    with initialize_config_dir(config_dir=str(REPO / "conf")):
        cfg = compose("quickstart", overrides=[f"out_dir={tmp_path}", "robot_based.n_trials=0"])
    assert cfg.robot_free.precision == "float32"
    free = tune(with_shipped_paths(cfg), tmp_path)["robot_free"]
    assert free["precision"] == "float32"
    assert f"{free['hypervolume']:.4g}" == f"{quoted_hypervolume:.4g}"
    prediction = free["prediction"]
    assert [(float(f"{p:.3g}"), float(f"{r:.3g}")) for p, r in zip(prediction["predicted_L_task_N"],
                                                                     prediction["realised_L_task_N"])] == quoted_pairs


def test_tune_names_the_overrides_when_the_demo_is_recorded_otherwise_than_the_training_demos(
        tiny_checkpoint: Path):
    spec = yaml.safe_load((REPO / "data/demos/wavelike.yaml").read_text())
    eight = DemoSpec.from_dict({**spec, "duration_s": 8.0})
    twelve_led = DemoSpec.from_dict({**spec, "duration_s": 12.0, "lead": True})
    contact = REPO / "models/dcm_diverse_contact.ckpt"  # trained on 12 s demos with a leading demonstrator
    message = recording_mismatch(contact, eight)
    assert "12 s demos with a leading demonstrator" in message and "8 s demos without" in message
    assert "demo.duration_s=12 ++demo.lead=true" in message
    assert recording_mismatch(contact, twelve_led) is None
    assert recording_mismatch(REPO / "models/stiffness_ridge_diverse_contact.json", twelve_led) is None
    realistic = REPO / "models/dcm_realistic.ckpt"  # trained on 8 s demos without a leading demonstrator
    assert "demo.duration_s=8 ++demo.lead=false" in recording_mismatch(realistic, twelve_led)
    assert recording_mismatch(realistic, eight) is None
    assert recording_mismatch(tiny_checkpoint, eight) is None  # a training checkpoint names no preset
    assert recording_mismatch("copy_demo", eight) is None


def _trained_on_preset(tmp_path: Path, preset: str, recorded: dict | None = None) -> Path:
    """The shipped DCM with a card naming another training preset (and the recording of its demos, which an
    exported run stores): what exporting a run on it would give."""
    raw = read_checkpoint(REPO / "models/dcm_diverse_contact.ckpt")
    raw[CARD_KEY]["dataset"]["dataset"] = preset
    if recorded is not None:
        raw[CARD_KEY]["dataset"]["recording"] = recorded
    torch.save(raw, tmp_path / f"dcm_{preset}.ckpt")
    return tmp_path / f"dcm_{preset}.ckpt"


def test_tune_names_the_bowl_grid_of_a_predictor_trained_on_a_converged_grid(tmp_path: Path):
    """A predictor of the *_fine presets learned forces on a 192 x 192 bowl grid; a skill on a coarser grid
    shows facet jumps it never saw, so tune.py names the inline bowl that gives the skill's bowl that grid.
    diverse_contact_fine is a research preset (studies/conf/dataset), which the product cannot look up: the
    card's stored recording is what tells."""
    import dcm.data.recording as rec
    from dcm.data.generate import compose_config

    research = f"hydra.searchpath=[file://{REPO / 'studies' / 'conf'}]"
    fine_recording = rec.recording(compose_config("diverse_contact_fine", [research]).dataset)
    assert rec.preset_recording("diverse_contact_fine") is None
    spec = yaml.safe_load((REPO / "data/demos/wavelike.yaml").read_text())
    coarse = DemoSpec.from_dict({**spec, "duration_s": 12.0, "lead": True})
    assert coarse.bowl.hfield_res != 192
    fine_ckpt = _trained_on_preset(tmp_path, "diverse_contact_fine", fine_recording._asdict())
    message = recording_mismatch(fine_ckpt, coarse)
    assert "on a 192 x 192 bowl grid" in message and f"on a {coarse.bowl.hfield_res} x" in message
    override = message.split("were: ")[1].split(" (or")[0]
    assert override.startswith("'demo.bowl={") and "hfield_res:192" in override
    with initialize_config_dir(config_dir=str(REPO / "conf")):  # the override, as tune.py reads it
        cfg = compose("tune", overrides=["demo=wavelike", "demo.duration_s=12.0", "+demo.lead=true",
                                         override.strip("'")])
    fine = DemoSpec.from_dict(OmegaConf.to_container(cfg.demo))
    assert fine.bowl.hfield_res == 192 and fine.bowl.rim_radius_m == coarse.bowl.rim_radius_m
    assert recording_mismatch(fine_ckpt, fine) is None
    assert recording_mismatch(REPO / "models/dcm_diverse_contact.ckpt", fine) is None  # its bowls keep their own grid


def test_tune_names_the_approach_height_of_a_preset_that_sets_one(monkeypatch: pytest.MonkeyPatch):
    import dcm.data.recording as rec

    monkeypatch.setattr(rec, "preset_recording", lambda name: rec.Recording(12.0, True, None, 0.0))
    spec = yaml.safe_load((REPO / "data/demos/wavelike.yaml").read_text())
    hovering = DemoSpec.from_dict({**spec, "duration_s": 12.0, "lead": True})
    message = recording_mismatch(REPO / "models/dcm_diverse_contact.ckpt", hovering)
    assert message.endswith("++demo.hover_m=0 (or those fields of demo_file)")
    assert f"approaching from {hovering.hover_m:g} m above the bowl" in message
    assert recording_mismatch(REPO / "models/dcm_diverse_contact.ckpt",
                              DemoSpec.from_dict({**spec, "duration_s": 12.0, "lead": True, "hover_m": 0.0})) is None


def test_a_prior_blends_the_tuners_model_with_the_stiffness_ridge(tiny_checkpoint: Path, tiny_dataset_path: Path,
                                                                   tmp_path: Path):
    """prior=<ridge.json> prior_weight=w: every virtual trial's L_task is L_model^(1-w) L_ridge^w, the log
    knows the prior and its weight, and a bad weight is named before any trial."""
    from dcm.models.predict import predict_task_loss, with_prior
    from dcm.models.references import main as references_main

    ref = references_main(["fit", "--dataset", str(tiny_dataset_path), "--out", str(tmp_path / "ref.json")])
    demo, out_dir = short_wave_demo(tmp_path), tmp_path / "run"
    small = ["robot_based.n_trials=0", f"prior={ref}"]
    results = tune(_config(tiny_checkpoint, demo, out_dir, 8, *small, "prior_weight=0.5"), out_dir)
    assert results["predictor"]["prior_weight"] == 0.5
    cfg = _config(tiny_checkpoint, demo, out_dir, 8, *small, "prior_weight=0.5")
    simulator, recorded, skill = record_skill(cfg, check_config(cfg))
    phases, objectives = TrialLog.load(out_dir / "robot_free_trials.npz").arrays()
    stiffness = skill.schedules(phases)
    inputs = (np.repeat(recorded.x_demo[None], len(phases), axis=0),
              np.repeat(recorded.force_demo[None], len(phases), axis=0),
              np.stack([simulator.attractor(recorded, k) for k in stiffness]), stiffness)
    model = load_model(tiny_checkpoint)
    use_sampler(model, "ddim", 5)  # as _config samples, in the default float32
    blend = with_prior(model, ref, 0.5, "test")
    assert blend.combine(np.array([4.0]), np.array([1.0])) == pytest.approx([2.0])  # the geometric mean
    first = 8  # robot_free.batch_size: the first batch, seeded as the tuner seeds it
    generator = torch.Generator(device=model.device).manual_seed(batch_seed(0, 0))
    expected = predict_task_loss(blend, *(a[:first] for a in inputs), generator=generator)
    assert objectives[:first, 0] == pytest.approx(expected, rel=1e-6)
    assert np.all(objectives[:, 0] != pytest.approx(load_model(ref).predict_task_loss(*inputs)))  # not the ridge alone
    with pytest.raises(TrialLogMismatch, match="prior_weight: 0.5 -> 0.25"):
        tune(_config(tiny_checkpoint, demo, out_dir, 8, *small, "prior_weight=0.25"), out_dir)
    with pytest.raises(TuneConfigError, match=r"prior_weight = 2 must be a number in \[0, 1\]"):
        tune(_config(tiny_checkpoint, demo, out_dir, 8, *small, "prior_weight=2", "overwrite=true"), out_dir)


def test_the_recording_warning_of_a_waypoint_demo_names_the_file_s_own_duration(tmp_path: Path):
    csv = tmp_path / "my_path.csv"
    csv.write_text("t,x,y,press\n0,0.0,0.0,0.01\n5,0.03,0.0,0.01\n10,0.03,0.03,0.01\n")
    spec = DemoSpec.from_dict({"family": "waypoints", "waypoints": str(csv), "bowl": "medium", "lead": True})
    message = recording_mismatch(REPO / "models/dcm_diverse_contact.ckpt", spec, control_hz=20.0)
    assert "this skill's demo: 10 s demos with a leading demonstrator" in message
    assert f"retime {csv} to span 11.95 s (240 steps at 20 Hz" in message and "demo.duration_s" not in message
    csv.write_text("t,x,y,press\n0,0.0,0.0,0.01\n5,0.03,0.0,0.01\n11.95,0.03,0.03,0.01\n")  # 240 steps: 12 s
    spec = DemoSpec.from_dict({"family": "waypoints", "waypoints": str(csv), "bowl": "medium", "lead": True})
    assert recording_mismatch(REPO / "models/dcm_diverse_contact.ckpt", spec, control_hz=20.0) is None


def test_the_reference_point_depends_on_the_skill_alone(tiny_checkpoint: Path, tmp_path: Path):
    """Two seeds of one skill score their hypervolumes on one point, set by the skill (a rollout at the demo's
    own stiffness, and the stiffest schedule), never by what either search found; a given point wins."""
    from dcm.control import compliance_loss

    demo = short_wave_demo(tmp_path)
    runs = [tune(_config(tiny_checkpoint, demo, tmp_path / f"seed{seed}", 8, f"seed={seed}", "domain=realistic"),
                 tmp_path / f"seed{seed}") for seed in (0, 1)]
    first, second = (run["reference_point"] for run in runs)
    assert first == second and first["source"] == "skill"
    assert runs[0]["robot_free"]["solutions"] != runs[1]["robot_free"]["solutions"]  # the searches differed

    from dcm.tuning.setup import REFERENCE_COMP_FACTOR, REFERENCE_TASK_FACTOR

    cfg = _config(tiny_checkpoint, demo, tmp_path / "seed0", 8, "domain=realistic")
    simulator, recorded, skill = record_skill(cfg, check_config(cfg))
    stiffness = np.tile(np.asarray(recorded.spec.stiffness_Npm), (1, cfg.stiffness.n_phases, 1))
    at_demo = SimulatorObjective(simulator, recorded, skill)(stiffness)[0, 0]
    assert first["L_task_N"] == pytest.approx(REFERENCE_TASK_FACTOR * at_demo)
    stiffest = skill.schedules(np.full((1, cfg.stiffness.n_phases, 3), cfg.stiffness.max_Npm))
    assert first["L_comp_kNpm"] == pytest.approx(REFERENCE_COMP_FACTOR * compliance_loss(stiffest)[0])

    given = tune(_config(tiny_checkpoint, demo, tmp_path / "given", 8, "reference_point=[3.0,2.0]"),
                 tmp_path / "given")["reference_point"]
    assert (given["L_task_N"], given["L_comp_kNpm"], given["source"]) == (3.0, 2.0, "reference_point")


def _deep_path(tmp_path: Path) -> Path:
    """A 12 s circle pressed 0.05 m deep: a demo force far above any the shipped models trained on."""
    t = np.arange(0.0, 12.0, 0.5)
    angle = np.linspace(0.0, 2 * np.pi, len(t))
    rows = "".join(f"{a:g},{0.06 * np.cos(b):.5f},{0.06 * np.sin(b):.5f},0.05\n" for a, b in zip(t, angle))
    path = tmp_path / "deep.csv"
    path.write_text("t,x,y,press\n" + rows)
    return path


def _shipped_config(tmp_path: Path, *extra: str):
    with initialize_config_dir(config_dir=str(REPO / "conf")):
        return compose("tune", overrides=[
            f"ckpt={REPO / 'models/dcm_diverse_contact.ckpt'}", "embodiment=tool", f"out_dir={tmp_path / 'run'}",
            "robot_free.n_trials=6", "robot_free.batch_size=6", "robot_free.n_validate=2", "robot_based.n_trials=0",
            "search.options.n_startup_trials=4", "+demo.lead=true", *extra])


def test_the_tuner_warns_where_the_skill_conditions_the_model_outside_its_training_range(tmp_path: Path):
    from dcm.tuning.diagnostics import ConditioningRangeWarning

    cfg = _shipped_config(tmp_path, "demo=waypoints", f"demo.waypoints={_deep_path(tmp_path)}")
    with pytest.warns(ConditioningRangeWarning) as caught:
        results = tune(cfg, tmp_path / "run")
    lines = [str(w.message) for w in caught if issubclass(w.category, ConditioningRangeWarning)]
    force = next(line for line in lines if line.startswith("F_demo.Fz_N: "))
    assert " N lies outside the training range [" in force and "x the range's half-width" in force
    assert all("\n" not in line for line in lines)
    conditioning = results["conditioning"]
    assert conditioning["checked"] and not conditioning["in_range"]
    fz = next(c for c in conditioning["outside"] if c["channel"] == "F_demo.Fz_N")
    assert fz["value"] > 30.0 and fz["training_high"] < 20.0 and abs(fz["normalised"]) > conditioning["limit"]
    assert json.loads((tmp_path / "run" / "results.json").read_text())["conditioning"] == conditioning


def test_a_skill_like_the_training_demos_conditions_the_model_inside_its_range(tmp_path: Path):
    import warnings

    from dcm.tuning.diagnostics import ConditioningRangeWarning

    cfg = _shipped_config(tmp_path, f"demo_file={short_wave_demo(tmp_path, duration_s=12.0, approach_s=1.0, lead=True)}")
    with warnings.catch_warnings():
        warnings.simplefilter("error", ConditioningRangeWarning)
        results = tune(cfg, tmp_path / "run")
    assert results["conditioning"]["checked"] and results["conditioning"]["in_range"]


def test_predicted_and_realised_L_task_of_the_validated_solutions_are_reported(tiny_checkpoint: Path, tmp_path: Path,
                                                                               monkeypatch: pytest.MonkeyPatch):
    """After validation the run says how far the model's L_task was from the simulator's on its own picks, and
    warns when that error exceeds the documented limit: a multiple of the error its card records on the valid
    split, else an absolute tolerance."""
    from dcm.tuning import diagnostics as checks

    demo, out_dir = short_wave_demo(tmp_path), tmp_path / "run"
    monkeypatch.setattr(checks, "PREDICTION_TOLERANCE_N", 1e-9)  # any error exceeds it
    with pytest.warns(checks.PredictionErrorWarning, match=r"L_task error on the validated solutions"):
        results = tune(_config(tiny_checkpoint, demo, out_dir, 8), out_dir)
    report = results["robot_free"]["prediction"]
    solutions = results["robot_free"]["solutions"]
    errors = [abs(s["predicted"]["L_task_N"] - s["validated"]["L_task_N"]) for s in solutions]
    assert report["L_task_mae_N"] == pytest.approx(np.mean(errors)) and report["n_solutions"] == len(solutions)
    assert report["limit_source"] == "absolute tolerance" and report["exceeded"]

    limit = checks.prediction_limit(REPO / "models/dcm_diverse_contact.ckpt", prior=None)
    card = checkpoint_card(REPO / "models/dcm_diverse_contact.ckpt")["evaluations"]
    valid = card["eval_diverse_contact_valid_ref-stiffness_ridge_diverse_contact"]["L_task_mae_N"]
    assert limit["limit_N"] == pytest.approx(checks.PREDICTION_ERROR_FACTOR * valid)
    assert limit["valid_L_task_mae_N"] == pytest.approx(valid) and "valid" in limit["limit_source"]


def test_tune_py_prints_the_reference_point_and_the_prediction_error_and_warns_in_one_line(tiny_checkpoint: Path,
                                                                                          tmp_path: Path):
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "PYTHONWARNINGS"}
    run_dir = tmp_path / "run"
    proc = subprocess.run([sys.executable, str(REPO / "tune.py"), f"ckpt={tiny_checkpoint}",
                           f"demo_file={short_wave_demo(tmp_path)}", "embodiment=tool", "robot_free.n_trials=8",
                           "robot_free.batch_size=8", "robot_free.sampling_steps=5",
                           "robot_free.n_validate=2", "robot_based.n_trials=5",
                           "search.options.n_startup_trials=4", f"hydra.run.dir={run_dir}"],
                          cwd=REPO, env={**env, "MUJOCO_GL": "egl"}, capture_output=True, text=True, timeout=300,
                          check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    results = json.loads((run_dir / "results.json").read_text())
    ref, prediction = results["reference_point"], results["robot_free"]["prediction"]
    assert f"hypervolume reference point: L_task {ref['L_task_N']:.4g} N, L_comp {ref['L_comp_kNpm']:.4g} kN/m" \
        in proc.stdout
    assert f"mean |error| {prediction['L_task_mae_N']:.3g} N" in proc.stdout
    lines = [line.split("\r")[-1] for line in proc.stderr.splitlines() if line.strip()]
    warned = [line for line in lines if line.startswith("warning: ")]
    assert warned and all("Warning: " in line for line in warned)  # e.g. the tiny model's ConditioningRangeWarning
    assert all(line.startswith("warning: ") or "trial" in line for line in lines), lines  # no source lines
    assert warned[0] in (run_dir / "tune.log").read_text()


def test_a_predictor_carries_the_recording_of_the_data_it_learned_from(tiny_dataset_path: Path, tmp_path: Path):
    """A run card and a reference fit store how their dataset's demos were recorded, so tune.py's recording
    check works for data of any preset; a file that records no preset (imported logs) stores none."""
    import json

    from dcm.data.recording import file_recording, stored_recording
    from dcm.data.schema import read_root_attrs
    from dcm.models.predict import trained_recording
    from dcm.models.references import StiffnessRegression
    from dcm.training.run_dir import _dataset_identity

    expected = file_recording(tiny_dataset_path)
    assert _dataset_identity(str(tiny_dataset_path))["recording"] == expected._asdict()
    ridge = tmp_path / "ridge.json"
    ridge.write_text(json.dumps(StiffnessRegression.fit_dataset(tiny_dataset_path).to_dict()))
    assert trained_recording(ridge) == expected
    assert stored_recording({**read_root_attrs(tiny_dataset_path), "config": ""}) is None
