"""A quick probe of a task design on TRAIN skills, before any oracle run: a few schedules, a few rollouts.

    python -m studies.benchmark.probe --revision fast_third --seeds 1000,1001,1002,1003 --rollouts 4 \\
        --out outputs/benchmark/probe

Each skill gets the prior's five constants, the demo's 800 N/m and four "stiff where fast" schedules (the
skill's fastest third at 1000 or 2500 N/m, the others at 150 or 400 N/m), judged by their mean L_task from
contact over common-draw rollouts. It prints one line per skill: its speeds, the best schedule, its gain over
the best constant of equal or lower L_comp (T2's definition) and every schedule's loss. ``--speed`` and
``--fast-speed`` override the revision's speed ranges, ``--domain nominal`` removes every disturbance. It is
for deciding whether a full certification is worth running; it certifies nothing.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from studies.benchmark import stats
from studies.benchmark import task as bench
from studies.benchmark.oracle import run_skill, task_losses


def probe_schedules(speeds: np.ndarray) -> np.ndarray:
    """The prior's constants, the demo's stiffness, then the fastest third stiff and the others soft."""
    rows = [[k] * bench.N_PHASES for k in (*bench.PRIOR_LEVELS_NPM, bench.DEMO_STIFFNESS_NPM)]
    fast = int(np.argmax(speeds))
    for stiff in (1000.0, 2500.0):
        for soft in (150.0, 400.0):
            row = [soft] * bench.N_PHASES
            row[fast] = stiff
            rows.append(row)
    return np.asarray(rows, dtype=np.float64)


def main(argv: list[str] | None = None) -> int:
    from dcm.sim import DemoSpec

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--revision", choices=sorted(bench.REVISIONS), default=bench.REVISION)
    parser.add_argument("--seeds", required=True, help="comma-separated skill seeds (train seeds only)")
    parser.add_argument("--rollouts", type=int, default=4)
    parser.add_argument("--domain", default=bench.DOMAIN, help="a domain preset name")
    parser.add_argument("--speed", type=float, nargs=2, metavar=("LOW", "HIGH"), help="speed_mps override [m/s]")
    parser.add_argument("--fast-speed", type=float, nargs=2, metavar=("LOW", "HIGH"),
                        help="fast_speed_mps override [m/s]")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",")]
    guarded = [s for s in seeds if s not in bench.TRAIN_SEEDS]
    if guarded:
        parser.error(f"--seeds {guarded}: a probe runs on the train seeds {list(bench.TRAIN_SEEDS)} only")
    if args.rollouts < 1:
        parser.error(f"--rollouts = {args.rollouts} must be >= 1")
    override = {k: list(v) for k, v in (("speed_mps", args.speed), ("fast_speed_mps", args.fast_speed)) if v}
    tag = "_".join(["probe", args.revision, args.domain, f"r{args.rollouts}"]
                   + [f"{k}{v[0]:g}-{v[1]:g}" for k, v in override.items()])
    for seed in seeds:
        spec = bench.skill_spec(seed, args.revision)
        spec["params"].update(override)
        speeds = np.asarray(DemoSpec.from_dict(spec).curve_draws()["speed_mps"])
        rows = probe_schedules(speeds)
        path = run_skill(seed, args.out, rollouts=args.rollouts, domain=args.domain,
                         spec_override={"params": spec["params"]}, schedules=rows, tag=tag, revision=args.revision)
        data = np.load(path)
        task = task_losses(data, from_contact=True).mean(axis=1)
        constant = np.all(rows == rows[:, :1], axis=1)
        t2 = stats.variable_gain(task, data["L_comp"], constant)
        labels = ["/".join(f"{v:g}" for v in row) for row in rows]
        print(f"{seed} speeds {np.round(speeds, 3).tolist()} best {labels[t2['best']]} {t2['best_task']:.3f} N "
              f"gain {t2['gain']:+.3f} | " + " ".join(f"{lab}:{loss:.2f}" for lab, loss in zip(labels, task)),
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
