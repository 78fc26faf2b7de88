"""Does the fast robot-free default tune as well as the one before it? Paired I_H over tuning seeds, per skill.

    python -m studies.tuning_speed.compare_defaults [--skills wavelike line spiral] [--seeds 16] [--threads 1]
        [--tuners old new ddim1 ...] [--against old] [--out outputs/studies/tuning_speed]
        [--report studies/tuning_speed/reports/<name>.md]

Why: the fast default changes three things at once (fewer DDIM steps than five, bfloat16 matrix products
where the CPU has them, one MOTPE fit per batch of proposals instead of one per proposal), each of which could
cost hypervolume. Per skill (recorded as ``conf/quickstart.yaml`` records its demo) and tuning seed, both
tuners run :func:`dcm.tuning.run.tune` with the shipped DCM, five validated solutions and no robot-based search:

* ``new``: ``conf/tune.yaml`` as it is (``ddim1`` ... ``ddim5``: with that many steps, the levers apart);
* ``old``: ``robot_free.sampler=ddim robot_free.sampling_steps=5 robot_free.precision=float32
  robot_free.batched_search=false``, and
  the RetNet's parallel form (the chunkwise one gives the same outputs up to float rounding).

Both are scored on ONE reference point per skill: the worst validated L_task and L_comp over every solution of
both tuners and all seeds, pushed out by 10 % of their range (:func:`dcm.tuning.pareto.reference_point`), so
neither tuner sets the point the other is judged against. The test is the paired two-sided Wilcoxon
signed-rank test of each tuner against ``--against`` (``old`` unless given;
:func:`studies.tuning_study.study_stats.paired_test`). A finished run
(``results.json``) is never redone, so a killed comparison resumes where it stopped.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

CONF_DIR = Path(__file__).resolve().parents[2] / "conf"
TEACHER = "models/dcm_diverse_contact.ckpt"  # every tuner's model unless its overrides name another
TUNERS = {
    "old": ["robot_free.sampler=ddim", "robot_free.sampling_steps=5", "robot_free.precision=float32",
            "robot_free.batched_search=false"],
    "new": [],
    # the default's levers apart: which one costs hypervolume where it does
    "ddim1": ["robot_free.sampler=ddim", "robot_free.sampling_steps=1"],
    "ddim2": ["robot_free.sampler=ddim", "robot_free.sampling_steps=2"],
    "ddim3": ["robot_free.sampler=ddim", "robot_free.sampling_steps=3"],
    "ddim5": ["robot_free.sampler=ddim", "robot_free.sampling_steps=5"],
    # DDIM steps spread evenly from t = T-1 to t = 0
    "even2": ["robot_free.sampler=ddim_even", "robot_free.sampling_steps=2"],
    "even3": ["robot_free.sampler=ddim_even", "robot_free.sampling_steps=3"],
    # the shipped DCM's one-step student (dcm-distill), on its own sampler
    "one_step": ["ckpt=models/dcm_diverse_contact_one_step.ckpt", "robot_free.sampler=null",
                 "robot_free.sampling_steps=null"],
}


def tune_config(skill: str, seed: int, tuner: str, threads: int, out_dir: Path, extra: Sequence[str] = ()) -> Any:
    """The quickstart's config of one run: the shipped multi-step DCM, ``demo=<skill>``, seed, the tuner's
    overrides, no robot-based search."""
    from hydra import compose, initialize_config_dir

    overrides = [f"ckpt={TEACHER}", f"demo={skill}", f"seed={seed}", "robot_based.n_trials=0",
                 f"torch_threads={threads}", f"out_dir={out_dir}", *TUNERS[tuner], *extra]
    with initialize_config_dir(config_dir=str(CONF_DIR)):
        return compose(config_name="quickstart", overrides=overrides)


def run_dir(out: Path, skill: str, tuner: str, seed: int) -> Path:
    return out / skill / tuner / f"seed_{seed:03d}"


def run_one(skill: str, seed: int, tuner: str, threads: int, out: Path, extra: Sequence[str] = ()) -> dict[str, Any]:
    """One tuning run's results.json, running it unless it has finished before."""
    import warnings

    from dcm.tuning.run import tune

    folder = run_dir(out, skill, tuner, seed)
    done = folder / "results.json"
    if done.exists():
        return json.loads(done.read_text())
    from dcm.models.nets.retnet import MultiScaleRetention

    chunk = MultiScaleRetention.CHUNK_STEPS
    if tuner == "old":
        MultiScaleRetention.CHUNK_STEPS = 2**31  # the parallel form, as predictions were computed before
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the recording warnings are the quickstart's, the same for both tuners
            return tune(tune_config(skill, seed, tuner, threads, folder, extra), folder)
    finally:
        MultiScaleRetention.CHUNK_STEPS = chunk


def validated(results: dict[str, Any]) -> np.ndarray:
    """(n, 2) validated (L_task, L_comp) of a run's solutions, failed rollouts dropped."""
    rows = [[s["validated"]["L_task_N"], s["validated"]["L_comp_kNpm"]] for s in results["robot_free"]["solutions"]]
    points = np.asarray(rows, dtype=np.float64).reshape(-1, 2)
    return points[np.isfinite(points).all(axis=1)]


def compare(runs: dict[str, dict[str, list[dict[str, Any]]]], against: str = "old") -> dict[str, Any]:
    """Per skill and tuner other than ``against``: the reference point of that pair, both tuners' I_H per seed
    against it, medians and the paired test of the tuner against ``against``."""
    from dcm.tuning.pareto import hypervolume, reference_point
    from studies.tuning_study.study_stats import paired_test, summarize

    report: dict[str, Any] = {}
    for skill, by_tuner in runs.items():
        for tuner, results in by_tuner.items():
            if tuner == against:
                continue
            pair = {against: by_tuner[against], tuner: results}
            reference = reference_point(*[validated(r) for rs in pair.values() for r in rs])
            hv = {t: [hypervolume(validated(r), reference) if len(validated(r)) else float("nan") for r in rs]
                  for t, rs in pair.items()}
            report.setdefault(skill, {})[tuner] = {
                "reference_point": reference.tolist(), "I_H": hv,
                "summary": {t: summarize(values) for t, values in hv.items()},
                "against": against, "test": paired_test(hv[tuner], hv[against]),
                "median_robot_free_seconds": {t: float(np.median([r["robot_free"]["seconds"] for r in rs]))
                                              for t, rs in pair.items()}}
    return report


def machine() -> str:
    """CPU model and cores (lscpu), for the report."""
    try:
        lines = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout.splitlines()
        fields = dict(line.split(":", 1) for line in lines if ":" in line)
        return f"{fields.get('Model name', '?').strip()}, {os.cpu_count()} cores"
    except (OSError, subprocess.CalledProcessError):
        return f"{platform.processor() or '?'}, {os.cpu_count()} cores"


def markdown(report: dict[str, Any], command: str, seeds: int, load: tuple[list[float], list[float]],
             wall_s: float, against: str = "old") -> str:
    base = against
    lines = [
        f"# Robot-free tuners paired against `{base}`: I_H over tuning seeds",
        "",
        f"Command: `{command}`",
        "",
        (f"Machine: {machine()}; load average (1/5/15 min) {'/'.join(f'{v:.2f}' for v in load[0])} when the "
         "report was written (quality runs: timing does not enter I_H)."),
        "",
        ("Tuners: `old` = " + f"`{' '.join(TUNERS['old'])}`" + " (DDIM 5 steps, float32, Optuna's MOTPE fit per "
         "proposal, the RetNet's parallel form: the previous default); `new` = `conf/tune.yaml`; the others = "
         "`conf/tune.yaml` with " + ", ".join(f"{t}: `{' '.join(o)}`" for t, o in TUNERS.items()
                                             if t not in ("old", "new")) + ". "
         f"Shipped DCM, the quickstart's recording (12 s, leading demonstrator), {seeds} tuning seeds, 1,000 "
         "virtual trials, 5 validated solutions, one torch thread. Reference point per skill and pair: the worst "
         "validated (L_task, L_comp) over both tuners' solutions of all seeds + 10 % of the range, the same for "
         f"both tuners of the pair. Test: paired two-sided Wilcoxon signed-rank, tuner against {base}."),
        "",
        (f"| skill | tuner | reference point (N, kN/m) | n | median I_H {base} | median I_H tuner "
         f"| median difference tuner - {base} | wins/losses | Wilcoxon p | median robot-free s {base} / tuner |"),
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for skill, by_tuner in report.items():
        for tuner, r in by_tuner.items():
            test, s = r["test"], r["summary"]
            p = "n/a" if test["p"] is None else f"{test['p']:.3f}"
            secs = r["median_robot_free_seconds"]
            lines.append(f"| {skill} | {tuner} | ({r['reference_point'][0]:.3f}, {r['reference_point'][1]:.3f}) | "
                         f"{test['n_pairs']} | {s[base]['median']:.4f} | {s[tuner]['median']:.4f} | "
                         f"{test['median_difference']:+.4f} | {test['wins']}/{test['losses']} | {p} | "
                         f"{secs[base]:.1f} / {secs[tuner]:.1f} |")
    lines += ["", f"Per seed I_H ({base}, tuner), each pair on its own reference point:", ""]
    for skill, by_tuner in report.items():
        for tuner, r in by_tuner.items():
            pairs = ", ".join(f"({x:.3f}, {y:.3f})" for x, y in zip(r["I_H"][base], r["I_H"][tuner]))
            lines.append(f"- {skill}, {tuner}: {pairs}")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skills", nargs="+", default=["wavelike", "line", "spiral"], help="conf/demo/<name>.yaml")
    parser.add_argument("--seeds", type=int, default=16)
    parser.add_argument("--threads", type=int, default=1, help="torch threads of every run")
    parser.add_argument("--out", type=Path, default=Path("outputs/studies/tuning_speed"))
    parser.add_argument("--report", type=Path, default=None, help="write the markdown report here")
    parser.add_argument("--tuners", nargs="+", choices=sorted(TUNERS), default=["old", "new"],
                        help="tuners to run and report, each against --against")
    parser.add_argument("--against", choices=sorted(TUNERS), default="old", help="the tuner every other is paired with")
    parser.add_argument("--only", choices=sorted(TUNERS), default=None, help="run one tuner only (no report)")
    args = parser.parse_args(argv)

    load_start, start = list(os.getloadavg()), time.perf_counter()
    runs: dict[str, dict[str, list[dict[str, Any]]]] = {}
    for skill in args.skills:
        for tuner in ([args.only] if args.only else [args.against, *[t for t in args.tuners if t != args.against]]):
            for seed in range(args.seeds):
                results = run_one(skill, seed, tuner, args.threads, args.out)
                runs.setdefault(skill, {}).setdefault(tuner, []).append(results)
                print(f"{skill} {tuner} seed {seed}: robot-free {results['robot_free']['seconds']:.1f} s", flush=True)
    if args.only:
        return
    report = compare(runs, args.against)
    (args.out / "compare_defaults.json").write_text(json.dumps(report, indent=2))
    command = "python -m studies.tuning_speed.compare_defaults " + " ".join(argv if argv is not None else
                                                                            __import__("sys").argv[1:])
    text = markdown(report, command.strip(), args.seeds, (load_start, list(os.getloadavg())),
                    time.perf_counter() - start, args.against)
    print(text)
    if args.report is not None:
        args.report.parent.mkdir(parents=True, exist_ok=True)
        args.report.write_text(text)


if __name__ == "__main__":
    main()
