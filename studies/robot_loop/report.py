"""The robot-loop study's report: I_H of every arm per skill (median over tuning seeds), paired comparisons of
the loop at 15 trials against each other arm, and how far each round's prediction was from the robot.

With several trained checkpoints the comparisons are also made at the level of the trained model, the unit of
replication: one mean difference per checkpoint over its cases, tested over checkpoints."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from studies.tuning_study.study_stats import signed_rank_test

ORDER = ["loop_gp_5", "loop_gp_10", "loop_gp_15", "loop_none_5", "loop_none_10", "loop_none_15", "one_shot_5",
         "prior_5", "prior_15", "robot_based_20", "robot_based_50"]
TRIALS = {"one_shot_5": 5, "prior_5": 5, "prior_15": 15, "robot_based_20": 20, "robot_based_50": 50}


def load_cases(out: Path) -> list[dict[str, Any]]:
    return [json.loads(p.read_text()) for p in sorted((out / "cases").rglob("seed_*.json"))]


def difference(case: dict[str, Any], a: str, b: str) -> float:
    return case["arms"][a]["hypervolume"] - case["arms"][b]["hypervolume"]


def per_model(cases: list[dict[str, Any]], a: str, b: str) -> dict[str, float]:
    """The mean difference a - b over each checkpoint's cases (its skills and tuning seeds)."""
    grouped: dict[str, list[float]] = {}
    for case in cases:
        grouped.setdefault(Path(case["ckpt"]).name, []).append(difference(case, a, b))
    return {name: float(np.mean(values)) for name, values in sorted(grouped.items())}


def paired(cases: list[dict[str, Any]], a: str, b: str, by_model: bool = False) -> dict[str, Any]:
    """Median difference a - b, wins of a, two-sided Wilcoxon p: over (checkpoint, skill, tuning seed) cases, or
    with ``by_model`` over the checkpoints' mean differences."""
    diff = list(per_model(cases, a, b).values()) if by_model else [difference(c, a, b) for c in cases]
    return signed_rank_test(diff)


def report(cases: list[dict[str, Any]]) -> str:
    demos = sorted({c["demo"] for c in cases})
    ckpts = sorted({Path(c["ckpt"]).name for c in cases})
    arms = [a for a in ORDER if all(a in c["arms"] for c in cases)]
    lines = [f"Cases: {len(cases)} = {len(ckpts)} checkpoint(s) ({', '.join(ckpts)}) x skills x tuning seeds; "
             f"every pick judged over {cases[0]['judge_rollouts']} fresh rollouts, up to {cases[0]['picks']} picks "
             "per arm.", "",
             "## I_H per skill (median over tuning seeds; min..max)", "",
             "| arm | robot trials | " + " | ".join(demos) + " | all cases |",
             "|---|---|" + "---|" * (len(demos) + 1)]
    for arm in arms:
        trials = TRIALS.get(arm, int(arm.rsplit("_", 1)[-1]) if arm.startswith("loop") else 0)
        cells = []
        for demo in demos + [None]:
            values = [c["arms"][arm]["hypervolume"] for c in cases if demo is None or c["demo"] == demo]
            cells.append(f"{np.median(values):.4f} ({min(values):.3f}..{max(values):.3f})")
        lines.append(f"| {arm} | {trials} | " + " | ".join(cells) + " |")
    pairs = [(a, b) for a, others in (("loop_gp_15", [x for x in arms if x != "loop_gp_15"]),
                                      ("loop_gp_10", ["one_shot_5", "prior_15", "robot_based_20"]),
                                      ("loop_none_15", ["one_shot_5", "prior_15", "robot_based_50"]))
             if a in arms for b in others if b in arms and b != a]
    header = ["| a | b | median I_H(a) - I_H(b) | a better | ties | n | Wilcoxon p (two-sided) |",
              "|---|---|---|---|---|---|---|"]
    if len(ckpts) > 1:
        lines += ["", "## Paired over trained models (the unit of replication: each checkpoint's mean difference "
                  "over its cases)", "", *header]
        lines += [paired_row(cases, a, b, by_model=True) for a, b in pairs]
        lines += ["", "Each checkpoint's mean I_H(loop_gp_15) - I_H(b) over its cases:", "",
                  "| checkpoint | " + " | ".join(b for a, b in pairs if a == "loop_gp_15") + " |",
                  "|---|" + "---|" * sum(a == "loop_gp_15" for a, _ in pairs)]
        means = {b: per_model(cases, "loop_gp_15", b) for a, b in pairs if a == "loop_gp_15"}
        for name in ckpts:
            lines.append(f"| {name} | " + " | ".join(f"{m[name]:+.4f}" for m in means.values()) + " |")
    level = "one checkpoint, so not a claim about the recipe" if len(ckpts) == 1 else \
        "the cases of one checkpoint are not independent replicates"
    lines += ["", f"## Paired over cases (tuning-seed level: {level})", "", *header]
    lines += [paired_row(cases, a, b) for a, b in pairs]
    lines += ["", "## Prediction error per round (mean |predicted - observed| L_task [N], median over cases)", "",
              "| correction | round 1 | round 2 | round 3 |", "|---|---|---|---|"]
    for correction in ("gp", "none"):
        key = f"loop_{correction}_15"
        if key not in arms:
            continue
        per_round = np.array([[np.nan if v is None else v for v in c["arms"][key]["prediction_mae_N"]] for c in cases])
        lines.append(f"| {correction} | " + " | ".join(f"{np.nanmedian(col):.3f}" for col in per_round.T) + " |")
    seconds = [c["seconds"] for c in cases]
    lines += ["", f"Wall time per case: median {np.median(seconds):.0f} s (min {min(seconds):.0f}, "
              f"max {max(seconds):.0f})."]
    return "\n".join(lines) + "\n"


def paired_row(cases: list[dict[str, Any]], a: str, b: str, by_model: bool = False) -> str:
    r = paired(cases, a, b, by_model)
    p = "n/a" if r["p"] is None else f"{r['p']:.3g}"
    return f"| {a} | {b} | {r['median_difference']:+.4f} | {r['wins']} | {r['ties']} | {r['n_pairs']} | {p} |"


def write_report(out: Path, path: Path) -> None:
    cases = load_cases(out)
    if not cases:
        raise SystemExit(f"error: no finished cases under {out}/cases")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(report(cases))
    print(f"report: {path} ({len(cases)} cases)")
