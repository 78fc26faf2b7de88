"""Pooling tuning studies over training seeds (studies.tuning_study.study_pool), on hand-made study.json files."""

from __future__ import annotations

import json

import pytest

from studies.tuning_study.study_pool import main, pool

REFERENCE = {"L_task_N": 0.44, "L_comp_kNpm": 2.6}


def _study(seeds, dcm, baseline, extra=None, reference=REFERENCE):
    hv = {"dcm": dcm, "baseline": baseline, **(extra or {})}
    return {"seeds": seeds, "tuners": list(hv), "hypervolume": hv, "reference_point": dict(reference)}


def test_pool_keeps_shared_seeds_and_tuners_and_counts_studies_ahead():
    first = _study([0, 1, 2, 3], [0.5, 0.6, 0.7, 0.9], [0.4, 0.5, 0.6, 0.1], {"prior": [0.3] * 4})
    second = _study([0, 1, 2], [0.2, 0.3, 0.4], [0.3, 0.4, 0.5])
    report = pool({"s0": first, "s1": second})
    assert report["seeds"] == [0, 1, 2]                      # seed 3 is only in the first study
    assert report["tuners"] == ["dcm", "baseline"]           # the prior is only in the first study
    assert report["per_study"]["s0"]["tuners"]["dcm"]["median"] == pytest.approx(0.6)
    assert report["per_study"]["s0"]["tests"]["baseline"]["wins"] == 3
    assert report["per_study"]["s1"]["tests"]["baseline"]["losses"] == 3
    pooled = report["pooled"]
    assert pooled["tests"]["baseline"]["n_pairs"] == 6
    assert (pooled["tests"]["baseline"]["wins"], pooled["tests"]["baseline"]["losses"]) == (3, 3)
    assert pooled["studies_ahead"]["baseline"] == 1
    assert pooled["tuners"]["dcm"]["median"] == pytest.approx(0.45)


def test_pool_refuses_another_skill_and_a_missing_subject():
    first = _study([0, 1], [0.5, 0.6], [0.4, 0.5])
    other = _study([0, 1], [0.5, 0.6], [0.4, 0.5], reference={"L_task_N": 0.3, "L_comp_kNpm": 2.6})
    with pytest.raises(ValueError, match="other: reference point L_task_N"):
        pool({"first": first, "other": other})
    with pytest.raises(ValueError, match="subject tuner 'ridge'"):
        pool({"first": first}, subject="ridge")
    with pytest.raises(ValueError, match="share no tuning seed"):
        pool({"first": first, "late": _study([5, 6], [0.5, 0.6], [0.4, 0.5])})


def test_cli_writes_the_table_and_names_a_folder_without_a_study(tmp_path, capsys):
    for name, dcm in (("a", [0.5, 0.6, 0.7]), ("b", [0.6, 0.7, 0.8])):
        (tmp_path / name).mkdir()
        (tmp_path / name / "study.json").write_text(json.dumps(_study([0, 1, 2], dcm, [0.4, 0.5, 0.6])))
    out = tmp_path / "pool.md"
    main([f"seed0={tmp_path / 'a'}", f"seed1={tmp_path / 'b'}", "--out", str(out)])
    table = out.read_text()
    assert "| seed0 | 0.600 | 0.500 (3 / 0" in table
    assert "| DCM median above, studies | – | 2 of 2 |" in table
    assert json.loads(out.with_suffix(".json").read_text())["pooled"]["tests"]["baseline"]["n_pairs"] == 6
    with pytest.raises(SystemExit, match="missing/study.json: no study.json"):
        main([f"x={tmp_path / 'missing'}"])


def test_versus_pairs_the_subject_with_the_same_tuners_of_another_design(tmp_path, capsys):
    prior = {"prior": [0.3, 0.3, 0.3]}  # a control that repeats in both designs joins once
    blended = {"s0": _study([0, 1, 2], [0.5, 0.6, 0.7], [0.4, 0.5, 0.6], prior),
               "s1": _study([0, 1, 2], [0.6, 0.7, 0.8], [0.5, 0.6, 0.7], prior)}
    plain = {"s0": _study([0, 1, 2, 3], [0.4, 0.5, 0.6, 0.9], [0.3, 0.4, 0.5, 0.9], {"prior": [0.3] * 4}),
             "s1": _study([0, 1, 2], [0.7, 0.8, 0.9], [0.2, 0.3, 0.4], prior)}
    report = pool(blended, versus=plain, versus_name="no prior")
    assert report["tuners"] == ["dcm", "baseline", "prior", "dcm (no prior)", "baseline (no prior)"]
    test = report["pooled"]["tests"]["dcm (no prior)"]
    assert test["n_pairs"] == 6 and (test["wins"], test["losses"]) == (3, 3)  # seed 3 is only in one study
    assert report["per_study"]["s0"]["tests"]["dcm (no prior)"]["wins"] == 3
    baseline_first = pool(blended, subject="baseline", versus=plain, versus_name="no prior")
    assert baseline_first["pooled"]["tests"]["baseline (no prior)"]["wins"] == 6
    with pytest.raises(ValueError, match=r"--versus needs one study per label \['s0', 's1'\], got \['s0'\]"):
        pool(blended, versus={"s0": plain["s0"]})
    other_skill = dict(plain, s1=_study([0, 1], [0.5, 0.6], [0.4, 0.5], reference={"L_task_N": 0.3, "L_comp_kNpm": 2.6}))
    with pytest.raises(ValueError, match=r"s1 \(other design\): reference point L_task_N"):
        pool(blended, versus=other_skill)
    for name, studies in (("blend", blended), ("plain", plain)):
        for label, study in studies.items():
            (tmp_path / name / label).mkdir(parents=True)
            (tmp_path / name / label / "study.json").write_text(json.dumps(study))
    out = tmp_path / "pool.md"
    main([f"s0={tmp_path / 'blend/s0'}", f"s1={tmp_path / 'blend/s1'}", "--versus", f"s0={tmp_path / 'plain/s0'}",
          f"s1={tmp_path / 'plain/s1'}", "--versus-name", "no prior", "--out", str(out)])
    assert "| study | DCM | baseline | prior | DCM (no prior) | baseline (no prior) |" in out.read_text()
    assert json.loads(out.with_suffix(".json").read_text())["versus"]["name"] == "no prior"
    main([f"s0={tmp_path / 'blend/s0'}", f"s1={tmp_path / 'blend/s1'}", "--subject", "baseline", "--out", str(out)])
    assert "| study | baseline | DCM | prior |" in out.read_text()  # the subject's column comes first
    capsys.readouterr()
