"""What a study writes: the box plot of I_H over seeds (the paper's Fig. 10), ``study.md`` and ``cost.md``."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

FIXED_LABELS = {"dcm": "DCM", "baseline": "baseline", "reference": "stiffness reference", "prior": "prior"}


def label(tuner: str) -> str:
    """Display name: ``robot_based_20`` -> ``robot-based N=20``."""
    if tuner.startswith("robot_based_"):
        return f"robot-based N={tuner.rsplit('_', 1)[1]}"
    return FIXED_LABELS.get(tuner, tuner)


def _stars(p: float | None) -> str:
    if p is None:
        return "n/a"
    return "***" if p < 0.001 else "**" if p < 0.01 else "*" if p < 0.05 else "n.s."


def box_plot(path: Path, results: Mapping[str, Sequence[float]], stats: Mapping[str, Any], title: str) -> None:
    """One box of I_H over seeds per tuner, every seed as a dot, and the DCM's paired test above each control."""
    names = list(results)
    fig, ax = plt.subplots(figsize=(1.2 * len(names) + 2.0, 4.2))
    data = [[v for v in results[n] if v is not None and math.isfinite(v)] for n in names]
    ax.boxplot(data, widths=0.55, showfliers=False, medianprops={"color": "k"})
    rng = np.random.default_rng(0)  # jitter only
    for i, values in enumerate(data, start=1):
        color = "tab:blue" if names[i - 1] == stats["subject"] else "tab:orange" if names[i - 1].startswith(
            "robot_based") else "tab:gray"
        ax.scatter(i + rng.uniform(-0.12, 0.12, len(values)), values, s=12, c=color, alpha=0.8, zorder=3)
    for i, name in enumerate(names, start=1):  # the test's verdict just above the axes, over each control
        test = stats["tests"].get(name)
        if test is not None:
            ax.text(i, 1.01, _stars(test["p"]), transform=ax.get_xaxis_transform(), ha="center", va="bottom",
                    fontsize=8)
    ax.set_xticks(range(1, len(names) + 1), [label(n) for n in names], rotation=20, ha="right", fontsize=8)
    ax.set_ylabel("hypervolume I_H (one fixed reference point)")
    ax.set_title(title, fontsize=9, pad=16)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _num(value: float | None, digits: int = 4) -> str:
    return "—" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}g}"


def study_table(stats: Mapping[str, Any], robot_trials: Mapping[str, int], reference: Mapping[str, Any],
                n_seeds: int, landscape: Mapping[str, Any] | None = None, rollouts: int = 1) -> str:
    """Markdown: per tuner the robot trials, median and IQR of I_H, and the DCM's paired test against it; then
    how much stiffness moves the skill's L_task (``study_stats.landscape``), which bounds what ranking can win."""
    subject = stats["subject"]
    lines = [
        f"I_H over {n_seeds} seeds against one fixed reference point (L_task {reference['L_task_N']:.4g} N, "
        f"L_comp {reference['L_comp_kNpm']:.4g} kN/m). Tests: two-sided Wilcoxon signed-rank, "
        f"{label(subject)} vs each control, paired by seed, alpha = {stats['alpha']}."
        + (f" Every solution, the robot-based fronts' picks included, is judged by its mean L_task over {rollouts} "
           "rollouts (the expected loss); the robot trials column counts the tuner's own trials." if rollouts > 1
           else ""),
        "",
        f"| tuner | robot trials | median I_H | IQR [Q1, Q3] | {label(subject)} − tuner, median | "
        f"{label(subject)} better / worse / tied | p |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, summary in stats["tuners"].items():
        test = stats["tests"].get(name)
        cells = [label(name), str(robot_trials.get(name, "")), _num(summary["median"]),
                 f"{_num(summary['iqr'])} [{_num(summary['q1'])}, {_num(summary['q3'])}]"]
        if test is None:
            cells += ["", "", ""]
        else:
            p = "—" if test["p"] is None else f"{test['p']:.3g}" + (" (significant)" if test["significant"] else "")
            cells += [_num(test["median_difference"]), f"{test['wins']} / {test['losses']} / {test['ties']}", p]
        lines.append("| " + " | ".join(cells) + " |")
    if landscape:
        lines += ["", f"What stiffness does to this skill, over the {landscape['n_trials']} robot-based trials of all "
                  f"seeds: L_task 10 / 50 / 90 % = {_num(landscape['q10'], 3)} / {_num(landscape['median'], 3)} / "
                  f"{_num(landscape['q90'], 3)} N (q90 / q10 = {_num(landscape['spread_q90_q10'], 3)}), Spearman "
                  f"rho(L_task, mean K) = {_num(landscape['spearman_mean_K'], 2)}. The narrower this spread, the more "
                  "the front is set by L_comp, which every tuner computes exactly, and the less a better ranking of "
                  "L_task can gain."]
    return "\n".join(lines) + "\n"


def _duration(seconds: float | None) -> str:
    if seconds is None or (isinstance(seconds, float) and math.isnan(seconds)):
        return "—"
    if seconds < 120:
        return f"{seconds:.1f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.2f} h"


def cost_table(costs: Mapping[str, Mapping[str, float]], minutes_per_trial: float) -> str:
    """The paper's Table I: optimisation, validation and total time of each tuner.

    ``costs[tuner]`` holds ``opt_trials``, ``opt_virtual`` (bool: the trials are model predictions),
    ``opt_seconds`` (measured), ``validation_trials`` and ``validation_seconds`` (measured, simulator): medians
    over seeds. On a robot, every real trial costs ``minutes_per_trial``; virtual trials cost their measured time.
    """
    robot_s = 60.0 * minutes_per_trial
    lines = [
        f"Time per tuning run: medians over seeds. \"robot\": every real trial at {minutes_per_trial:g} min (the "
        "paper's), virtual trials at their measured model time; \"simulator\": as measured here.",
        "",
        "| tuner | optimisation | optimisation time (robot / simulator) | validation | "
        "validation time (robot / simulator) | total (robot / simulator) |",
        "|---|---|---|---|---|---|",
    ]
    for name, c in costs.items():
        virtual = bool(c.get("opt_virtual", False))
        n_opt, n_val = int(c.get("opt_trials", 0)), int(c.get("validation_trials", 0))
        opt_sim, val_sim = float(c.get("opt_seconds", 0.0)), float(c.get("validation_seconds", 0.0))
        opt_robot = opt_sim if virtual else n_opt * robot_s
        val_robot = n_val * robot_s
        what_opt = "—" if n_opt == 0 else f"{n_opt:,} {'virtual' if virtual else 'robot'} trials"
        what_val = "—" if n_val == 0 else f"{n_val} robot trials"
        lines.append(
            f"| {label(name)} | {what_opt} | {_duration(opt_robot)} / {_duration(opt_sim)} | {what_val} | "
            f"{_duration(val_robot)} / {_duration(val_sim)} | {_duration(opt_robot + val_robot)} / "
            f"{_duration(opt_sim + val_sim)} |")
    return "\n".join(lines) + "\n"
