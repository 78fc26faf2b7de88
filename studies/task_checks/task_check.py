"""Does the simulated task reward stiffness, without controller artefacts? Measured per skill of a preset.

    python -m studies.task_checks.task_check --dataset sim --splits valid test \
        --out studies/task_checks/reports/task_check_sim

For every skill of the chosen splits it records the demo once and runs:

* **a constant-stiffness sweep** (100 ... 2,500 N/m, isotropic): Spearman(K, L_task), which must be
  strongly negative if stiffness buys force tracking, and ``L_task(100) / L_task(2500)``;
* **phase additivity** of ``1500→150→1500`` and ``150→1500→150`` (3 equal-time phases): the schedule's
  summed squared force error divided by the sum, phase by phase, of the same phases' error at constant
  stiffness. A controller whose stiffness changes add no artefact of their own gives about 1;
* **random per-phase schedules** (the search space of ``conf/stiffness/default.yaml``): Spearman between
  L_comp and L_task, i.e. how much of a trade-off one skill offers.

It writes ``task_check.json`` (per skill and medians) and ``task_check.png`` (L_task against K per family,
additivity, L_task against L_comp). The simulator options (embodiment, damping) are flags, so the
controller variants can be compared on the same skills.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import spearmanr

from dcm.control import compliance_loss, equal_time_phases, schedule_from_phases
from dcm.control.objectives import task_loss, task_window_start

SWEEP_NPM = (100.0, 150.0, 250.0, 500.0, 1000.0, 1500.0, 2500.0)
ADDITIVITY_SCHEDULES = {"1500-150-1500": (1500.0, 150.0, 1500.0), "150-1500-150": (150.0, 1500.0, 150.0)}
CONF_DIR = Path(__file__).resolve().parents[2] / "conf"  # the product's: generate.yaml, dataset/, stiffness/
STUDY_CONF_DIR = Path(__file__).resolve().parents[1] / "conf"  # the research dataset presets (dataset/)
REPORTS = Path(__file__).resolve().parent / "reports"


def squared_error(force_obs: np.ndarray, force_demo: np.ndarray) -> np.ndarray:
    """Per-step squared force error over the three force axes (H,): what L_task averages."""
    return ((np.asarray(force_obs)[:, :3] - np.asarray(force_demo)[:, :3]) ** 2).sum(-1)


def phase_additivity(schedule_error: np.ndarray, constant_errors: list[np.ndarray], boundaries: np.ndarray) -> float:
    """Σ_t e²(schedule) / Σ_phases Σ_{t in phase} e²(that phase's stiffness held constant)."""
    expected = sum(err[boundaries[p]:boundaries[p + 1]].sum() for p, err in enumerate(constant_errors))
    return float(schedule_error.sum() / max(expected, 1e-12))


def check_skill(sim: Any, spec: Any, n_random: int, space: dict[str, Any], rng: np.random.Generator,
                task_from_s: float = 0.0) -> dict[str, Any]:
    """All three measurements on one demo spec (a ``DemoSpec``); L_task and the additivity's errors count the
    force from ``task_from_s`` on (:func:`dcm.control.objectives.task_window_start`)."""
    demo = sim.record_demo(spec)
    horizon = demo.horizon
    bounds = equal_time_phases(horizon, 3)
    rot = float(space["rot_Nmprad"])
    start = task_window_start(task_from_s, sim.control_hz, horizon)

    def error(trial: Any) -> np.ndarray:
        err = squared_error(trial.force_obs, demo.force_demo)
        err[:start] = 0.0
        return err

    def loss(trial: Any) -> float:
        return float("inf") if trial.failed else float(task_loss(trial.force_obs, demo.force_demo, start))

    sweep: dict[float, Any] = {}
    for k in SWEEP_NPM:
        sweep[k] = sim.rollout(demo, sim.constant_stiffness(demo, k, rot))
    l_sweep = [loss(sweep[k]) for k in SWEEP_NPM]
    additivity = {}
    for name, phases in ADDITIVITY_SCHEDULES.items():
        trial = sim.rollout(demo, schedule_from_phases(np.repeat(np.array(phases)[:, None], 3, 1), bounds, rot))
        const = [error(sweep[k]) for k in phases]
        additivity[name] = phase_additivity(error(trial), const, bounds)
    low, high = float(space["min_Npm"]), float(space["max_Npm"])
    l_task, l_comp = [], []
    for _ in range(n_random):
        phases = rng.uniform(low, high, size=(3, 3))
        schedule = schedule_from_phases(phases, bounds, rot)
        trial = sim.rollout(demo, schedule)
        if not trial.failed:
            l_task.append(loss(trial))
            l_comp.append(float(compliance_loss(schedule)))
    failed = sum(t.failed for t in sweep.values())
    return {
        "family": spec.family,
        "sweep_Npm": list(SWEEP_NPM),
        "sweep_L_task": l_sweep,
        "spearman_K_L_task": float(spearmanr(SWEEP_NPM, l_sweep).statistic),
        "ratio_L_task_100_over_2500": float(l_sweep[0] / max(l_sweep[-1], 1e-12)),
        "additivity": additivity,
        "random_L_task": l_task,
        "random_L_comp": l_comp,
        "spearman_L_comp_L_task": float(spearmanr(l_comp, l_task).statistic) if len(l_task) > 2 else float("nan"),
        "failed_sweep_trials": int(failed),
    }


def summarise(skills: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Medians and ranges per family, and the share of skills with Spearman(K, L_task) <= -0.8."""
    out: dict[str, Any] = {}
    for family in sorted({s["family"] for s in skills.values()}):
        rows = [s for s in skills.values() if s["family"] == family]
        rho = np.array([s["spearman_K_L_task"] for s in rows])
        ratio = np.array([s["ratio_L_task_100_over_2500"] for s in rows])
        out[family] = {
            "n_skills": len(rows),
            "spearman_K_L_task_median": float(np.median(rho)),
            "share_spearman_K_L_task_le_-0.8": float(np.mean(rho <= -0.8)),
            "ratio_L_task_100_over_2500_median": float(np.median(ratio)),
            "ratio_range": [float(ratio.min()), float(ratio.max())],
            "additivity_range": {name: [float(min(s["additivity"][name] for s in rows)),
                                        float(max(s["additivity"][name] for s in rows))]
                                 for name in ADDITIVITY_SCHEDULES},
            "spearman_L_comp_L_task_median": float(np.nanmedian([s["spearman_L_comp_L_task"] for s in rows])),
        }
    return out


def plot(skills: dict[str, dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    families = sorted({s["family"] for s in skills.values()})
    colours = dict(zip(families, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    fig, axes = plt.subplots(1, 3, figsize=(14, 4), constrained_layout=True)
    for s in skills.values():
        c = colours[s["family"]]
        axes[0].plot(s["sweep_Npm"], s["sweep_L_task"], "o-", c=c, ms=3, lw=0.8, alpha=0.7)
        axes[2].scatter(s["random_L_comp"], s["random_L_task"], s=8, color=c, alpha=0.6)
    for f in families:
        axes[0].plot([], [], c=colours[f], label=f)
    axes[0].set(xscale="log", xlabel="constant stiffness K [N/m]", ylabel="L_task [N]",
                title="L_task against constant stiffness")
    axes[0].legend()
    names = list(ADDITIVITY_SCHEDULES)
    jitter = np.random.default_rng(0).uniform(-0.15, 0.15, size=len(skills))  # spread the skills' dots
    for i, name in enumerate(names):
        for j, s in enumerate(skills.values()):
            axes[1].scatter(i + jitter[j], s["additivity"][name], color=colours[s["family"]], s=14)
    axes[1].axhline(1.0, c="k", lw=0.8, ls="--")
    axes[1].set(xticks=range(len(names)), xticklabels=names, ylabel="phase additivity",
                title="phase additivity (1 = no artefact)")
    axes[2].set(xlabel="L_comp [kN/m]", ylabel="L_task [N]", title="random schedules: L_task against L_comp")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def preset_skills(dataset: str, splits: list[str], seed: int, max_skills: int | None, error: Callable[[str], Any],
                  overrides: dict[str, Any] | None = None) -> tuple[dict[str, Any], list[Any]]:
    """The preset ``<dataset>.yaml`` of ``conf/dataset`` or ``studies/conf/dataset`` as generation sees it
    (plus ``overrides``) and the demo jobs of its skills whose first trial split is in ``splits`` (the first
    ``max_skills``); ``error`` is called with a message naming the preset when there is none."""
    from omegaconf import OmegaConf

    from dcm.data.generate import compose_config
    from dcm.data.presets import plan_demos

    folders = [CONF_DIR / "dataset", STUDY_CONF_DIR / "dataset"]
    if not any((folder / f"{dataset}.yaml").is_file() for folder in folders):
        error(f"--dataset {dataset!r}: no preset file {dataset}.yaml in {' or '.join(map(str, folders))}")
    research = f"hydra.searchpath=['file://{STUDY_CONF_DIR}']"  # a research preset is found beside the product's
    preset = {**OmegaConf.to_container(compose_config(dataset, [research]).dataset, resolve=True),
              **(overrides or {})}
    jobs = [j for j in plan_demos(preset, seed) if j.trial_splits[0] in splits]
    if max_skills:
        jobs = jobs[:max_skills]
    if not jobs:
        error(f"preset {dataset!r} has no skills in splits {splits}")
    return preset, jobs


def parse_domain(text: str, error: Callable[[str], Any]) -> Any:
    """``--domain``: a DomainSpec preset name or a JSON mapping of its fields; ``error`` names what is wrong."""
    from dcm.sim.domain import DomainSpec, DomainSpecError

    try:
        return DomainSpec.resolve(json.loads(text) if text.lstrip().startswith("{") else text)
    except json.JSONDecodeError as err:
        error(f"--domain {text!r} is not a JSON mapping: {err}")
    except DomainSpecError as err:
        error(f"--domain: {err}")


def main(argv: list[str] | None = None) -> dict[str, Any]:
    from omegaconf import OmegaConf
    from tqdm import tqdm

    from dcm.sim.demos import DemoSpec
    from dcm.sim.domain import DomainSpec
    from dcm.sim.rollout import Simulator

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", default="sim", help="preset in conf/dataset/ or studies/conf/dataset/")
    parser.add_argument("--splits", nargs="+", default=["valid", "test"])
    parser.add_argument("--embodiment", default=None, help="default: the preset's")
    parser.add_argument("--damping", default="critical", choices=["critical", "unit"])
    parser.add_argument("--domain", default=None,
                        help="default: the preset's; a domain preset name (realistic) or a JSON mapping of "
                             "DomainSpec fields, e.g. '{\"joint_frictionloss\": 0.5}'")
    parser.add_argument("--max-skills", type=int, default=None, help="first N skills of the chosen splits")
    parser.add_argument("--n-random", type=int, default=20)
    parser.add_argument("--duration", type=float, default=None, help="override the demos' duration [s]")
    parser.add_argument("--demo-lead", action="store_true", help="record the demos with a leading demonstrator")
    parser.add_argument("--demo-hover-m", type=float, default=None,
                        help="start the demos' approach this high above the bowl [m] (0: resting on it)")
    parser.add_argument("--task-from-s", type=float, default=0.0,
                        help="count the force error from this time [s] on (1.0: without the demos' approach)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=str(REPORTS / "task_check"))
    args = parser.parse_args(argv)

    overrides = {"duration_s": args.duration} if args.duration is not None else {}
    if args.demo_lead:
        overrides["demo_lead"] = True
    if args.demo_hover_m is not None:
        overrides["demo_hover_m"] = args.demo_hover_m
    preset, jobs = preset_skills(args.dataset, args.splits, args.seed, args.max_skills, parser.error, overrides)
    domain = parse_domain(args.domain, parser.error) if args.domain is not None else DomainSpec.resolve(preset["domain"])
    space = OmegaConf.to_container(OmegaConf.load(CONF_DIR / "stiffness" / "default.yaml"))
    embodiment = args.embodiment or preset["embodiment"]
    sims: dict[str, Simulator] = {}
    rng = np.random.default_rng(args.seed)
    skills: dict[str, dict[str, Any]] = {}
    start = time.perf_counter()
    for job in tqdm(jobs, desc="task check", unit="skill"):
        spec = DemoSpec.from_dict(job.spec, where=f"{args.dataset} skill {job.index}")
        key = json.dumps(job.spec.get("bowl", {}), sort_keys=True)
        if key not in sims:
            sims = {key: Simulator(embodiment, spec.bowl, domain, seed=args.seed,
                                   damping=args.damping)}
        skills[f"{job.skill}_{job.index:03d}"] = check_skill(sims[key], spec, args.n_random, space, rng,
                                                             args.task_from_s)
    result = {"dataset": args.dataset, "splits": args.splits, "embodiment": embodiment, "damping": args.damping,
              "domain": domain.to_dict(),
              "duration_s": preset.get("duration_s", 8.0), "demo_lead": bool(preset.get("demo_lead", False)),
              "task_from_s": args.task_from_s, "demo_hover_m": preset.get("demo_hover_m"),
              "seconds": time.perf_counter() - start, "summary": summarise(skills), "skills": skills}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "task_check.json").write_text(json.dumps(result, indent=1))
    plot(skills, out / "task_check.png")
    print(json.dumps(result["summary"], indent=1))
    print(f"wrote {out / 'task_check.json'} and {out / 'task_check.png'} in {result['seconds']:.0f} s")
    return result


if __name__ == "__main__":
    main()
