"""Could a robot's F/T sensor tell a skill's schedules apart? The ranking ceiling that label noise sets.

    python -m studies.task_checks.sensor_check --sets data/test_line_fine.h5:test \
        data/diverse_contact_fine.h5:valid --task-from-s 1.0 --out studies/task_checks/reports/sensor_check/fine_wipe

A dataset generated in the nominal domain holds noise-free forces. On a robot, the demo and every trial
are read through a force/torque sensor, and this check asks what that costs the tuner's question. Each draw
is one robot session: the skill's demo force and each trial's F_obs are read once, with a fresh noise
realisation, through the sensing of ``--domain`` (:meth:`dcm.sim.domain.DomainSpec.sense`: its white noise
times ``--noise-scale`` and its low-pass; by default the ``realistic`` preset's 0.3–0.4 N and 5 Hz). The
sensor's bias is left out: a tared sensor reads the demo and the trials with the same offset. Over
``--draws`` sessions it reports per skill:

* ``L_task_sd_N``: how far the skill's schedules differ in noise-free L_task;
* ``label_noise_sd_N``: how far one schedule's sensed L_task moves between two readings (its standard
  deviation over the draws, RMS over the skill's trials);
* ``R_label_truth``: the within-skill Pearson R of one sensed reading against the noise-free L_task, mean
  over draws. A predictor that knew the noise-free force exactly would score about this against labels
  measured by the sensor: the ceiling of R within skill on such data;
* ``R_label_label``: the R of two readings of the same schedules (draw d against draw d + 1, mean over d):
  how alike two robot-based measurements of the skill rank its schedules.

A domain without sensing effects (``--domain nominal``) reads the forces as stored: both Rs are 1, the known
answer. A dataset whose own domain already senses its forces is refused (its labels hold noise already).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from dcm.control.objectives import task_loss, task_window_start
from dcm.data.schema import load_dataset
from dcm.sim.domain import DomainSpec, DomainSpecError

MIN_TRIALS = 3  # as dcm.models.metrics (kept here so that this check loads without torch)


class SensorCheckError(ValueError):
    """An unusable input; the message names the file, split or value."""


def _pearson(a: np.ndarray, b: np.ndarray) -> float:
    if np.ptp(a) == 0 or np.ptp(b) == 0:
        return float("nan")
    return float(np.corrcoef(a, b)[0, 1])


def sensed_task_losses(F_obs: np.ndarray, F_demo: np.ndarray, skills: np.ndarray, domain: DomainSpec,
                       dt: float, draws: int, rng: np.random.Generator, from_step: int = 0) -> np.ndarray:
    """(draws, N) L_task [N] of N stored trials (forces (N, H, 6)) over ``draws`` sessions, from step
    ``from_step`` on: in each session every trial's F_obs and each skill's demo force (shared by its trials)
    are read once through ``domain``'s sensor, without its bias."""
    tared = replace(domain, ft_bias=(0.0,) * 6)
    _, first, index = np.unique(skills, return_index=True, return_inverse=True)

    def read(forces: np.ndarray) -> np.ndarray:  # (B, H, 6); the sensor filters along time
        return np.swapaxes(tared.sense(np.swapaxes(forces, 0, 1).copy(), dt, rng), 0, 1)

    trials = np.asarray(F_obs, dtype=np.float64)
    demos = np.asarray(F_demo, dtype=np.float64)[first]  # one demo recording per skill
    out = np.empty((int(draws), len(trials)))
    for d in range(int(draws)):
        out[d] = task_loss(read(trials), read(demos)[index], from_step)
    return out


def skill_rows(L_true: np.ndarray, L_sensed: np.ndarray, skills: np.ndarray) -> list[dict[str, Any]]:
    """One row per skill with >= :data:`MIN_TRIALS` trials (see the module docstring for the keys)."""
    rows = []
    for skill in np.unique(skills):
        sel = np.flatnonzero(skills == skill)
        if sel.size < MIN_TRIALS:
            continue
        truth, sensed = L_true[sel], L_sensed[:, sel]
        pairs = [_pearson(sensed[d], sensed[d + 1]) for d in range(len(sensed) - 1)]
        rows.append({"skill": str(skill), "n": int(sel.size), "L_task_mean_N": float(truth.mean()),
                     "L_task_sd_N": float(truth.std()),
                     "label_noise_sd_N": float(np.sqrt(np.mean(sensed.var(axis=0)))),
                     "R_label_truth": float(np.nanmean([_pearson(s, truth) for s in sensed])),
                     "R_label_label": float(np.nanmean(pairs)) if pairs else float("nan")})
    return rows


def check_set(path: Path, split: str, domain: DomainSpec, draws: int, seed: int,
              task_from_s: float = 0.0) -> dict[str, Any]:
    """The per-skill rows of one split of one dataset file, and what produced them."""
    try:
        loaded = load_dataset(path, split=split)
    except (OSError, ValueError) as err:
        raise SensorCheckError(f"--sets {path}:{split}: {err}") from None
    stored = DomainSpec.resolve(loaded.attrs.get("domain", "nominal"))
    if stored.has_sensing_effects:
        raise SensorCheckError(f"--sets {path}:{split}: the dataset's domain {stored.name!r} already reads its "
                               "forces through a noisy sensor; this check needs noise-free forces (a nominal set)")
    try:
        from_step = task_window_start(task_from_s, loaded.control_hz, loaded.horizon)
    except ValueError as err:
        raise SensorCheckError(f"--sets {path}:{split}: {err}") from None
    F_obs, F_demo = loaded.arrays["F_obs"], loaded.arrays["F_demo"]
    L_true = np.asarray(task_loss(F_obs.astype(np.float64), F_demo.astype(np.float64), from_step))
    skills = np.asarray(loaded.demo_ids)
    L_sensed = sensed_task_losses(F_obs, F_demo, skills, domain, 1.0 / loaded.control_hz, draws,
                                  np.random.default_rng(seed), from_step)
    return {"dataset": str(path), "split": split, "n": int(len(L_true)), "skills": skill_rows(L_true, L_sensed, skills)}


def markdown(results: list[dict[str, Any]], header: str) -> str:
    lines = [header, "", "| set | skill | trials | L_task mean [N] | L_task sd [N] | label noise sd [N] | "
             "R: one reading vs truth | R: two readings |", "|---|---|---|---|---|---|---|---|"]
    for result in results:
        name = f"{Path(result['dataset']).stem}:{result['split']}"
        for row in result["skills"]:
            lines.append(f"| {name} | {row['skill']} | {row['n']} | {row['L_task_mean_N']:.4f} | "
                         f"{row['L_task_sd_N']:.4f} | {row['label_noise_sd_N']:.4f} | "
                         f"{row['R_label_truth']:.3f} | {row['R_label_label']:.3f} |")
    return "\n".join(lines)


def _parse_set(text: str) -> tuple[Path, str]:
    path, sep, split = text.rpartition(":")
    if not sep or not path or not split:
        raise SensorCheckError(f"--sets {text!r}: expected FILE.h5:SPLIT, e.g. data/test_line_fine.h5:test")
    return Path(path), split


def main(argv: list[str] | None = None) -> list[dict[str, Any]]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sets", nargs="+", required=True, help="FILE.h5:SPLIT of nominal (noise-free) datasets")
    parser.add_argument("--domain", default="realistic", help="the domain preset whose sensor reads the forces")
    parser.add_argument("--noise-scale", type=float, default=1.0,
                        help="multiply the domain's sensor noise, e.g. 0.25 for a sensor four times quieter")
    parser.add_argument("--draws", type=int, default=16, help="sensor readings per trajectory (>= 2)")
    parser.add_argument("--task-from-s", type=float, default=0.0, help="count L_task from this time [s] on")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None, help="write OUT.json and OUT.md")
    argv = sys.argv[1:] if argv is None else argv
    args = parser.parse_args(argv)
    try:
        if args.draws < 2:
            raise SensorCheckError(f"--draws {args.draws}: two readings at least are needed to compare them")
        if not (np.isfinite(args.noise_scale) and args.noise_scale >= 0):
            raise SensorCheckError(f"--noise-scale {args.noise_scale}: expected a finite number >= 0")
        preset = DomainSpec.resolve(args.domain)
        domain = replace(preset, ft_noise_std=tuple(args.noise_scale * v for v in preset.ft_noise_std))
        results = [check_set(*_parse_set(text), domain, args.draws, args.seed, args.task_from_s)
                   for text in args.sets]
    except (SensorCheckError, DomainSpecError) as err:
        parser.error(str(err))
    header = (f"Sensor of `{domain.name}` (force noise std {[round(v, 4) for v in domain.ft_noise_std[:3]]} N, low-pass "
              f"{domain.ft_lowpass_hz:g} Hz, tared), {args.draws} sessions, L_task from {args.task_from_s:g} s. "
              f"Command: `python -m studies.task_checks.sensor_check {' '.join(argv)}`")
    text = markdown(results, header)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        payload = {"domain": domain.to_dict(), "draws": args.draws, "seed": args.seed,
                   "task_from_s": args.task_from_s, "sets": results}
        args.out.with_suffix(".json").write_text(json.dumps(payload, indent=1) + "\n")
        args.out.with_suffix(".md").write_text(text + "\n")
    print(text)
    return results


if __name__ == "__main__":
    main()
