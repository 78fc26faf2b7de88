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

A run can choose its design (issue 67): ``--objective`` (paper | wipe, ``task.OBJECTIVES``), ``--schedules`` (a
named set, ``task.SCHEDULE_SETS``, whose frame is world or surface) and ``--domain`` (``task.DOMAINS``, e.g. with
the Panda's joint friction), or all of them and the revision at once with ``--design`` (``task.DESIGNS``). The
defaults are the committed task. A schedule is "constant" when its diagonal (anisotropic ones included) is the
same in every phase. T5 ranks each skill's schedules with a stiffness-only ridge fitted on the train skills
(``--rule-from``), or leave-one-skill-out over the split's own skills without it::

    python -m studies.benchmark.certify --split train --design wipe_surface --out outputs/benchmark/wipe_surface \
        --from-contact --workers 1 --rule-from outputs/benchmark/wipe_surface
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
from studies.benchmark.oracle import run_skill, squared_error_sums, task_losses

TASK_FACTOR = 1.5  # the reference point's L_task: this x the demo stiffness's expected L_task (as the tuning study)


def _run(args: tuple[int, str]) -> str:
    seed, out = args
    if SCHEDULES == "isotropic_grid" and DOMAIN == bench.DOMAIN:  # the committed task, exactly as it ran
        return str(run_skill(seed, Path(out), revision=REVISION))
    sched = bench.schedule_set(SCHEDULES)
    return str(run_skill(seed, Path(out), revision=REVISION, domain=bench.domain(DOMAIN), schedules=sched.phase_Npm,
                         frame=sched.frame, kinds=sched.kinds))


def _run_fresh(args: tuple[int, str, list[Any]]) -> str:
    seed, out, schedules = args
    frame = bench.schedule_set(SCHEDULES).frame
    return str(run_skill(seed, Path(out), schedules=np.asarray(schedules), first_repeat=bench.ROLLOUTS, tag="fresh",
                         revision=REVISION, domain=bench.domain(DOMAIN), frame=frame))


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


def schedule_kinds(diagonal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(constant, isotropic) flags of per-phase diagonals (S, P, 3). Constant: the same diagonal in every phase,
    anisotropic ones included (in the surface frame, the same (K_t, K_n) throughout), so that T2 measures what
    varying stiffness in time buys. Isotropic: the same stiffness on every axis in every phase."""
    diagonal = np.asarray(diagonal, dtype=np.float64)
    return (np.all(diagonal == diagonal[:, :1], axis=(1, 2)), np.all(diagonal == diagonal[:, :, :1], axis=(1, 2)))


def load_skill(out: Path, seed: int, from_contact: bool, objective: Any = None) -> dict[str, Any]:
    objective = objective if objective is not None else bench.objective(OBJECTIVE)
    data = np.load(Path(out) / "skills" / f"paced_{seed}.npz")
    losses = task_losses(data, from_contact, objective)
    kinds = [str(k) for k in data["kinds"]]
    phase = data["phase_Npm"]
    diagonal = bench.phase_diagonal(phase)
    constant, isotropic = schedule_kinds(diagonal)
    task = losses.mean(axis=1)  # inf if any rollout failed
    demo_row = int(np.flatnonzero(np.all(diagonal == bench.DEMO_STIFFNESS_NPM, axis=(1, 2)))[0])
    stiffest = float(data["L_comp"].max())
    reference = np.array([TASK_FACTOR * task[demo_row], stiffest])
    spec = json.loads(str(data["spec"]))
    frame = str(data["frame"]) if "frame" in data else "world"
    return {"seed": seed, "task": task, "comp": data["L_comp"], "constant": constant, "kinds": kinds,
            "phase": phase, "diagonal": diagonal, "isotropic": isotropic, "frame": frame,
            "reference": reference, "losses": losses, "spec": spec,
            "approach_share": stats.approach_share(*squared_error_sums(data, objective)),
            "failed": int(data["failed"].sum()), "rollouts": int(data["failed"].size)}


def _label(row: np.ndarray, frame: str = "world") -> str:
    return bench.schedule_label(row, frame)


def _speeds(spec: dict[str, Any]) -> list[float]:
    from dcm.sim import DemoSpec

    draws = DemoSpec.from_dict(spec).curve_draws()
    return [round(float(v), 3) for v in draws["speed_mps"]] + [round(float(draws["press_m"]) * 1000, 1)]


def prior_indices(skill: dict[str, Any]) -> np.ndarray:
    """The five-constant prior's schedules in a skill's set: constant, isotropic, at ``task.PRIOR_LEVELS_NPM``."""
    return np.flatnonzero([bool(c) and bool(i) and (k in ("grid", "prior")) and float(d[0, 0]) in bench.PRIOR_LEVELS_NPM
                           for c, i, k, d in zip(skill["constant"], skill["isotropic"], skill["kinds"],
                                                 skill["diagonal"])])


def certify(skills: list[dict[str, Any]], rule: list[int] | None, fresh: dict[int, np.ndarray] | None,
            t5: dict[str, Any] | None = None) -> dict[str, Any]:
    """T1-T4 over ``skills`` (``load_skill`` dicts); ``rule`` indexes the fixed rule's schedules; ``t5`` is a
    ``stats.ridge_ranking`` result for the same skills, in their order (left out when None)."""
    rows = []
    frame = skills[0].get("frame", "world")
    _lab = lambda row: _label(row, frame)  # noqa: E731
    prior = prior_indices(skills[0])
    for sk in skills:
        t2 = stats.variable_gain(sk["task"], sk["comp"], sk["constant"])
        ih_all = stats.front_hypervolume(sk["task"], sk["comp"], sk["reference"])
        ih_prior = stats.front_hypervolume(sk["task"], sk["comp"], sk["reference"], prior)
        ih_rule = stats.front_hypervolume(sk["task"], sk["comp"], sk["reference"], rule) if rule else float("nan")
        row = {"seed": sk["seed"], "speeds_press": _speeds(sk["spec"]), "approach_share": sk["approach_share"],
               "best": _lab(sk["phase"][t2["best"]]), "best_task": t2["best_task"],
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
    out: dict[str, Any] = {}
    if t5 is not None:
        for row, rho in zip(rows, t5["spearman"]):
            row["ridge_spearman"] = rho
        out = {"t5_median": t5["median"], "t5_mode": t5["mode"]}
    return {"rows": rows, "single": _lab(skills[0]["phase"][t4["single"]]), "t4_median": t4["median"],
            "prior": [_lab(skills[0]["phase"][i]) for i in prior],
            "rule": [_lab(skills[0]["phase"][i]) for i in rule] if rule else [], **out,
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
        result[seed] = task_losses(data, FROM_CONTACT, bench.objective(OBJECTIVE)).mean(axis=1)
        del horizon, approach
    return result


def render(result: dict[str, Any]) -> str:
    """The per-skill table and the T1-T4 summary (T5 and the design where the result holds them), as markdown."""
    unit = "N" if result.get("objective", "paper") == "paper" else "tolerances"
    head = ("| skill seed | speeds per third [m/s], press [mm] | approach share | best schedule [N/m] "
            f"| its L_task [{unit}] | best constant within its L_comp [{unit}] | T2 gain (oracle) "
            "| T2 gain (fresh rollouts) | I_H oracle | I_H prior | I_H rule | oracle over prior | oracle over rule "
            "| T4 regret of the single schedule | failed rollouts |")
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
    if "t5_median" in result:
        lines += [f"- T5 stiffness-only ridge ({result['t5_mode']}), within-skill Spearman per skill: "
                  + ", ".join(f"{r['seed']}: {r['ridge_spearman']:.3f}" for r in result["rows"])
                  + f"; median {result['t5_median']:.3f}"]
    if "design" in result:
        lines = [f"design: objective {result['objective']}, schedules {result['schedules']} "
                 f"({result['frame']} frame), domain {result['domain']}, revision {result['revision']}", ""] + lines
    return "\n".join(lines) + "\n"


FROM_CONTACT = False  # set by --from-contact; module level so worker processes need not know it
REVISION = bench.REVISION  # set by --revision, the same way
OBJECTIVE = "paper"  # set by --objective (task.OBJECTIVES)
SCHEDULES = "isotropic_grid"  # set by --schedules (task.SCHEDULE_SETS)
DOMAIN = bench.DOMAIN  # set by --domain (task.DOMAINS)


def main(argv: list[str] | None = None) -> int:
    global FROM_CONTACT, REVISION, OBJECTIVE, SCHEDULES, DOMAIN
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--split", choices=("train", "valid"), required=True)
    parser.add_argument("--out", type=Path, required=True, help="where the oracle's per-skill results go")
    parser.add_argument("--rule-from", type=Path, help="a finished train oracle: fit the fixed rule and T5's ridge there")
    parser.add_argument("--workers", type=int, default=2, help="worker processes (1 or 2 on a shared machine)")
    parser.add_argument("--from-contact", action="store_true", help="L_task from the end of the approach on")
    parser.add_argument("--revision", choices=sorted(bench.REVISIONS), default=None,
                        help="the task revision to certify (studies/benchmark/task.py REVISIONS)")
    parser.add_argument("--design", choices=sorted(bench.DESIGNS), default=None,
                        help="objective, schedules, domain and revision at once (task.py DESIGNS)")
    parser.add_argument("--objective", choices=sorted(bench.OBJECTIVES), default=None)
    parser.add_argument("--schedules", choices=sorted(bench.SCHEDULE_SETS), default=None)
    parser.add_argument("--domain", choices=sorted(bench.DOMAINS), default=None)
    parser.add_argument("--no-t5", action="store_true", help="leave T5 (the stiffness-only ridge) out")
    parser.add_argument("--report", type=Path, help="write <report>.json and <report>_tables.md next to this path")
    args = parser.parse_args(argv)
    if args.workers not in (1, 2):
        parser.error(f"--workers = {args.workers}: use 1 or 2 on this shared machine")
    design = dict(bench.DESIGNS[args.design]) if args.design else dict(bench.DESIGNS["paper_isotropic"])
    for key in ("objective", "schedules", "domain", "revision"):
        if getattr(args, key) is not None:
            if args.design and getattr(args, key) != design[key]:
                parser.error(f"--{key} {getattr(args, key)} contradicts --design {args.design} ({design[key]})")
            design[key] = getattr(args, key)
    FROM_CONTACT = args.from_contact
    REVISION, OBJECTIVE, SCHEDULES, DOMAIN = (design[k] for k in ("revision", "objective", "schedules", "domain"))
    legacy = args.design is None and design == bench.DESIGNS["paper_isotropic"]
    seeds = list(bench.TRAIN_SEEDS if args.split == "train" else bench.VALID_SEEDS)
    start = time.time()
    run_oracle(seeds, args.out, args.workers)
    oracle_s = time.time() - start
    skills = [load_skill(args.out, s, args.from_contact) for s in seeds]
    rule = None
    train = None
    if args.rule_from is not None:
        train = [load_skill(args.rule_from, s, args.from_contact) for s in bench.TRAIN_SEEDS]
        rule = stats.greedy_rule([t["task"] for t in train], [t["comp"] for t in train],
                                 [t["reference"] for t in train], bench.RULE_SIZE)
    fresh = fresh_pairs(skills, args.out, args.workers)
    t5 = None
    if not args.no_t5 and not legacy:
        if args.split == "train":
            t5 = stats.ridge_ranking([(sk["diagonal"], sk["task"]) for sk in skills])
        elif train is not None:
            t5 = stats.ridge_ranking([(t["diagonal"], t["task"]) for t in train],
                                     [(sk["diagonal"], sk["task"]) for sk in skills])
    result = certify(skills, rule, fresh, t5)
    result["from_contact"] = args.from_contact
    result["split"] = args.split
    result["revision"] = REVISION
    if not legacy:
        result.update(design=args.design or "custom", objective=OBJECTIVE, schedules=SCHEDULES, domain=DOMAIN,
                      frame=bench.schedule_set(SCHEDULES).frame, n_schedules=int(len(skills[0]["task"])),
                      wall_s={"oracle": oracle_s, "total": time.time() - start})
    text = json.dumps(result, indent=1, default=float)
    print(text)
    if args.report:
        args.report.parent.mkdir(parents=True, exist_ok=True)
        args.report.with_suffix(".json").write_text(text + "\n")
        args.report.with_name(args.report.stem + "_tables.md").write_text(render(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
