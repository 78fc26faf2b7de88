"""A bowl re-placed between rollouts, its surface changing (``DomainSpec.bowl_offset_std_m``,
``bowl_friction_std``), and the oracle spread check."""

import json

import numpy as np
import pytest

from dcm.sim import BowlSpec, DemoSpec, Simulator
from dcm.sim.domain import DomainSpec, DomainSpecError
from studies.task_checks import spread_check

FLAT = BowlSpec(shape="flat", rim_radius_m=0.15, depth_m=0.0, friction=0.3)
PRESS = DemoSpec(family="line", press_m=0.01, duration_s=3.0, approach_s=1.0, bowl=FLAT,
                 params={"start_xy_m": [-0.02, 0.0], "end_xy_m": [0.02, 0.0]})


@pytest.fixture(scope="module")
def demo():
    return Simulator("tool", FLAT).record_demo(PRESS)


def _normal_force_shift(demo, seed: int, stiffness_Npm: float) -> tuple[float, float]:
    sim = Simulator("tool", FLAT, DomainSpec(bowl_offset_std_m=0.003), seed=seed)
    trial = sim.rollout(demo, sim.constant_stiffness(demo, stiffness_Npm))
    steady = slice(demo.horizon // 2, None)
    return trial.bowl_offset_m, float(np.mean(trial.force_obs[steady, 2] - demo.force_demo[steady, 2]))


def test_a_raised_bowl_pushes_back_by_stiffness_times_offset(demo) -> None:
    """The controller does not know the offset, so its spring pushes ``K * offset`` more (or less) into the
    plate: the spread of the force grows with stiffness, the trade-off a distribution model can see."""
    for seed in (0, 1, 2):
        for k in (300.0, 1000.0):
            offset, shift = _normal_force_shift(demo, seed, k)
            assert offset != 0.0
            if offset > -0.008:  # a plate that drops further than the press loses contact
                assert shift == pytest.approx(k * offset, rel=0.15, abs=0.05)


def test_the_offset_is_seeded_and_off_by_default(demo) -> None:
    assert _normal_force_shift(demo, 4, 500.0) == _normal_force_shift(demo, 4, 500.0)
    assert _normal_force_shift(demo, 4, 500.0)[0] != _normal_force_shift(demo, 5, 500.0)[0]
    plain = Simulator("tool", FLAT)
    assert plain.rollout(demo, plain.constant_stiffness(demo, 500.0)).bowl_offset_m == 0.0
    # Off, the field is left out of the domain's dict, so older datasets and tuning logs keep their fingerprints.
    assert "bowl_offset_std_m" not in DomainSpec().to_dict()
    assert DomainSpec(bowl_offset_std_m=0.002).to_dict()["bowl_offset_std_m"] == 0.002
    with pytest.raises(DomainSpecError, match="bowl_offset_std_m"):
        DomainSpec(bowl_offset_std_m=0.5)


def test_the_draw_does_not_hang_on_the_last_bits_of_the_demo(demo) -> None:
    """Another CPU records the same demo with other last bits; the bowl must be drawn where it was, or every
    result of a spread domain changes with the machine (it did: the same seeds drew other offsets)."""
    from dataclasses import replace

    sim = Simulator("tool", FLAT, DomainSpec(bowl_offset_std_m=0.003), seed=4)
    stiffness = sim.constant_stiffness(demo, 500.0)
    nudged = replace(demo, x_demo=np.nextafter(demo.x_demo, np.inf), force_demo=demo.force_demo * (1 + 1e-15))
    assert sim.rollout(nudged, stiffness).bowl_offset_m == sim.rollout(demo, stiffness).bowl_offset_m
    assert sim.rollout(demo, stiffness * 1.01).bowl_offset_m != sim.rollout(demo, stiffness).bowl_offset_m


def test_a_repeated_rollout_draws_again_and_repeat_zero_is_the_trial_of_old(demo) -> None:
    """``repeat`` re-runs a schedule with another draw of the spread, as re-running it on a robot would;
    without a spread the physics is the same, so every repeat gives the same forces."""
    sim = Simulator("tool", FLAT, DomainSpec(bowl_offset_std_m=0.003), seed=4)
    stiffness = sim.constant_stiffness(demo, 500.0)
    draws = [sim.rollout(demo, stiffness, repeat=r).bowl_offset_m for r in range(4)]
    assert draws[0] == sim.rollout(demo, stiffness).bowl_offset_m == _normal_force_shift(demo, 4, 500.0)[0]
    assert len(set(draws)) == 4
    assert sim.rollout(demo, stiffness, repeat=2).bowl_offset_m == draws[2]  # seeded
    plain = Simulator("tool", FLAT)
    np.testing.assert_array_equal(plain.rollout(demo, stiffness, repeat=3).force_obs,
                                  plain.rollout(demo, stiffness).force_obs)


def test_oracle_losses_and_within_skill_r_on_known_cases() -> None:
    force_demo = np.zeros((4, 6))
    # Samples at +-2 N around the demo: each one's L_task is 2/sqrt(3) N (RMSE over three axes); the truth
    # rollouts are exact and 4 N off; the unperturbed rollout (the mean model's) is exact.
    forces = np.zeros((5, 4, 6))
    forces[0, :, 0], forces[1, :, 0], forces[3, :, 0] = 2.0, -2.0, 4.0
    losses = spread_check.oracle_losses(forces, force_demo, k=2)
    scale = np.sqrt(1 / 3)
    assert losses == pytest.approx({"distribution_1": 2 * scale, "distribution_k": 2 * scale, "mean_force": 0.0,
                                    "label": 0.0, "expected": 2 * scale})
    with pytest.raises(ValueError, match="k \\+ n_truth \\+ 1 = 5"):
        spread_check.oracle_losses(forces[:4], force_demo, k=2)
    # One sample, three truths: the expected loss is the mean over rollouts 1..3.
    assert spread_check.oracle_losses(forces, force_demo, k=1, n_truth=3)["expected"] == pytest.approx(
        (2 + 0 + 4) * scale / 3)
    skills = {"a": [{"label": 1.0, "p": 1.0}, {"label": 2.0, "p": 2.0}, {"label": 3.0, "p": 3.5}],
              "b": [{"label": 1.0, "p": 3.0}, {"label": 2.0, "p": 2.0}, {"label": 3.0, "p": 1.0}]}
    assert spread_check.within_skill_r(skills, "p") == pytest.approx((0.9933992677987828 - 1.0) / 2)
    assert spread_check.within_skill_r(skills, "p", truth="p") == pytest.approx(1.0)


def test_top_pick_regret_on_known_cases() -> None:
    """0 when a predictor keeps the truly best schedules, 1 for the average pick, above 1 when it keeps the
    worst; NaN for one that ranks nothing."""
    expected = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]  # mean 4, best 1
    rows = [{"expected": e, "label": e, "right": e, "wrong": -e, "flat": 0.0,
             "middle": abs(e - 4.0) if e != 4.0 else -1.0} for e in expected]
    skills = {"a": rows}
    assert spread_check.top_pick_regret(skills, "right") == pytest.approx(0.0)  # keeps 1, 2, 3, the best three
    assert spread_check.top_pick_regret(skills, "wrong") == pytest.approx((6 - 2) / (4 - 2))  # keeps 5, 6, 7
    assert spread_check.top_pick_regret(skills, "right", n_top=1) == pytest.approx(0.0)
    assert spread_check.top_pick_regret(skills, "wrong", n_top=1) == pytest.approx(2.0)  # keeps 7: (7-1)/(4-1)
    assert spread_check.top_pick_regret(skills, "middle", n_top=1) == pytest.approx(1.0)  # keeps 4, the mean
    assert np.isnan(spread_check.top_pick_regret(skills, "flat"))


def test_the_regret_key_is_the_metrics_one() -> None:
    """spread_check keeps its own TOP_PICKS to load without torch; the two must not drift apart."""
    from dcm.models.metrics import REGRET_KEY, TOP_PICKS

    assert spread_check.TOP_PICKS == TOP_PICKS and f"top{spread_check.TOP_PICKS}_regret" == REGRET_KEY


def test_without_a_perturbation_every_oracle_ranks_perfectly(tmp_path) -> None:
    """The known answer: with no per-rollout perturbation every rollout repeats the label, so every oracle
    has R = 1; with one, the rollouts differ and the oracles fall below 1."""
    result = spread_check.main(["--dataset", "tiny", "--max-skills", "1", "--n-schedules", "4", "--k", "1",
                                "--n-truth", "2", "--bowl-offset-mm", "0", "3", "--out", str(tmp_path),
                                "--predictor", "copy=copy_demo"])
    exact, offset = result["by_spread"]["bowl_offset_std_mm=0"], result["by_spread"]["bowl_offset_std_mm=3"]
    for truth in spread_check.TRUTHS:
        assert {p: exact["R_within"][truth][p] for p in spread_check.PREDICTORS} == {
            p: pytest.approx(1.0) for p in spread_check.PREDICTORS}
    rows = next(iter(offset["skills"].values()))
    assert len(rows) == 4 and all(r["offset_std_mm"] > 0 for r in rows)
    assert any(r["label"] != r["distribution_1"] for r in rows)
    assert all(r["copy"] == 0.0 for r in rows), "copying F_demo predicts no force error at all"
    assert all(r["force_spread_N"] == 0.0 for r in next(iter(exact["skills"].values())))  # the same force each time
    assert all(r["force_spread_N"] > 0.0 for r in rows)
    stored = tmp_path / "spread_check.json"
    assert json.loads(stored.read_text())["k"] == 1
    assert exact["top3_regret"]["mean_force"] == pytest.approx(0.0)
    # Rescoring a stored file recomputes every statistic from its rows alone: the same bytes again.
    written = stored.read_text()
    spread_check.main(["--rescore", str(stored)])
    assert stored.read_text() == written
    with pytest.raises(SystemExit):
        spread_check.main(["--rescore", str(tmp_path / "missing.json")])
    with pytest.raises(SystemExit):  # past the last skill of the split
        spread_check.main(["--dataset", "tiny", "--first-skill", "50", "--out", str(tmp_path)])


def test_the_drag_follows_the_drawn_friction(demo) -> None:
    """A surface that changes between trials: each rollout draws its friction factor (mean-preserving
    log-normal), and the sliding tool's drag is that friction times the normal force."""
    slide = Simulator("tool", FLAT).record_demo(
        DemoSpec.from_dict({**PRESS.to_dict(), "params": {"start_xy_m": [-0.04, 0.0], "end_xy_m": [0.04, 0.0]}}))
    factors = []
    for seed in range(3):
        sim = Simulator("tool", FLAT, DomainSpec(bowl_friction_std=0.3), seed=seed)
        trial = sim.rollout(slide, sim.constant_stiffness(slide, 500.0))
        sliding = slice(slide.horizon // 2, 3 * slide.horizon // 4)
        drag, normal = -trial.force_obs[sliding, 0].mean(), trial.force_obs[sliding, 2].mean()
        assert drag == pytest.approx(FLAT.friction * trial.bowl_friction_factor * normal, rel=0.1)
        factors.append(trial.bowl_friction_factor)
    assert len(set(factors)) == 3 and all(0.3 < f < 3 for f in factors)
    plain = Simulator("tool", FLAT)
    assert plain.rollout(demo, plain.constant_stiffness(demo, 500.0)).bowl_friction_factor == 1.0
    assert "bowl_friction_std" not in DomainSpec().to_dict()
    with pytest.raises(DomainSpecError, match="bowl_friction_std"):
        DomainSpec(bowl_friction_std=-0.1)
    spread = Simulator("tool", FLAT, DomainSpec(bowl_friction_std=0.3))
    draws = [spread._bowl_draw(np.random.default_rng(i)).friction_factor for i in range(2000)]
    assert np.mean(draws) == pytest.approx(1.0, abs=0.02)


def test_the_check_compares_friction_spreads_with_more_truth_rollouts(tmp_path, tiny_checkpoint,
                                                                      monkeypatch) -> None:
    """Friction alone, three truth rollouts, and a DCM drawing its own number of samples once, scored both
    ways from them."""
    from dcm.models.dcm import DCM

    drawn = []
    original = DCM.predict_forces

    def recording(self, *args, n_samples=None, **kwargs):
        drawn.append(n_samples)
        return original(self, *args, n_samples=n_samples, **kwargs)

    monkeypatch.setattr(DCM, "predict_forces", recording)
    result = spread_check.main(["--dataset", "tiny", "--max-skills", "1", "--n-schedules", "3", "--k", "1",
                                "--n-truth", "3", "--model-samples", "2", "--friction-std", "0.3",
                                "--out", str(tmp_path), "--predictor", f"dcm={tiny_checkpoint}"])
    assert list(result["by_spread"]) == ["bowl_friction_std=0.3"]
    assert (result["n_truth"], result["model_samples"]) == (3, 2) and set(drawn) == {2}
    assert len(drawn) == 1, "both read-outs come from one draw of samples"
    rows = next(iter(result["by_spread"]["bowl_friction_std=0.3"]["skills"].values()))
    assert all(r["friction_factor_std"] > 0 and r["offset_std_mm"] == 0 for r in rows)
    assert all(np.isfinite(r["dcm"]) and np.isfinite(r["dcm, over samples"]) for r in rows)
    assert any(r["dcm, over samples"] != r["dcm"] for r in rows), "the samples' spread counts one way only"
    assert all(r["force_spread_N"] > 0 and r["dcm, force spread"] > 0 for r in rows)
    calibration = result["by_spread"]["bowl_friction_std=0.3"]["spread_calibration"]
    assert list(calibration) == ["dcm"] and "dcm, force spread" not in result["by_spread"][
        "bowl_friction_std=0.3"]["R_within"]["label"], "a spread is not a prediction of L_task"
    ratios = [r["dcm, force spread"] / r["force_spread_N"] for r in rows]
    assert calibration["dcm"]["ratio_median"] == pytest.approx(float(np.median(ratios)))
    again = spread_check.main(["--dataset", "tiny", "--max-skills", "1", "--n-schedules", "3", "--k", "1",
                               "--n-truth", "3", "--model-samples", "2", "--friction-std", "0.3",
                               "--out", str(tmp_path / "again"), "--predictor", f"dcm={tiny_checkpoint}"])
    assert next(iter(again["by_spread"]["bowl_friction_std=0.3"]["skills"].values())) == rows, "same seed, same scores"


def test_spread_calibration_on_known_cases() -> None:
    """The force spread is the RMS over time and force axes of the per-step std (torques left out); a model
    spreading half as much as the rollouts, in proportion, has median ratio 0.5 and within-skill R 1."""
    std = np.zeros((2, 5, 6))
    std[0, :, :3], std[1, :, :3], std[:, :, 3:] = 2.0, [[1.0, 2.0, 2.0]], 9.0
    np.testing.assert_allclose(spread_check.force_spread(std), [2.0, np.sqrt(3.0)])
    truth = {"a": [0.2, 0.4, 0.8], "b": [1.0, 2.0, 1.5]}
    skills = {name: [{"force_spread_N": t, "m, force spread": 0.5 * t} for t in values]
              for name, values in truth.items()}
    calibration = spread_check.spread_calibration(skills, "m, force spread")
    assert calibration["ratio_median"] == pytest.approx(0.5) and calibration["R_within"] == pytest.approx(1.0)
    assert calibration["truth_median_N"] == pytest.approx(0.9)
    for rows in skills.values():  # the same sizes, in the opposite order of the schedules
        spreads = [r["force_spread_N"] for r in rows]
        for row in rows:
            row["m, force spread"] = 0.5 * (max(spreads) + min(spreads) - row["force_spread_N"])
    assert spread_check.spread_calibration(skills, "m, force spread")["R_within"] == pytest.approx(-1.0)


def test_a_dcm_predictor_takes_the_chosen_sampler(tiny_checkpoint) -> None:
    """``--sampler ddim --sampling-steps`` score a DCM as the tuner samples it; steps that do not divide T
    are an error naming the predictor."""
    def fail(message: str):
        raise SystemExit(message)

    model = spread_check.load_predictors([f"dcm={tiny_checkpoint}"], fail, "ddim", 5)["dcm"]
    assert (model.cfg.sampler, model.cfg.sampling_steps) == ("ddim", 5)
    assert spread_check.load_predictors([f"dcm={tiny_checkpoint}"], fail)["dcm"].cfg.sampler == "ddpm"
    with pytest.raises(SystemExit, match="--predictor 'dcm="):
        spread_check.load_predictors([f"dcm={tiny_checkpoint}"], fail, "ddim", 3)
