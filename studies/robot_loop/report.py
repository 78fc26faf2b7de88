"""The robot-loop study's report: I_H of every arm per skill (median over tuning seeds), paired comparisons of
the loop at 15 trials against each other arm, and how far each round's prediction was from the robot."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

ORDER = ["loop_gp_5", "loop_gp_10", "loop_gp_15", "loop_none_5", "loop_none_10", "loop_none_15", "one_shot_5",
         "prior_5", "prior_15", "robot_based_20", "robot_based_50"]
TRIALS = {"one_shot_5": 5, "prior_5": 5, "prior_15": 15, "robot_based_20": 20, "robot_based_50": 50}


def load_cases(out: Path) -> list[dict[str, Any]]:
    return [json.loads(p.read_text()) for p in sorted((out / "cases").rglob("seed_*.json"))]


def paired(cases: list[dict[str, Any]], a: str, b: str) -> dict[str, Any]:
    """Paired over (checkpoint, skill, tuning seed): median difference a - b, wins of a, two-sided Wilcoxon p."""
    from scipy.stats import wilcoxon

    diff = np.array([c["arms"][a]["hypervolume"] - c["arms"][b]["hypervolume"] for c in cases])
    nonzero = diff[diff != 0]
    p = float(wilcoxon(nonzero).pvalue) if len(nonzero) >= 2 else float("nan")
    return {"median_diff": float(np.median(diff)), "wins": int((diff > 0).sum()), "ties": int((diff == 0).sum()),
            "n": len(diff), "p": p}


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
    lines += ["", "## Paired over cases (tuning-seed level: one checkpoint, so not a claim about the recipe)", "",
              "| a | b | median I_H(a) - I_H(b) | a better | ties | n | Wilcoxon p (two-sided) |",
              "|---|---|---|---|---|---|---|"]
    for a, others in (("loop_gp_15", [x for x in arms if x != "loop_gp_15"]),
                      ("loop_gp_10", ["one_shot_5", "prior_15", "robot_based_20"]),
                      ("loop_none_15", ["one_shot_5", "prior_15", "robot_based_50"])):
        if a not in arms:
            continue
        for b in others:
            if b in arms and b != a:
                r = paired(cases, a, b)
                lines.append(f"| {a} | {b} | {r['median_diff']:+.4f} | {r['wins']} | {r['ties']} | {r['n']} | "
                             f"{r['p']:.3g} |")
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


def write_report(out: Path, path: Path) -> None:
    cases = load_cases(out)
    if not cases:
        raise SystemExit(f"error: no finished cases under {out}/cases")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(report(cases))
    print(f"report: {path} ({len(cases)} cases)")
