"""Dataset generation: the tiny preset, reproducibility across workers/shards, kill + resume, failed trials."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from dcm.data.generate import GenerationError, compose_config, generate
from dcm.data.merge import merge_shards, part_trajectories, write_part
from dcm.data.schema import FIELDS, load_dataset
from dcm.search import MOTPESearch, RandomSearch, SearchSpace

REPO = Path(__file__).resolve().parents[1]
RESEARCH_PRESETS = f"hydra.searchpath=[file://{REPO / 'studies' / 'conf'}]"  # studies/conf/dataset/


def _all_arrays(path: Path) -> dict[str, dict[str, np.ndarray]]:
    with h5py.File(path, "r") as f:
        return {name: {k: f["data"][name][k][()] for k in FIELDS} for name in f["data"]}


def _masks(path: Path) -> dict[str, list[bytes]]:
    with h5py.File(path, "r") as f:
        return {s: f["mask"][s][()].tolist() for s in f["mask"]}


def assert_same_data(a: Path, b: Path) -> None:
    arrays_a, arrays_b = _all_arrays(a), _all_arrays(b)
    assert sorted(arrays_a) == sorted(arrays_b)
    for name in arrays_a:
        for field in FIELDS:
            np.testing.assert_array_equal(arrays_a[name][field], arrays_b[name][field], err_msg=f"{name}/{field}")
    assert _masks(a) == _masks(b)


def test_tiny_dataset(tiny_dataset_path: Path) -> None:
    train = load_dataset(tiny_dataset_path, split="train", expect_control_hz=20.0)
    assert train.horizon == 40 and len(train) == 9 and len(set(train.demo_ids)) == 3
    assert train.arrays["x_demo"].shape == (9, 40, 6)
    assert len(load_dataset(tiny_dataset_path, split="valid")) == 3
    test = load_dataset(tiny_dataset_path, split="test")
    assert len(test) == 3 and test.meta[0]["demo"]["family"] == "wavelike"
    assert np.all(train.L_comp > 0) and np.all(np.isfinite(train.L_task))
    meta = train.meta[0]
    assert meta["embodiment"] == "tool" and meta["domain"]["name"] == "nominal" and "rim_radius_m" in meta["bowl"]
    assert len(meta["phase_stiffness_Npm"]) == 3 and meta["phase_boundaries"][-1] == 40
    # trials of one demo share the demo but differ in stiffness, hence in force
    assert np.array_equal(train.arrays["x_demo"][0], train.arrays["x_demo"][1])
    assert not np.array_equal(train.arrays["K"][0], train.arrays["K"][1])
    assert "search:" in train.attrs["config"] and train.attrs["dcm_version"]


def test_shards_merge_to_the_full_dataset(tiny_dataset_path: Path, tmp_path: Path) -> None:
    out = tmp_path / "tiny.h5"
    shards = []
    for index in (1, 0):
        cfg = compose_config("tiny", [f"out={out}", "workers=1", "progress=false", "shard.count=2",
                                      f"shard.index={index}"])
        shards.append(generate(cfg))
    assert sorted(p.name for p in shards) == ["tiny.shard-0-of-2.h5", "tiny.shard-1-of-2.h5"]
    with pytest.raises(ValueError, match="every shard"):
        merge_shards(out, shards[:1])
    merge_shards(out, shards)
    assert_same_data(out, tiny_dataset_path)
    np.testing.assert_allclose(load_dataset(out).stats["F_obs"]["mean"],
                               load_dataset(tiny_dataset_path).stats["F_obs"]["mean"])


def test_merge_refuses_an_existing_output_unless_told_to_overwrite(
        tiny_dataset_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """An existing output (or a shard taken for it, when the output was left out) is named in one line and
    left as it was; --overwrite replaces it; the shards are never written."""
    from dcm.data.merge import main as merge_main

    shards = [str(generate(compose_config("tiny", [f"out={tmp_path / 'tiny.h5'}", "workers=1", "progress=false",
                                                   "shard.count=2", f"shard.index={i}"]))) for i in (0, 1)]
    shard_bytes = [Path(s).read_bytes() for s in shards]
    out = tmp_path / "merged.h5"
    out.write_text("an earlier dataset")
    assert merge_main([str(out), *shards]) == 1
    err = capsys.readouterr().err
    assert err == f"error: merge failed: {out} exists; pass --overwrite to replace it, or choose another output\n"
    assert out.read_text() == "an earlier dataset"
    assert merge_main(shards) == 1  # the output left out: shard 0 would have been replaced
    assert f"{shards[0]} exists; pass --overwrite" in capsys.readouterr().err
    assert merge_main(["--overwrite", shards[0], *shards]) == 1
    assert f"{shards[0]} is both the output and a shard" in capsys.readouterr().err
    assert merge_main([str(tmp_path), *shards]) == 1
    assert capsys.readouterr().err == f"error: merge failed: cannot write {tmp_path}: {tmp_path} is a directory\n"
    (tmp_path / "a_file").write_text("")
    assert merge_main([str(tmp_path / "a_file" / "merged.h5"), *shards]) == 1
    assert "is not a writable directory" in capsys.readouterr().err
    assert merge_main(["--overwrite", str(out), *shards]) == 0
    assert_same_data(out, tiny_dataset_path)
    assert [Path(s).read_bytes() for s in shards] == shard_bytes


def test_valid_split_alone_is_the_full_runs_valid_split(tiny_dataset_path: Path, tmp_path: Path) -> None:
    # one name without brackets is that split (it was taken letter by letter)
    out = generate(compose_config("tiny", [f"out={tmp_path / 'valid.h5'}", "workers=1", "progress=false",
                                           "splits=valid"]))
    alone, full = load_dataset(out, split="valid"), load_dataset(tiny_dataset_path, split="valid")
    assert len(alone) == len(full) == len(load_dataset(out)) == 3
    for field in FIELDS:
        np.testing.assert_array_equal(alone.arrays[field], full.arrays[field], err_msg=field)
    with pytest.raises(GenerationError, match=r"splits=\['val'\]: unknown split"):
        generate(compose_config("tiny", [f"out={tmp_path / 'v.h5'}", "splits=val"]))


def _run(args: list[str], **kwargs) -> subprocess.Popen:
    env = {**os.environ, "MUJOCO_GL": "egl"}
    return subprocess.Popen([sys.executable, "-m", "dcm.data.generate", *args], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kwargs)


def test_kill_and_resume_gives_identical_arrays(tiny_dataset_path: Path, tmp_path: Path) -> None:
    out = tmp_path / "resumed.h5"
    parts = tmp_path / "resumed.h5.parts"
    args = ["dataset=tiny", f"out={out}", "progress=false", f"hydra.run.dir={tmp_path / 'hydra'}"]
    proc = _run([*args, "workers=1"], start_new_session=True)
    deadline = time.monotonic() + 120
    while not list(parts.glob("demo_*.npz")):
        assert proc.poll() is None, proc.communicate()[1][-2000:]
        assert time.monotonic() < deadline, "no part file appeared within 120 s"
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not out.exists()
    n_done = len(list(parts.glob("demo_*.npz")))
    assert 1 <= n_done < 5
    resumed = _run([*args, "workers=2"])
    _, stderr = resumed.communicate(timeout=300)
    assert resumed.returncode == 0, stderr[-3000:]
    assert "resuming:" in stderr
    assert_same_data(out, tiny_dataset_path)  # also: 2 workers reproduce the 1-worker run
    assert not parts.exists()


def test_stale_parts_are_refused(tmp_path: Path) -> None:
    out = tmp_path / "t.h5"
    base = [f"out={out}", "workers=1", "progress=false", "keep_parts=true", "shard.count=5", "shard.index=4"]
    generate(compose_config("tiny", base))
    with pytest.raises(GenerationError, match="different settings"):
        generate(compose_config("tiny", [*base, "seed=1"]))


def test_failed_trials_are_kept_but_masked(tmp_path: Path) -> None:
    horizon, n = 8, 2
    rng = np.random.default_rng(0)
    arrays = {k: rng.normal(size=(n, horizon, 6)).astype(np.float32) for k in ("x_attr", "K", "x_obs", "F_obs")}
    arrays["K"] = np.abs(arrays["K"]) + 100
    arrays["x_obs"][1, 5:] = np.nan  # a diverged rollout may carry garbage
    arrays.update(contact=np.ones((n, horizon), np.uint8), L_task=np.array([0.5, np.inf]), L_comp=np.array([1.0, 1.1]),
                  failed=np.array([False, True]), failure_reason=np.array(["", "contact force 412 N > 300 N"]),
                  phase_stiffness_Npm=np.full((n, 1, 3), 500.0), x_demo=np.zeros((horizon, 6), np.float32),
                  F_demo=np.zeros((horizon, 6), np.float32), phase_boundaries=np.array([0, horizon]))
    job = {"index": 0, "skill": "spiral", "n_trials": n, "trial_splits": ["train", "train"], "seed": 1,
           "first_traj": 0}
    meta = {"job": job, "demo": {"family": "spiral", "bowl": {}}, "embodiment": "tool", "domain": {"name": "nominal"},
            "search": "random"}
    path = write_part(tmp_path, 0, arrays, meta)
    from dcm.data.merge import assemble

    assemble([path], tmp_path / "f.h5", {"control_hz": 20.0})
    data = load_dataset(tmp_path / "f.h5", split="train")
    assert data.names == ["traj_000000"]
    everything = load_dataset(tmp_path / "f.h5", include_failed=True)
    assert everything.meta[1]["failed"] and "412 N" in everything.meta[1]["failure_reason"]
    assert np.all(np.isfinite(everything.arrays["x_obs"]))
    assert len(part_trajectories(arrays, meta)) == 2


def test_search_strategies_are_seeded() -> None:
    space = SearchSpace(n_phases=2, min_Npm=100, max_Npm=1500)

    def proposals(search) -> np.ndarray:
        out = []
        for i in range(8):
            k = search.ask()
            search.tell(None if i == 3 else (float(k.sum()) / 1e3, float(k.mean()) / 1e3))
            out.append(k)
        return np.array(out)

    a = proposals(MOTPESearch(space, seed=5, n_startup_trials=3))
    np.testing.assert_array_equal(a, proposals(MOTPESearch(space, seed=5, n_startup_trials=3)))
    assert a.shape == (8, 2, 3) and a.min() >= 100 and a.max() <= 1500
    assert not np.array_equal(a, proposals(MOTPESearch(space, seed=6, n_startup_trials=3)))
    r = proposals(RandomSearch(space, seed=5))
    np.testing.assert_array_equal(r, proposals(RandomSearch(space, seed=5)))


def test_missing_embodiment_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(GenerationError, match="embodiment='nope'"):
        generate(compose_config("tiny", [f"out={tmp_path / 'x.h5'}", "embodiment=nope", "progress=false"]))


# -- the diverse presets (spirals + random curves) ------------------------------------------------------------
def _plan(preset: str) -> list:
    from omegaconf import OmegaConf

    from dcm.data.presets import plan_demos

    return plan_demos(OmegaConf.to_container(compose_config(preset, [RESEARCH_PRESETS]).dataset, resolve=True), 0)


def _skill_splits(jobs: list) -> dict[tuple[str, str], int]:
    counts: dict[tuple[str, str], int] = {}
    for job in jobs:
        for split in set(job.trial_splits):
            counts[(job.skill, split)] = counts.get((job.skill, split), 0) + 1
    return counts


def test_diverse_preset_plan() -> None:
    jobs = _plan("diverse")
    assert _skill_splits(jobs) == {("spiral", "train"): 36, ("spiral", "valid"): 4, ("curve", "train"): 36,
                                   ("curve", "valid"): 4, ("wavelike", "test"): 1, ("line", "test"): 1}
    assert sum(job.n_trials for job in jobs) == 80 * 20 + 2 * 30  # about the cost of sim (80 x 20 + 30)
    sim = _plan("sim")
    sim_spirals = [job.spec for job in sim if job.skill == "spiral"]
    assert all(job.spec in sim_spirals for job in jobs if job.skill == "spiral")  # a subset of sim's spirals
    assert [j.spec for j in jobs if j.skill == "wavelike"] == [j.spec for j in sim if j.skill == "wavelike"]
    curves = [job.spec for job in jobs if job.skill == "curve"]
    assert sorted(c["params"]["seed"] for c in curves) == list(range(40))  # one curve per skill
    assert {(c["bowl"]["rim_radius_m"], c["bowl"]["depth_m"]) for c in curves} == \
        {(s["bowl"]["rim_radius_m"], s["bowl"]["depth_m"]) for s in sim_spirals}  # the same 20 bowls


def test_diverse_contact_is_diverse_recorded_at_12_s_with_the_lead() -> None:
    diverse, contact = _plan("diverse"), _plan("diverse_contact")
    assert [(j.skill, j.trial_splits, j.n_trials) for j in contact] == \
        [(j.skill, j.trial_splits, j.n_trials) for j in diverse]
    for d, c in zip(diverse, contact):
        assert c.spec == {**d.spec, "duration_s": 12.0, "lead": True}


def test_diverse_contact_wide_keeps_diverse_contact_and_adds_unseen_train_bowls() -> None:
    contact, wide = _plan("diverse_contact"), _plan("diverse_contact_wide")
    assert wide[:len(contact)] == contact  # same demos, seeds and splits: judged on the same held-out skills
    extra = wide[len(contact):]
    assert {job.trial_splits for job in extra} == {("train",) * 20}
    assert sum(job.n_trials for job in wide) == 4300
    seeds = [job.spec["params"]["seed"] for job in extra if job.skill == "curve_wide"]
    assert sorted(seeds) == list(range(40, 148))  # no curve of diverse_contact repeated

    def bowl(job) -> tuple[float, float]:
        return job.spec["bowl"]["rim_radius_m"], job.spec["bowl"]["depth_m"]

    valid_bowls = {bowl(j) for j in contact if "valid" in j.trial_splits}
    assert valid_bowls and not valid_bowls & {bowl(j) for j in extra}


def test_diverse_contact_slow_extends_the_wide_preset_with_slow_train_curves() -> None:
    wide, slow = _plan("diverse_contact_wide"), _plan("diverse_contact_slow")
    assert slow[:len(wide)] == wide  # extra_skills merge across presets: the wide groups are not restated
    extra = slow[len(wide):]
    assert {job.skill for job in extra} == {"curve_slow"} and len(extra) == 108
    assert {job.trial_splits for job in extra} == {("train",) * 20}
    assert {tuple(job.spec["params"]["speed_mps"]) for job in extra} == {(0.01, 0.04)}
    seeds = [job.spec["params"]["seed"] for job in wide + extra if job.skill.startswith("curve")]
    assert len(seeds) == len(set(seeds))


def test_diverse_contact_fine_is_the_slow_preset_on_a_finer_bowl_grid() -> None:
    slow, fine = _plan("diverse_contact_slow"), _plan("diverse_contact_fine")
    assert [(j.skill, j.trial_splits, j.seed) for j in fine] == [(j.skill, j.trial_splits, j.seed) for j in slow]
    for s, f in zip(slow, fine):
        assert f.spec == {**s.spec, "bowl": {**s.spec["bowl"], "hfield_res": 192}}


def test_diverse_contact_rest_is_the_fine_preset_approaching_from_the_bowl() -> None:
    fine, rest = _plan("diverse_contact_fine"), _plan("diverse_contact_rest")
    assert [(j.skill, j.trial_splits, j.seed) for j in rest] == [(j.skill, j.trial_splits, j.seed) for j in fine]
    for f, r in zip(fine, rest):
        assert r.spec == {**f.spec, "hover_m": 0.0}


def test_extra_skills_must_be_a_mapping() -> None:
    from dcm.data.presets import PresetError, plan_demos

    with pytest.raises(PresetError, match=r"dataset.extra_skills must map a group name"):
        plan_demos({"skills": [{"spec": {"family": "line"}}], "extra_skills": [{"spec": {"family": "line"}}]}, 0)
    with pytest.raises(PresetError, match=r"dataset.extra_skills.more = 3 must be a skill group"):
        plan_demos({"skills": [{"spec": {"family": "line"}}], "extra_skills": {"more": 3}}, 0)


def test_preset_axes_zip_and_enumerate_are_checked() -> None:
    from dcm.data.presets import PresetError, expand_skill

    skill = {"spec": {"family": "curve"}, "vary": [{"keys": ["params.harmonics", "bowl.rim_radius_m"],
                                                     "values": [[2, 0.1], [4, 0.12]]}],
             "enumerate": {"key": "params.seed", "start": 5}}
    specs = expand_skill(skill, {}, "s")
    assert [(s["params"], s["bowl"]["rim_radius_m"]) for s in specs] == \
        [({"harmonics": 2, "seed": 5}, 0.1), ({"harmonics": 4, "seed": 6}, 0.12)]
    with pytest.raises(PresetError, match=r"s.vary\[0\].values\[1\] = \[4\] must list 2 values"):
        expand_skill({**skill, "vary": [{"keys": ["a", "b"], "values": [[1, 2], [4]]}]}, {}, "s")
    with pytest.raises(PresetError, match=r"s.vary\[0\] needs 'key'"):
        expand_skill({**skill, "vary": [{"key": "a", "keys": ["b"], "values": [1]}]}, {}, "s")
    with pytest.raises(PresetError, match=r"s.enumerate.start = -1 must be an integer >= 0"):
        expand_skill({**skill, "enumerate": {"key": "params.seed", "start": -1}}, {}, "s")


def test_tiny_diverse_dataset(tmp_path: Path) -> None:
    out = generate(compose_config("tiny_diverse", [RESEARCH_PRESETS, f"out={tmp_path / 'td.h5'}", "workers=1",
                                                   "progress=false"]))
    skills = {split: {m["skill"] for m in load_dataset(out, split=split).meta} for split in ("train", "valid", "test")}
    assert skills == {"train": {"spiral", "curve"}, "valid": {"spiral", "curve"}, "test": {"wavelike", "line"}}
    test = load_dataset(out, split="test")
    assert len(test) == 6 and test.horizon == 40
    curve = next(m for m in load_dataset(out, split="train").meta if m["skill"] == "curve")["demo"]
    assert curve["family"] == "curve" and curve["params"]["press_range_m"] == [0.005, 0.02]


def test_an_out_that_cannot_be_written_is_refused_before_generating(tmp_path: Path) -> None:
    (tmp_path / "a_file").write_text("")
    out = tmp_path / "a_file" / "x.h5"
    with pytest.raises(GenerationError, match=rf"^out={re.escape(str(out))} cannot be written: "
                                              rf"{re.escape(str(tmp_path / 'a_file'))} is not a writable directory"):
        generate(compose_config("tiny", [f"out={out}", "workers=1", "progress=false"]))
