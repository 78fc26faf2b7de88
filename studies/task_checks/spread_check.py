"""Can a model of the force *distribution* rank a skill's schedules better than a model of its *mean*?

    python -m studies.task_checks.spread_check --dataset sim_contact --bowl-offset-mm 0.5 2 5 \
        --out studies/task_checks/reports/spread_check_sim_contact
    python -m studies.task_checks.spread_check --bowl-offset-mm 0.5 --friction-std 0.3 --n-truth 16 \
        --out studies/task_checks/reports/spread_check_n16

The paper's case for a diffusion model is that contact is uncertain: the same inputs give different forces.
This check asks, with the simulator as an oracle, how much that can be worth on the tuner's question. For
every skill of the chosen splits it records the demo once and draws random per-phase schedules (the search
space of ``conf/stiffness/default.yaml``). Each schedule is rolled out ``k + n + 1`` times (``n`` truth
rollouts, ``--n-truth``, k by default): ``k + n`` times with different simulator seeds, i.e. different draws
of the domain's per-rollout perturbation (the bowl's height, ``bowl_offset_std_m``, or its friction,
``bowl_friction_std``), and once without it:

* rollouts ``1..k`` stand in for a perfect **diffusion model** drawing k samples: ``L_task`` averaged over
  them (``distribution_k``), or of the first one alone (``distribution_1``);
* the unperturbed rollout stands in for a perfect **single-pass model**, which learns the conditional mean
  of the force: the force responds about linearly to a small bowl offset (K times it, while in contact) and
  to the friction coefficient (the drag is friction times the normal force), so its mean is the force of
  the nominal bowl; ``L_task`` of that force (``mean_force``);
* rollouts ``k+1..k+n`` are the truth: the first one is the **label** a dataset holds (one realisation),
  their mean ``L_task`` the **expected** loss a tuner wants to minimise. The expected loss is itself an
  average of n draws; a larger n makes it the truth a ranking can be judged against.

Each predictor is correlated with both truths within each skill (Pearson, averaged over skills, as
``R_within``), and its **top-3 regret** says what a tuner keeping its three best-ranked schedules of a skill
loses in expected loss (``top_pick_regret``); ``--rescore JSON`` recomputes both from a stored run's rows.
With no per-rollout perturbation every rollout is the same, so all three rank perfectly (R = 1): the known
answer. The gap between ``distribution_k`` and ``mean_force`` is what a model drawing k exact samples gains
over a model of the mean, before either has to learn anything. ``--predictor LABEL=PATH`` scores trained
models (and references) on the same schedules beside the oracles, a DCM both ways: L_task of its samples'
mean force, and their RMS L_task (``task_loss=over_samples``).

**Is a DCM's spread calibrated?** Ranking by ``over_samples`` needs the samples to spread as the rollouts do.
Every row also holds the truth's force spread (``force_spread_N``: the RMS over time and the three force
axes of the per-step std over the n truth rollouts) and each DCM's (``LABEL, force spread``, the same of its
samples). ``spread_calibration`` gives, per DCM, the median ratio of the two over every schedule (1:
calibrated, below 1: too sure) and their within-skill correlation (does it know *which* schedules spread
more, e.g. the stiff ones on an uncertain bowl height?).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from dcm.control import equal_time_phases, schedule_from_phases, task_loss, task_loss_over_samples
from studies.task_checks.task_check import CONF_DIR, REPORTS, preset_skills

PREDICTORS = ("distribution_1", "distribution_k", "mean_force")
TRUTHS = ("label", "expected")
ROW_FACTS = ("label", "expected", "offset_std_mm", "friction_factor_std", "force_spread_N")  # they predict nothing
SPREAD = ", force spread"  # a DCM's column of its samples' force spread (``LABEL, force spread``)
TOP_PICKS = 3  # = dcm.models.metrics.TOP_PICKS, kept here so that the module loads without torch


def force_spread(std: np.ndarray) -> np.ndarray:
    """(..., H, 6) per-step std of the wrench -> (...,) its RMS over time and the three force axes [N]: the
    reduction of L_task, so that ``over_samples`` L_task² = (L_task of the mean)² + force spread²."""
    std = np.asarray(std, dtype=np.float64)
    return task_loss(std, np.zeros_like(std))


def oracle_losses(forces: np.ndarray, force_demo: np.ndarray, k: int,
                  n_truth: int | None = None) -> dict[str, float]:
    """Each oracle predictor's and truth's L_task from ``forces`` (k + n + 1, H, 6) of one schedule, with
    ``n = n_truth`` (k by default): rollouts ``0..k-1`` are the distribution model's samples, the next n the
    truth (the first the label, all of them the expected loss), the last one the unperturbed force the mean
    model predicts."""
    n = k if n_truth is None else n_truth
    if forces.shape[0] != k + n + 1:
        raise ValueError(f"need k + n_truth + 1 = {k + n + 1} rollouts, got {forces.shape[0]}")
    per_rollout = task_loss(forces, force_demo[None])
    return {
        "distribution_1": float(per_rollout[0]),
        "distribution_k": float(per_rollout[:k].mean()),
        "mean_force": float(per_rollout[k + n]),
        "label": float(per_rollout[k]),
        "expected": float(per_rollout[k:k + n].mean()),
    }


def _columns(skills: dict[str, list[dict[str, float]]], predictor: str, truth: str
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A predictor's and a truth's values over every skill's schedules, with each schedule's skill index."""
    rows = [(r[predictor], r[truth], i) for i, skill in enumerate(skills.values()) for r in skill]
    return tuple(np.array(a) for a in zip(*rows))  # type: ignore[return-value]


def within_skill_r(skills: dict[str, list[dict[str, float]]], predictor: str, truth: str = "label") -> float:
    """The project's R_within (``dcm.models.metrics.within_skill_correlation``) of a predictor against the
    truth over each skill's schedules: NaN for a predictor that ranks nothing (copy-F_demo)."""
    from dcm.models.metrics import within_skill_correlation

    return within_skill_correlation(*_columns(skills, predictor, truth))[0]


def top_pick_regret(skills: dict[str, list[dict[str, float]]], predictor: str, n_top: int = TOP_PICKS) -> float:
    """What a tuner keeping a predictor's ``n_top`` best-ranked schedules of a skill loses in expected loss
    (``dcm.models.metrics.within_skill_regret``): 0 keeps the truly best, 1 is a random pick; NaN for a
    predictor that ranks nothing (copy-F_demo)."""
    from dcm.models.metrics import within_skill_regret

    return within_skill_regret(*_columns(skills, predictor, "expected"), n_top=n_top)[0]


def summarise(skills: dict[str, list[dict[str, float]]]) -> dict[str, Any]:
    """Every predictor's R_within against both truths and its top-pick regret, from the rows alone."""
    first = next((rows[0] for rows in skills.values() if rows), None)
    if first is None:
        raise ValueError("no schedule of any skill was rolled out without failing; nothing to score")
    columns = [key for key in first if key not in ROW_FACTS and not key.endswith(SPREAD)]
    label = np.array([r["label"] for rows in skills.values() for r in rows])
    out = {
        "R_within": {truth: {p: within_skill_r(skills, p, truth) for p in columns} for truth in TRUTHS},
        f"top{TOP_PICKS}_regret": {p: top_pick_regret(skills, p) for p in columns},
        "L_task_label_median": float(np.median(label)),
    }
    spreads = [key for key in first if key.endswith(SPREAD)]
    if spreads and "force_spread_N" in first:
        out["spread_calibration"] = {key[:-len(SPREAD)]: spread_calibration(skills, key) for key in spreads}
    return out


def spread_calibration(skills: dict[str, list[dict[str, float]]], column: str) -> dict[str, float]:
    """A predictor's force spread against the truth's: the median ratio over every schedule, and their
    within-skill correlation (NaN where neither varies, e.g. with no per-rollout perturbation)."""
    pred, true = (np.array([r[key] for rows in skills.values() for r in rows]) for key in (column, "force_spread_N"))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = pred / true
    finite = np.isfinite(ratio)
    return {"ratio_median": float(np.median(ratio[finite])) if finite.any() else float("nan"),
            "R_within": within_skill_r(skills, column, "force_spread_N"),
            "truth_median_N": float(np.median(true)), "predicted_median_N": float(np.median(pred))}


def rescore(path: Path) -> dict[str, Any]:
    """Recompute the statistics of a stored ``spread_check.json`` from its rows, without a rollout."""
    out = json.loads(path.read_text())
    if "by_spread" not in out:
        raise ValueError(f"{path}: no 'by_spread' entry; rescore needs the rows keyed by spread")
    for row in out["by_spread"].values():
        row.update(summarise(row["skills"]))
    path.write_text(json.dumps(out, indent=1))
    return out


def print_summary(out: dict[str, Any]) -> None:
    """The run's statistics as a table, a row per spread and a column per predictor."""
    results = out["by_spread"]
    n_skills = len(next(iter(results.values()))["skills"])
    columns = list(next(iter(results.values()))["R_within"]["label"])
    print(f"R_within ({n_skills} skills, {out['n_schedules']} schedules each, k = {out['k']}, n_truth = "
          f"{out['n_truth']}), against one labelled rollout / against the expected L_task; then the top-"
          f"{TOP_PICKS} regret (0 = the best schedules kept, 1 = a random pick)")
    print("per-rollout spread | " + " | ".join(columns) + " | median label L_task [N]")
    for name, row in results.items():
        r, regret = row["R_within"], row[f"top{TOP_PICKS}_regret"]
        print(f"{name} | " + " | ".join(f"{r['label'][p]:.3f} / {r['expected'][p]:.3f}" for p in columns)
              + f" | {row['L_task_label_median']:.2f}")
        print(f"{name}, top-{TOP_PICKS} regret | " + " | ".join(f"{regret[p]:.2f}" for p in columns) + " |")
        for label, cal in row.get("spread_calibration", {}).items():
            print(f"{name}, {label}: force spread {cal['predicted_median_N']:.3f} N against the rollouts' "
                  f"{cal['truth_median_N']:.3f} N (median ratio {cal['ratio_median']:.2f}), R within "
                  f"{cal['R_within']:.3f}")


def check_skill(sims: list[Any], spec: Any, n_schedules: int, k: int, space: dict[str, Any],
                rng: np.random.Generator, predictors: dict[str, Any] | None = None,
                model_samples: int | None = None) -> list[dict[str, float]]:
    """Oracle losses for ``n_schedules`` random 3-phase schedules of one skill; ``sims`` are k + n simulators
    that differ only in their seed (k samples, n truths), then one without the per-rollout perturbation.
    ``predictors`` (label -> loaded predictor) add each one's L_task for the same schedules, from
    ``model_samples`` samples, k by default (``dcm.models.predict.predict_task_loss``)."""
    demo = sims[0].record_demo(spec)
    bounds = equal_time_phases(demo.horizon, 3)
    low, high = float(space["min_Npm"]), float(space["max_Npm"])
    rows, inputs = [], []
    for _ in range(n_schedules):
        schedule = schedule_from_phases(rng.uniform(low, high, size=(3, 3)), bounds, float(space["rot_Nmprad"]))
        trials = [sim.rollout(demo, schedule) for sim in sims]
        if any(t.failed for t in trials):
            continue
        forces = np.stack([t.force_obs for t in trials])
        perturbed = trials[:-1]
        rows.append({**oracle_losses(forces, np.asarray(demo.force_demo), k, len(perturbed) - k),
                     "offset_std_mm": float(np.std([t.bowl_offset_m for t in perturbed]) * 1000),
                     "friction_factor_std": float(np.std([t.bowl_friction_factor for t in perturbed])),
                     "force_spread_N": float(force_spread(forces[k:-1].std(axis=0)))})
        inputs.append((trials[0].x_attr, schedule))
    if rows and predictors:
        from dcm.models.dcm import DCM
        from dcm.models.predict import predict_task_loss

        x_attr, stiffness = (np.stack(a) for a in zip(*inputs))
        x_demo, force_demo = (np.repeat(np.asarray(a)[None], len(rows), 0) for a in (demo.x_demo, demo.force_demo))
        for label, model in predictors.items():
            if isinstance(model, DCM):  # one draw of samples, read out both ways
                mean, std = (np.asarray(a, dtype=np.float64) for a in model.predict_forces(
                    x_demo, force_demo, x_attr, stiffness, n_samples=model_samples or k))
                columns = {label: task_loss(mean, force_demo),
                           f"{label}, over samples": task_loss_over_samples(mean, std, force_demo),
                           label + SPREAD: force_spread(std)}
            else:
                columns = {label: predict_task_loss(model, x_demo, force_demo, x_attr, stiffness,
                                                    n_samples=model_samples or k)}
            for column, losses in columns.items():
                for row, loss in zip(rows, losses):
                    row[column] = float(loss)
    return rows


def load_predictors(specs: list[str], error: Callable[[str], Any], sampler: str | None = None,
                    sampling_steps: int | None = None) -> dict[str, Any]:
    """``LABEL=PATH`` (a checkpoint, a reference JSON or ``copy_demo``) -> loaded predictors. A DCM is scored
    twice from the same samples: ``LABEL`` with L_task of their mean force, ``LABEL, over samples`` with
    their RMS L_task (``task_loss=over_samples``); ``sampler`` / ``sampling_steps`` override its sampler."""
    from dcm.models.dcm import DCM
    from dcm.models.predict import load_model

    out: dict[str, Any] = {}
    for spec in specs:
        label, sep, path = spec.partition("=")
        if not sep or not label or not path:
            error(f"--predictor {spec!r}: expected LABEL=PATH")
        out[label] = load_model(path)
        if isinstance(out[label], DCM) and (sampler or sampling_steps):
            try:
                out[label].set_sampler(sampler, sampling_steps)
            except ValueError as err:
                error(f"--predictor {spec!r}: {err}")
    return out


def main(argv: list[str] | None = None) -> dict[str, Any]:
    from omegaconf import OmegaConf
    from tqdm import tqdm

    from dcm.sim.demos import DemoSpec
    from dcm.sim.domain import PER_ROLLOUT_SPREADS, DomainSpec
    from dcm.sim.rollout import Simulator

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", default="sim_contact", help="preset in conf/dataset/ or studies/conf/dataset/")
    parser.add_argument("--splits", nargs="+", default=["valid"])
    parser.add_argument("--max-skills", type=int, default=4, help="N skills of the chosen splits")
    parser.add_argument("--first-skill", type=int, default=0, help="skip the chosen splits' first skills")
    parser.add_argument("--n-schedules", type=int, default=16, help="random schedules per skill")
    parser.add_argument("--k", type=int, default=4, help="samples the distribution model draws")
    parser.add_argument("--model-samples", type=int, default=None,
                        help="samples a --predictor DCM draws per schedule (default: k)")
    parser.add_argument("--n-truth", type=int, default=None,
                        help="rollouts whose mean L_task is the expected loss (default: k)")
    parser.add_argument("--bowl-offset-mm", type=float, nargs="+", default=None,
                        help="per-rollout bowl height spread(s) to compare [mm] (default 0 2 4 when no "
                             "--friction-std is given)")
    parser.add_argument("--friction-std", type=float, nargs="+", default=[],
                        help="per-rollout log-normal spread(s) of the bowl's friction to compare")
    parser.add_argument("--predictor", nargs="*", default=[], metavar="LABEL=PATH",
                        help="also score these predictors (checkpoint, reference JSON, copy_demo) on the schedules")
    parser.add_argument("--sampler", choices=("ddpm", "ddim"), default=None,
                        help="a --predictor DCM's sampler (default: the checkpoint's own)")
    parser.add_argument("--sampling-steps", type=int, default=None, help="its DDIM steps (dividing T)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=str(REPORTS / "spread_check"))
    parser.add_argument("--rescore", metavar="JSON", help="recompute the statistics of a stored spread_check.json "
                        "from its rows (no rollouts), rewrite it and print them")
    args = parser.parse_args(argv)
    if args.rescore:
        try:
            out = rescore(Path(args.rescore))
        except (OSError, ValueError) as err:
            parser.error(str(err))
        print_summary(out)
        return out
    n_truth = args.k if args.n_truth is None else args.n_truth
    model_samples = args.k if args.model_samples is None else args.model_samples
    if min(args.k, n_truth, model_samples) < 1 or args.n_schedules < 3:
        parser.error(f"--k {args.k}, --n-truth {n_truth} and --model-samples {model_samples} must be >= 1 and "
                     f"--n-schedules {args.n_schedules} >= 3")
    offsets_mm = args.bowl_offset_mm
    if offsets_mm is None:
        offsets_mm = [] if args.friction_std else [0.0, 2.0, 4.0]
    spreads = [(f"bowl_offset_std_mm={v:g}", {"bowl_offset_std_m": v / 1000.0}) for v in offsets_mm]
    spreads += [(f"bowl_friction_std={v:g}", {"bowl_friction_std": v}) for v in args.friction_std]

    preset, jobs = preset_skills(args.dataset, args.splits, args.seed, None, parser.error)
    jobs = jobs[args.first_skill:args.first_skill + args.max_skills]
    if args.first_skill < 0 or not jobs:
        parser.error(f"--first-skill {args.first_skill} --max-skills {args.max_skills}: "
                     f"no skill of {args.splits} left")
    predictors = load_predictors(args.predictor, parser.error, args.sampler, args.sampling_steps)
    if predictors:
        import torch

        torch.manual_seed(args.seed)  # a DCM's samples: the same seed gives the same scores
    space = OmegaConf.to_container(OmegaConf.load(CONF_DIR / "stiffness" / "default.yaml"))
    domain = DomainSpec.resolve(preset["domain"]).to_dict()
    try:
        nominal = DomainSpec.from_dict({**domain, **{key: 0.0 for key in PER_ROLLOUT_SPREADS}})
        perturbed = {name: DomainSpec.from_dict({**nominal.to_dict(), **fields}) for name, fields in spreads}
    except ValueError as err:
        parser.error(str(err))
    results: dict[str, Any] = {}
    start = time.perf_counter()
    bar = tqdm(total=len(spreads) * len(jobs), desc="spread check", unit="skill")
    for name, skill_domain in perturbed.items():
        rng = np.random.default_rng(args.seed)  # the same schedules at every spread
        skills: dict[str, list[dict[str, float]]] = {}
        for job in jobs:
            spec = DemoSpec.from_dict(job.spec, where=f"{args.dataset} skill {job.index}")
            sims = [Simulator(preset["embodiment"], spec.bowl, d, seed=args.seed + i, damping=space["damping"])
                    for i, d in enumerate([skill_domain] * (args.k + n_truth) + [nominal])]
            skills[f"{job.skill}_{job.index:03d}"] = check_skill(sims, spec, args.n_schedules, args.k, space, rng,
                                                                 predictors, model_samples)
            bar.update()
        results[name] = {"domain": {key: getattr(skill_domain, key) for key in PER_ROLLOUT_SPREADS},
                         **summarise(skills), "skills": skills}
    bar.close()
    out = {"dataset": args.dataset, "splits": args.splits, "embodiment": preset["embodiment"], "k": args.k,
           "n_truth": n_truth, "model_samples": model_samples, "n_schedules": args.n_schedules,
           "seed": args.seed, "predictors": args.predictor, "sampler": args.sampler,
           "sampling_steps": args.sampling_steps, "seconds": time.perf_counter() - start,
           "by_spread": results}
    path = Path(args.out)
    path.mkdir(parents=True, exist_ok=True)
    (path / "spread_check.json").write_text(json.dumps(out, indent=1))
    print_summary(out)
    print(f"wrote {path / 'spread_check.json'} in {out['seconds']:.0f} s")
    return out


if __name__ == "__main__":
    main()
