"""A fixed "stiff touch-down, soft wipe" rule, no model, against a finished tuning study of the same skill.

    python -m studies.tuning_study.fixed_rule <study folder> --out <folder> [--grid 6]
        [--touchdown-Npm 600,675,750,825,900] [--wipe-Npm 100] [k=v ...]

``k=v`` are the study's own settings (``studies/conf/study.yaml``, e.g. ``demo=line demo.duration_s=12.0
+demo.lead=true``), so the skill is recorded as the study recorded it.

Why: the multi-seed study's model-free control is five *constant* stiffnesses. On the skills tried, a
schedule that is stiff while the tool lands and soft while it wipes sits on the front, so a model-free rule of
that shape is the stronger control a learned tuner has to beat. The rule is five isotropic schedules (the
study's robot budget per robot-free tuner): phase 1 at ``--touchdown-Npm`` and every later phase at
``--wipe-Npm``, each one level or five (one per schedule); by default phase 1 at 600-900 N/m and the wipe at the
search space's minimum. Each is rolled out once in the study's simulator. Its I_H
is seed-independent in a noise-free domain, so it is compared with every tuner's per-seed I_H of the study
(``study.json``) as the prior is: a two-sided Wilcoxon signed-rank test of the paired differences.

Before anything is compared, the study's reference point and its prior are rolled out again and must match
``reference_point.json`` and ``study.json``: a skill recorded otherwise would make the comparison void.
``--grid L`` also rolls out every isotropic schedule of ``L`` levels per phase (``L**P`` rollouts, evenly
spaced over the search space) and lists its Pareto front, the evidence for the rule's shape on that skill.

Writes ``<out>/rule.json`` and ``<out>/rule.md``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from studies.tuning_study.study_controls import (
    SkillSetup,
    demo_reference_point,
    prior_levels,
    setup_skill,
    write_json,
)

TOUCHDOWN_NPM = (600.0, 675.0, 750.0, 825.0, 900.0)  # phase 1 of the rule's five schedules
MATCH_RTOL = 1e-6  # a re-rolled reference point or prior I_H must match the study's to this relative tolerance


def hv(points: np.ndarray, reference: np.ndarray) -> float:
    """I_H of the finite rows of (n, 2) (L_task, L_comp) against ``reference``."""
    from dcm.tuning.pareto import hypervolume

    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return hypervolume(points[np.isfinite(points).all(axis=1)], reference)


def rule_schedules(touchdown_Npm: list[float], wipe_Npm: list[float], n_phases: int) -> np.ndarray:
    """(n, P, 3) isotropic schedules: phase 1 at the touch-down level, the later phases at the wipe level, the
    two lists paired one level per schedule (a single level serves every schedule)."""
    touchdown, wipe = np.broadcast_arrays(np.asarray(touchdown_Npm, dtype=np.float64),
                                          np.asarray(wipe_Npm, dtype=np.float64))
    schedules = np.repeat(wipe[:, None, None], n_phases, axis=1).repeat(3, axis=2)
    schedules[:, 0, :] = touchdown[:, None]
    return schedules


def grid_schedules(min_Npm: float, max_Npm: float, n_levels: int, n_phases: int) -> np.ndarray:
    """(n_levels ** P, P, 3) isotropic schedules: every combination of ``n_levels`` even levels per phase."""
    levels = np.linspace(min_Npm, max_Npm, n_levels)
    combos = np.asarray(list(itertools.product(levels, repeat=n_phases)), dtype=np.float64)
    return np.repeat(combos[:, :, None], 3, axis=2)


def front_rows(schedules: np.ndarray, objectives: np.ndarray) -> list[dict[str, Any]]:
    """The non-dominated (L_task, L_comp) rows with their per-phase stiffness, by rising L_comp."""
    from dcm.tuning.pareto import pareto_mask

    finite = np.isfinite(objectives).all(axis=1)
    index = np.flatnonzero(finite)[pareto_mask(objectives[finite])]
    index = index[np.argsort(objectives[index, 1])]
    return [{"phase_Npm": schedules[i, :, 0].tolist(), "L_task_N": float(objectives[i, 0]),
             "L_comp_kNpm": float(objectives[i, 1])} for i in index]


def check_same_skill(setup: SkillSetup, study: dict[str, Any], cfg: Any, reference: np.ndarray) -> dict[str, float]:
    """Re-roll the study's reference point and prior; raise unless both match the study's."""
    info = study["reference_point"]
    again = demo_reference_point(setup, float(info["task_factor"]), float(info["comp_factor"]),
                                 int(cfg.validation_rollouts))
    redone = np.array([again["L_task_N"], again["L_comp_kNpm"]])
    if not np.allclose(redone, reference, rtol=MATCH_RTOL, atol=0.0):
        raise ValueError(f"the skill is not the study's: its reference point is {redone.tolist()}, the study's "
                         f"{reference.tolist()}; pass the study's settings (e.g. demo=line demo.duration_s=12.0 "
                         "+demo.lead=true)")
    levels = prior_levels(setup.space.min_Npm, setup.space.max_Npm, int(cfg.prior.n_levels))
    constant = np.broadcast_to(levels[:, None, None], (len(levels), setup.space.n_phases, 3))
    prior = hv(setup.evaluate(np.array(constant), int(cfg.validation_rollouts)), reference)
    study_prior = float(np.median(study["hypervolume"]["prior"]))
    if not np.isclose(prior, study_prior, rtol=MATCH_RTOL, atol=0.0):
        raise ValueError(f"the prior's I_H is {prior:.6g} here and {study_prior:.6g} in the study: the skill or the "
                         "simulator differs from the study's")
    return {"prior": prior, "study_prior": study_prior}


def compare(study: dict[str, Any], rule_ih: float, alpha: float) -> dict[str, Any]:
    """The rule's constant I_H against every tuner's per-seed I_H of ``study``, paired by seed."""
    from studies.tuning_study.study_stats import aggregate

    values = {"rule": [rule_ih] * len(study["seeds"]), **study["hypervolume"]}
    return aggregate(values, subject="rule", alpha=alpha)


def report_md(result: dict[str, Any]) -> str:
    from studies.tuning_study.study_report import label

    stats, ref = result["statistics"], result["reference_point"]
    lines = [
        f"A fixed rule against the {len(result['seeds'])} seeds of `{result['study']}`, on its reference point "
        f"(L_task {ref['L_task_N']:.4g} N, L_comp {ref['L_comp_kNpm']:.4g} kN/m). Command: `{result['command']}`.",
        "",
        f"The rule: five isotropic schedules, phase 1 at {', '.join(f'{k:g}' for k in result['touchdown_Npm'])} "
        f"N/m and phases 2-{result['n_phases']} at {', '.join(f'{k:g}' for k in result['wipe_Npm'])} N/m, one "
        "rollout each. "
        f"I_H {result['rule_ih']:.4f}; each schedule alone: "
        f"{', '.join(f'{v:.4f}' for v in result['single_schedule_ih'])}. "
        f"The prior re-rolled here: {result['check']['prior']:.4f} (the study's {result['check']['study_prior']:.4f}).",
        "",
        "| tuner | robot trials | median I_H | rule − tuner, median | rule better / worse / tied | p |",
        "|---|---|---|---|---|---|",
        f"| fixed rule | 5 | {result['rule_ih']:.4f} |  |  |  |",
    ]
    for name, test in stats["tests"].items():
        p = "—" if test["p"] is None else f"{test['p']:.3g}" + (" (significant)" if test["significant"] else "")
        lines.append(f"| {label(name)} | {result['robot_trials'].get(name, '—')} | "
                     f"{stats['tuners'][name]['median']:.4f} | {test['median_difference']:+.4f} | "
                     f"{test['wins']} / {test['losses']} / {test['ties']} | {p} |")
    lines.append("")
    lines.append("Rule's rollouts:")
    lines.append("")
    lines.append("| phase stiffness [N/m] | L_task [N] | L_comp [kN/m] |")
    lines.append("|---|---|---|")
    for row in result["rule_rollouts"]:
        lines.append(f"| {' / '.join(f'{k:g}' for k in row['phase_Npm'])} | {row['L_task_N']:.4f} | "
                     f"{row['L_comp_kNpm']:.4f} |")
    grid = result.get("grid")
    if grid:
        lines += ["", f"Grid: {grid['n_schedules']} isotropic schedules ({grid['n_levels']} levels per phase, "
                      f"{', '.join(f'{k:g}' for k in grid['levels_Npm'])} N/m), one rollout each; its front's I_H "
                      f"{grid['front_ih']:.4f} ({len(grid['front'])} schedules, {grid['n_schedules']} robot trials):",
                  "", "| phase stiffness [N/m] | L_task [N] | L_comp [kN/m] |", "|---|---|---|"]
        for row in grid["front"]:
            lines.append(f"| {' / '.join(f'{k:g}' for k in row['phase_Npm'])} | {row['L_task_N']:.4f} | "
                         f"{row['L_comp_kNpm']:.4f} |")
    return "\n".join(lines) + "\n"


def run(study_dir: Path, out_dir: Path, overrides: list[str], touchdown_Npm: list[float],
        wipe_Npm: list[float] | None, grid_levels: int | None, command: str) -> dict[str, Any]:
    from studies.tuning_study.study_config import Tuner, compose_study, tune_config

    study_path = study_dir / "study.json"
    if not study_path.is_file():
        raise ValueError(f"{study_dir}: no study.json (a finished study's folder or report)")
    study = json.loads(study_path.read_text())
    for key, levels in (("--touchdown-Npm", touchdown_Npm), ("--wipe-Npm", wipe_Npm or [0.0])):
        if len(levels) not in (1, 5):
            raise ValueError(f"{key} has {len(levels)} levels; give one, or five (the rule's five schedules, the "
                             "study's robot budget per robot-free tuner)")
    if len(touchdown_Npm) == 1 and (wipe_Npm is None or len(wipe_Npm) == 1):
        raise ValueError("the rule's five schedules need five levels in --touchdown-Npm or in --wipe-Npm")
    if not any(o.split("=", 1)[0].lstrip("+") == "ckpt" for o in overrides):
        overrides = ["ckpt=models/dcm_diverse_contact.ckpt", *overrides]  # the skill's setup needs a predictor
    cfg = compose_study(overrides)
    reference = np.array([study["reference_point"]["L_task_N"], study["reference_point"]["L_comp_kNpm"]])
    setup = setup_skill(tune_config(cfg, Tuner("dcm", str(cfg.ckpt)), int(study["reference_point"].get("seed", 0)),
                                    None, out_dir))
    space = setup.space
    wipe = [float(space.min_Npm)] if wipe_Npm is None else [float(k) for k in wipe_Npm]
    for level in [*touchdown_Npm, *wipe]:
        if not space.min_Npm <= level <= space.max_Npm:
            raise ValueError(f"rule stiffness {level:g} N/m is outside the search space "
                             f"[{space.min_Npm:g}, {space.max_Npm:g}] N/m")
    check = check_same_skill(setup, study, cfg, reference)

    schedules = rule_schedules(touchdown_Npm, wipe, space.n_phases)
    objectives = setup.evaluate(schedules, int(cfg.validation_rollouts))
    rule_ih = hv(objectives, reference)
    result: dict[str, Any] = {
        "study": str(study_dir), "command": command, "seeds": study["seeds"], "n_phases": int(space.n_phases),
        "reference_point": study["reference_point"], "touchdown_Npm": list(touchdown_Npm), "wipe_Npm": wipe,
        "rule_ih": rule_ih, "single_schedule_ih": [hv(o[None], reference) for o in objectives],
        "rule_rollouts": [{"phase_Npm": s[:, 0].tolist(), "L_task_N": float(o[0]), "L_comp_kNpm": float(o[1])}
                          for s, o in zip(schedules, objectives)],
        "check": check, "robot_trials": study.get("robot_trials", {}),
        "statistics": compare(study, rule_ih, float(cfg.alpha)),
    }
    if grid_levels:
        grid = grid_schedules(space.min_Npm, space.max_Npm, grid_levels, space.n_phases)
        grid_objectives = setup.evaluate(grid, int(cfg.validation_rollouts))
        result["grid"] = {"n_levels": grid_levels, "levels_Npm": np.linspace(space.min_Npm, space.max_Npm,
                                                                             grid_levels).tolist(),
                          "n_schedules": len(grid), "front_ih": hv(grid_objectives, reference),
                          "front": front_rows(grid, grid_objectives)}
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(out_dir / "rule.json", result)
    (out_dir / "rule.md").write_text(report_md(result))
    return result


def levels_arg(text: str) -> list[float]:
    """``600,700`` -> [600.0, 700.0] (comma-separated, so the study's k=v settings can follow)."""
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of stiffness levels [N/m]") from None


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("study", type=Path, help="a finished tuning study's folder or report (its study.json)")
    parser.add_argument("--out", type=Path, required=True, help="folder for rule.json and rule.md")
    parser.add_argument("--touchdown-Npm", type=levels_arg, default=list(TOUCHDOWN_NPM),
                        help="phase 1 of the rule's five schedules [N/m]: one level, or five, comma-separated")
    parser.add_argument("--wipe-Npm", type=levels_arg, default=None,
                        help="every later phase [N/m]: one level, or five, comma-separated (default: the search "
                             "space's minimum)")
    parser.add_argument("--grid", type=int, default=None, help="also roll out L levels per phase (L**P schedules)")
    parser.add_argument("overrides", nargs="*", help="the study's settings, k=v (studies/conf/study.yaml)")
    args = parser.parse_intermixed_args(argv)
    if args.grid is not None and args.grid < 2:
        raise SystemExit(f"error: --grid {args.grid} must be at least 2 levels per phase")
    command = "python -m studies.tuning_study.fixed_rule " + " ".join(sys.argv[1:] if argv is None else argv)
    try:
        result = run(args.study, args.out, args.overrides, args.touchdown_Npm, args.wipe_Npm, args.grid, command)
    except (ValueError, OSError, RuntimeError) as err:
        raise SystemExit(f"error: {' '.join(str(err).split())}") from None
    print((args.out / "rule.md").read_text())
    print(f"rule: {args.out} (I_H {result['rule_ih']:.4f})")


if __name__ == "__main__":
    main()
