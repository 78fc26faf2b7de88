"""Certify the benchmark task before any model sees it: T1-T4 from an oracle grid judged over many rollouts.

    python -m studies.benchmark.certify --split train --out outputs/benchmark/train
    python -m studies.benchmark.certify --split valid --out outputs/benchmark/valid \\
        --rule-from outputs/benchmark/train --report studies/benchmark/reports/certification.md

Every skill of the split gets every oracle schedule (``task.oracle_schedules``) rolled out ``task.ROLLOUTS``
times; each schedule is judged by its mean L_task. Then, per skill, the best schedule and the best constant
schedule within its L_comp are re-run on fresh rollouts, so the T2 gain is not the winner's luck. The fixed
rule of T3 is fitted on the train split's oracle only (``--rule-from``). Skills run in up to two worker
processes; a finished skill is kept, so a killed run resumes. ``--revision`` picks a task revision
(``task.REVISIONS``); the default is the task PROTOCOL.md describes.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from multiprocessing import Pool
from pathlib import Path
from typing import Any

import numpy as np

from studies.benchmark import stats
from studies.benchmark import task as bench
from studies.benchmark.oracle import run_skill, task_losses

TASK_FACTOR = 1.5  # the reference point's L_task: this x the demo stiffness's expected L_task (as the tuning study)


def _run(args: tuple[int, str]) -> str:
    seed, out = args
    return str(run_skill(seed, Path(out), revision=REVISION))


def _run_fresh(args: tuple[int, str, list[list[float]]]) -> str:
    seed, out, schedules = args
    return str(run_skill(seed, Path(out), schedules=np.asarray(schedules), first_repeat=bench.ROLLOUTS, tag="fresh",
                         revision=REVISION))


def run_oracle(seeds: list[int], out: Path, workers: int) -> None:
    """Run (or resume) the oracle on ``seeds``, skills spread over ``workers`` processes."""
    start = time.time()
    jobs = [(s, str(out)) for s in seeds]
    if workers <= 1:
        results = map(_run, jobs)
        _report_progress(results, len(jobs), start)
        return
    with Pool(workers) as pool:
        _report_progress(pool.imap_unordered(_run, jobs), len(jobs), start)


def _report_progress(results: Any, total: int, start: float) -> None:
    for done, path in enumerate(results, start=1):
        elapsed = time.time() - start
        print(f"skill {done}/{total} done ({Path(path).name}); {elapsed / 60:.1f} min, "
              f"ETA {elapsed / done * (total - done) / 60:.1f} min", file=sys.stderr, flush=True)


def load_skill(out: Path, seed: int, from_contact: bool) -> dict[str, Any]:
    data = np.load(Path(out) / "skills" / f"paced_{seed}.npz")
    losses = task_losses(data, from_contact)
    kinds = [str(k) for k in data["kinds"]]
    phase = data["phase_Npm"]
    constant = np.all(phase == phase[:, :1], axis=1)
    task = losses.mean(axis=1)  # inf if any rollout failed
    demo_row = int(np.flatnonzero(np.all(phase == bench.DEMO_STIFFNESS_NPM, axis=1))[0])
    stiffest = float(data["L_comp"].max())
    reference = np.array([TASK_FACTOR * task[demo_row], stiffest])
    spec = json.loads(str(data["spec"]))
    return {"seed": seed, "task": task, "comp": data["L_comp"], "constant": constant, "kinds": kinds,
            "phase": phase, "reference": reference, "losses": losses, "spec": spec,
            "approach_share": stats.approach_share(data["sq_approach"], data["sq_total"]),
            "failed": int(data["failed"].sum()), "rollouts": int(data["failed"].size)}


def _label(row: np.ndarray) -> str:
    return "/".join(f"{v:g}" for v in row)


def _speeds(spec: dict[str, Any]) -> list[float]:
    from dcm.sim import DemoSpec

    draws = DemoSpec.from_dict(spec).curve_draws()
    return [round(float(v), 3) for v in draws["speed_mps"]] + [round(float(draws["press_m"]) * 1000, 1)]


def certify(skills: list[dict[str, Any]], rule: list[int] | None, fresh: dict[int, np.ndarray] | None,
            ) -> dict[str, Any]:
    """T1-T4 over ``skills`` (``load_skill`` dicts); ``rule`` indexes the fixed rule's schedules."""
    rows = []
    prior = np.flatnonzero([bool(c) and (k in ("grid", "prior")) and float(p[0]) in bench.PRIOR_LEVELS_NPM
                            for c, k, p in zip(skills[0]["constant"], skills[0]["kinds"], skills[0]["phase"])])
    for sk in skills:
        t2 = stats.variable_gain(sk["task"], sk["comp"], sk["constant"])
        ih_all = stats.front_hypervolume(sk["task"], sk["comp"], sk["reference"])
        ih_prior = stats.front_hypervolume(sk["task"], sk["comp"], sk["reference"], prior)
        ih_rule = stats.front_hypervolume(sk["task"], sk["comp"], sk["reference"], rule) if rule else float("nan")
        row = {"seed": sk["seed"], "speeds_press": _speeds(sk["spec"]), "approach_share": sk["approach_share"],
               "best": _label(sk["phase"][t2["best"]]), "best_task": t2["best_task"],
               "constant_task": t2["constant_task"], "gain": t2["gain"], "max_gain": t2["max_gain"],
               "ih_oracle": ih_all, "ih_prior": ih_prior, "ih_rule": ih_rule,
               "over_prior": ih_all / ih_prior - 1 if ih_prior > 0 else float("inf"),
               "over_rule": ih_all / ih_rule - 1 if ih_rule and ih_rule > 0 else float("nan"),
               "failed": f"{sk['failed']}/{sk['rollouts']}", "reference": sk["reference"].tolist()}
        if fresh is not None and sk["seed"] in fresh:
            pair = fresh[sk["seed"]]  # (2,) fresh mean L_task of [best, best constant]
            row["fresh_gain"] = 0.0 if sk["constant"][t2["best"]] else float(1 - pair[0] / pair[1])
        rows.append(row)
    t4 = stats.single_schedule_regret(np.stack([sk["task"] for sk in skills]), skills[0]["comp"])
    for row, regret in zip(rows, t4["regrets"]):
        row["single_regret"] = regret
    return {"rows": rows, "single": _label(skills[0]["phase"][t4["single"]]), "t4_median": t4["median"],
            "prior": [_label(skills[0]["phase"][i]) for i in prior],
            "rule": [_label(skills[0]["phase"][i]) for i in rule] if rule else [],
            "t1_median": float(np.median([r["approach_share"] for r in rows])),
            "t2_count": int(sum(r.get("fresh_gain", r["gain"]) >= 0.15 for r in rows)),
            "t2_count_oracle": int(sum(r["gain"] >= 0.15 for r in rows)),
            "t3_prior_median": float(np.median([r["over_prior"] for r in rows])),
            "t3_rule_median": float(np.median([r["over_rule"] for r in rows])) if rule else float("nan")}


def fresh_pairs(skills: list[dict[str, Any]], out: Path, workers: int) -> dict[int, np.ndarray]:
    """Re-run, on fresh rollouts, each skill's best schedule and its best constant within its L_comp."""
    jobs = []
    for sk in skills:
        t2 = stats.variable_gain(sk["task"], sk["comp"], sk["constant"])
        best = t2["best"]
        pick = sk["constant"] & (sk["comp"] <= sk["comp"][best] + stats.COMP_TOL)
        if not pick.any():
            pick = sk["constant"] & (sk["comp"] == sk["comp"][sk["constant"]].min())
        const = int(np.flatnonzero(pick)[np.argmin(sk["task"][pick])])
        jobs.append((sk["seed"], str(out), [sk["phase"][best].tolist(), sk["phase"][const].tolist()]))
    if workers <= 1:
        paths = list(map(_run_fresh, jobs))
    else:
        with Pool(workers) as pool:
            paths = pool.map(_run_fresh, jobs)
    result = {}
    for (seed, _, _), path in zip(jobs, paths):
        data = np.load(path)
        horizon, approach = int(data["horizon"]), int(data["approach_steps"])
        result[seed] = task_losses(data, FROM_CONTACT).mean(axis=1)
        del horizon, approach
    return result


def render(result: dict[str, Any]) -> str:
    """The per-skill table and the T1-T4 summary of a ``certify`` result, as markdown."""
    head = ("| skill seed | speeds per third [m/s], press [mm] | approach share | best schedule [N/m] | its L_task [N] "
            "| best constant within its L_comp [N] | T2 gain (oracle) | T2 gain (fresh rollouts) | I_H oracle "
            "| I_H prior | I_H rule | oracle over prior | oracle over rule | T4 regret of the single schedule "
            "| failed rollouts |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in result["rows"]:
        lines.append(
            f"| {r['seed']} | {', '.join(f'{v:g}' for v in r['speeds_press'][:-1])}; {r['speeds_press'][-1]:g} "
            f"| {r['approach_share']:.3f} | {r['best']} | {r['best_task']:.3f} | {r['constant_task']:.3f} "
            f"| {r['gain']:+.3f} | {r.get('fresh_gain', float('nan')):+.3f} | {r['ih_oracle']:.4f} "
            f"| {r['ih_prior']:.4f} | {r['ih_rule']:.4f} | {r['over_prior']:+.3f} | {r['over_rule']:+.3f} "
            f"| {r['single_regret']:+.3f} | {r['failed']} |")
    lines += ["", f"- prior (five constants): {', '.join(result['prior'])}",
              f"- fixed rule (fitted on the train skills): {', '.join(result['rule']) or 'none'}",
              f"- best single schedule over these skills: {result['single']}",
              f"- T1 median approach share: {result['t1_median']:.3f}",
              f"- T2 skills with gain >= 15 %: {result['t2_count']} of {len(result['rows'])} on fresh rollouts "
              f"({result['t2_count_oracle']} on the oracle's own rollouts)",
              f"- T3 median oracle I_H over the prior's: {result['t3_prior_median']:+.3f}; over the rule's: "
              f"{result['t3_rule_median']:+.3f}",
              f"- T4 median regret of the single schedule: {result['t4_median']:+.3f}"]
    return "\n".join(lines) + "\n"


FROM_CONTACT = False  # set by --from-contact; module level so worker processes need not know it
REVISION = bench.REVISION  # set by --revision, the same way


def main(argv: list[str] | None = None) -> int:
    global FROM_CONTACT, REVISION
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--split", choices=("train", "valid"), required=True)
    parser.add_argument("--out", type=Path, required=True, help="where the oracle's per-skill results go")
    parser.add_argument("--rule-from", type=Path, help="a finished train oracle: fit the fixed rule there")
    parser.add_argument("--workers", type=int, default=2, help="worker processes (1 or 2 on a shared machine)")
    parser.add_argument("--from-contact", action="store_true", help="L_task from the end of the approach on")
    parser.add_argument("--revision", choices=sorted(bench.REVISIONS), default=bench.REVISION,
                        help="the task revision to certify (studies/benchmark/task.py REVISIONS)")
    parser.add_argument("--report", type=Path, help="write <report>.json and <report>_tables.md next to this path")
    args = parser.parse_args(argv)
    if args.workers not in (1, 2):
        parser.error(f"--workers = {args.workers}: use 1 or 2 on this shared machine")
    FROM_CONTACT = args.from_contact
    REVISION = args.revision
    seeds = list(bench.TRAIN_SEEDS if args.split == "train" else bench.VALID_SEEDS)
    run_oracle(seeds, args.out, args.workers)
    skills = [load_skill(args.out, s, args.from_contact) for s in seeds]
    rule = None
    if args.rule_from is not None:
        train = [load_skill(args.rule_from, s, args.from_contact) for s in bench.TRAIN_SEEDS]
        rule = stats.greedy_rule([t["task"] for t in train], [t["comp"] for t in train],
                                 [t["reference"] for t in train], bench.RULE_SIZE)
    fresh = fresh_pairs(skills, args.out, args.workers)
    result = certify(skills, rule, fresh)
    result["from_contact"] = args.from_contact
    result["split"] = args.split
    result["revision"] = args.revision
    text = json.dumps(result, indent=1, default=float)
    print(text)
    if args.report:
        args.report.parent.mkdir(parents=True, exist_ok=True)
        args.report.with_suffix(".json").write_text(text + "\n")
        args.report.with_name(args.report.stem + "_tables.md").write_text(render(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
