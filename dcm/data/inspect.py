"""Look into a dataset file: counts, split sizes, per-channel statistics, objective ranges, and plots.

    python -m dcm.data.inspect data/sim.h5                                  # summary
    python -m dcm.data.inspect data/sim.h5 --plot traj.png --traj traj_000007
    python -m dcm.data.inspect data/sim.h5 --demo-plot 0 --out docs/dataset_spiral_trials.png

``--demo-plot`` draws one demo and all its trials' forces coloured by their mean stiffness, which shows
how stiffness shapes the contact force (the data the contact model learns from).
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from dcm.console import print_error
from dcm.data.schema import CHANNELS, FIELDS, SPLITS, DatasetError, _decode_attr, load_dataset


def within_demo_spread(L_task: np.ndarray, demo_ids: np.ndarray) -> str:
    """How much stiffness moves L_task inside one demo: p90/p10 over its trials, median [range] over demos.

    The tuner ranks one demo's schedules, so a split whose demos barely vary says little about ranking."""
    ratios = []
    for demo in np.unique(demo_ids):
        lt = L_task[demo_ids == demo]
        lt = lt[np.isfinite(lt)]
        if lt.size >= 3:
            p10, p90 = np.percentile(lt, [10, 90])
            if p10 > 0:
                ratios.append(p90 / p10)
    if not ratios:
        return "–"
    return f"{np.median(ratios):.2f} [{min(ratios):.2f}–{max(ratios):.2f}]"


def force_step_change(wrench: np.ndarray) -> float:
    """Median over trajectories of the mean step-to-step change of the force vector (N, H, 6) -> N.

    A rough surface shows here: on a coarse bowl grid the tool crosses facet edges and the force jumps from step
    to step (studies/record.md, "The bowl's heightfield grid")."""
    steps = np.linalg.norm(np.diff(wrench[..., :3], axis=1), axis=-1)
    return float(np.median(steps.mean(axis=1)))


def approach_share(F_obs: np.ndarray, F_demo: np.ndarray, approach_steps: np.ndarray, demo_ids: np.ndarray
                   ) -> tuple[float, float]:
    """How much of L_task the demo's approach (descent and touch-down) decides, for trajectories (N, H, 6).

    Returns the median over trajectories of the share of the squared force error in each one's first
    ``approach_steps`` steps, and the median over demos (of >= 3 trials) of the within-demo Spearman between
    L_task and L_task after the approach: near 1, the approach does not change the ranking; near 0, the
    ranking is the touch-down's (studies/record.md, "The touch-down").
    """
    from scipy.stats import spearmanr

    err = ((np.asarray(F_obs, np.float64)[..., :3] - np.asarray(F_demo, np.float64)[..., :3]) ** 2).sum(-1)
    after = np.arange(err.shape[1])[None, :] >= np.asarray(approach_steps)[:, None]
    total = err.sum(1)
    share = np.where(total > 0, (err * ~after).sum(1) / np.where(total > 0, total, 1.0), 0.0)
    whole, wipe = np.sqrt(err.mean(1)), np.sqrt((err * after).sum(1) / np.maximum(after.sum(1), 1))
    rhos = [spearmanr(whole[sel], wipe[sel]).statistic for d in np.unique(demo_ids)
            if (sel := demo_ids == d).sum() >= 3 and np.ptp(whole[sel]) > 0 and np.ptp(wipe[sel]) > 0]
    return float(np.median(share)), float(np.median(rhos)) if rhos else float("nan")


def _packages(packages: dict[str, str] | None) -> str:
    if not packages:
        return "unrecorded package versions (a file from before they were recorded)"
    return ", ".join(f"{name} {v}" for name, v in packages.items())


def summarize(path: Path) -> str:
    """A human-readable summary; loading validates the file first, so a damaged file fails here."""
    everything = load_dataset(path, include_failed=True)
    attrs = everything.attrs
    failed = np.array([bool(m.get("failed", False)) for m in everything.meta])
    lines = [
        f"{path}",
        f"  format {attrs['format_version']}, dcm {attrs.get('dcm_version')}, created {attrs.get('created')}, "
        f"written with {_packages(attrs.get('packages'))}",
        f"  dataset {attrs.get('dataset', '?')}, embodiment {attrs.get('embodiment')}, "
        f"domain {(attrs.get('domain') or {}).get('name', attrs.get('domain'))}, search {attrs.get('search', '?')}",
        f"  control {everything.control_hz:g} Hz, horizon H={everything.horizon} "
        f"({everything.horizon / everything.control_hz:g} s)",
        f"  trajectories {len(everything)} ({int(failed.sum())} failed), demos {len(set(everything.demo_ids))}",
    ]
    with h5py.File(path, "r") as f:
        masks = {s: [n.decode() for n in f["mask"][s][()]] for s in f["mask"]}
    index = {name: i for i, name in enumerate(everything.names)}
    lines.append("  split     trajs  demos   L_task [N] min/median/max     L_comp [kN/m] min/median/max"
                 "   L_task p90/p10 in a demo")
    for split in [s for s in SPLITS if s in masks] + [s for s in masks if s not in SPLITS]:
        rows = [index[n] for n in masks[split] if n in index]
        if not rows:
            lines.append(f"  {split:<8} {0:>6}")
            continue
        lt, lc = everything.L_task[rows], everything.L_comp[rows]
        n_demos = len(set(everything.demo_ids[rows]))
        lines.append(f"  {split:<8} {len(rows):>6} {n_demos:>6}   "
                     f"{lt.min():7.3f} {np.median(lt):7.3f} {lt.max():7.3f}        "
                     f"{lc.min():7.3f} {np.median(lc):7.3f} {lc.max():7.3f}   "
                     f"{within_demo_spread(lt, everything.demo_ids[rows])}")
    ok = ~failed
    if ok.any():
        lines.append(f"  force step change, mean |dF| per control step over the force axes, median over trajectories: "
                     f"F_obs {force_step_change(everything.arrays['F_obs'][ok]):.3f} N, "
                     f"F_demo {force_step_change(everything.arrays['F_demo'][ok]):.3f} N")
        steps = np.array([round(float((m.get("demo") or {}).get("approach_s", 0.0)) * everything.control_hz)
                          for m in everything.meta])[ok]
        share, rho = approach_share(everything.arrays["F_obs"][ok], everything.arrays["F_demo"][ok], steps,
                                    everything.demo_ids[ok])
        lines.append(f"  the approach (each demo's approach_s): {share:.0%} of a trajectory's squared force error, "
                     f"median; within a demo, Spearman(L_task, L_task after the approach) {rho:.2f}, median")
    # group failure reasons by their wording (numbers masked), keep one full example each
    failures = [str(m.get("failure_reason", "")) for m, bad in zip(everything.meta, failed) if bad]
    kinds: dict[str, list[str]] = {}
    for reason in failures:
        kinds.setdefault(re.sub(r"[-+]?\d+(\.\d+)?", "#", reason), []).append(reason)
    for kind, examples in sorted(kinds.items()):
        lines.append(f"  failed: {len(examples)} x {kind!r}, e.g. {examples[0]!r}")
    lines.append(f"  per-channel statistics over {attrs.get('stats_split', 'train')} (min / max / mean / std):")
    for field in FIELDS:
        stats = everything.stats[field]
        for c, channel in enumerate(CHANNELS[field]):
            lines.append(f"    {field:<7} {channel:<11} {stats['min'][c]:10.4g} {stats['max'][c]:10.4g} "
                         f"{stats['mean'][c]:10.4g} {stats['std'][c]:10.4g}")
    return "\n".join(lines)


def _read_traj(f: h5py.File, name: str) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    if name not in f["data"]:
        raise DatasetError(f.filename, "no such trajectory", trajectory=name)
    group = f["data"][name]
    return {k: group[k][()] for k in FIELDS}, {k: _decode_attr(v) for k, v in group.attrs.items()}


def plot_trajectory(path: Path, out: Path, name: str | None = None) -> Path:
    """Pose, force, stiffness and contact of one trajectory against its demo."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with h5py.File(path, "r") as f:
        control_hz = float(f.attrs["control_hz"])
        name = name or sorted(f["data"].keys())[0]
        arrays, meta = _read_traj(f, name)
    t = np.arange(arrays["x_demo"].shape[0]) / control_hz
    fig, axes = plt.subplots(4, 1, figsize=(8, 9), sharex=True)
    for c, axis in enumerate("xyz"):
        color = f"C{c}"
        axes[0].plot(t, arrays["x_demo"][:, c] * 1e3, color=color, ls="--", label=f"{axis} demo")
        axes[0].plot(t, arrays["x_obs"][:, c] * 1e3, color=color, label=f"{axis} obs")
        axes[1].plot(t, arrays["F_demo"][:, c], color=color, ls="--", label=f"F{axis} demo")
        axes[1].plot(t, arrays["F_obs"][:, c], color=color, label=f"F{axis} obs")
        axes[2].plot(t, arrays["K"][:, c], color=color, label=f"K{axis}")
    axes[3].fill_between(t, arrays["contact"], step="mid", alpha=0.4)
    axes[0].set_ylabel("position [mm]")
    axes[1].set_ylabel("contact force [N]")
    axes[2].set_ylabel("stiffness [N/m]")
    axes[3].set_ylabel("contact")
    axes[3].set_xlabel("time [s]")
    for ax in axes[:3]:
        ax.legend(fontsize=7, ncol=3, loc="upper right")
        ax.grid(alpha=0.3)
    fig.suptitle(f"{path.name} {name}: demo {meta.get('demo_id')} trial {meta.get('trial')}, "
                 f"L_task={meta.get('L_task', float('nan')):.2f} N, L_comp={meta.get('L_comp', float('nan')):.2f} kN/m"
                 + (f" FAILED ({meta.get('failure_reason')})" if meta.get("failed") else ""), fontsize=9)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def plot_demo_trials(path: Path, demo_id: int, out: Path) -> Path:
    """One demo's path and every trial's normal/tangential force coloured by the trial's mean stiffness."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import cm, colors

    trials = []
    with h5py.File(path, "r") as f:
        control_hz = float(f.attrs["control_hz"])
        source = f"{_decode_attr(f.attrs.get('dataset', path.name))} dataset, {_decode_attr(f.attrs.get('embodiment'))}"
        for name in sorted(f["data"].keys()):
            if int(f["data"][name].attrs.get("demo_id", -1)) == demo_id:
                trials.append(_read_traj(f, name))
    if not trials:
        raise DatasetError(path, f"no trajectories with demo_id {demo_id}", field="demo_id")
    usable = [(a, m) for a, m in trials if not m.get("failed")]
    demo_arrays, demo_meta = trials[0]
    t = np.arange(demo_arrays["x_demo"].shape[0]) / control_hz
    mean_k = np.array([np.linalg.norm(a["K"][:, :3], axis=1).mean() for a, _ in usable])
    norm = colors.Normalize(vmin=mean_k.min(), vmax=mean_k.max() if mean_k.max() > mean_k.min() else mean_k.min() + 1)
    cmap = cm.viridis

    fig = plt.figure(figsize=(12, 7))
    grid = fig.add_gridspec(2, 3, hspace=0.35, wspace=0.3)
    ax_path = fig.add_subplot(grid[0, 0])
    ax_fz = fig.add_subplot(grid[0, 1:])
    ax_pareto = fig.add_subplot(grid[1, 0])
    ax_ft = fig.add_subplot(grid[1, 1:], sharex=ax_fz)
    x_demo = demo_arrays["x_demo"]
    ax_path.plot(x_demo[:, 0] * 1e3, x_demo[:, 1] * 1e3, "k-", lw=1.5)
    ax_path.plot(x_demo[0, 0] * 1e3, x_demo[0, 1] * 1e3, "ko")
    ax_path.set_aspect("equal")
    ax_path.set_xlabel("x [mm]")
    ax_path.set_ylabel("y [mm]")
    family = demo_meta.get("demo", {}).get("family", "demo") if isinstance(demo_meta.get("demo"), dict) else "demo"
    ax_path.set_title(f"{family} demo {demo_id} (top view)", fontsize=9)
    order = np.argsort(mean_k)
    for i in order:
        arrays, _ = usable[i]
        color = cmap(norm(mean_k[i]))
        ax_fz.plot(t, arrays["F_obs"][:, 2], color=color, lw=0.9, alpha=0.85)
        ax_ft.plot(t, np.linalg.norm(arrays["F_obs"][:, :2], axis=1), color=color, lw=0.9, alpha=0.85)
    ax_fz.plot(t, demo_arrays["F_demo"][:, 2], "r--", lw=2, label="F_demo")
    ax_ft.plot(t, np.linalg.norm(demo_arrays["F_demo"][:, :2], axis=1), "r--", lw=2, label="F_demo")
    ax_fz.set_ylabel("normal force F_z [N]")
    ax_ft.set_ylabel("tangential |F_xy| [N]")
    ax_ft.set_xlabel("time [s]")
    for ax in (ax_fz, ax_ft):
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    l_task = np.array([m["L_task"] for _, m in usable])
    l_comp = np.array([m["L_comp"] for _, m in usable])
    ax_pareto.scatter(l_comp, l_task, c=mean_k, cmap=cmap, norm=norm, edgecolors="k", linewidths=0.4)
    ax_pareto.set_xlabel("L_comp [kN/m]")
    ax_pareto.set_ylabel("L_task [N]")
    ax_pareto.set_title(f"{len(usable)} trials ({len(trials) - len(usable)} failed)", fontsize=9)
    ax_pareto.grid(alpha=0.3)
    bar = fig.colorbar(cm.ScalarMappable(norm=norm, cmap=cmap), ax=[ax_fz, ax_ft], pad=0.01)
    bar.set_label("mean |K_xyz| over the trial [N/m]")
    fig.suptitle(f"{source}: one demo and its {len(trials)} stiffness-search trials; colour = mean stiffness",
                 fontsize=10)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dcm.data.inspect", description=__doc__.split("\n")[0])
    parser.add_argument("file", type=Path)
    parser.add_argument("--plot", type=Path, help="PNG of one trajectory (the first, or --traj)")
    parser.add_argument("--traj", help="trajectory name for --plot, e.g. traj_000012")
    parser.add_argument("--demo-plot", type=int, metavar="DEMO_ID", help="plot a demo and all its trials")
    parser.add_argument("--out", type=Path, default=Path("demo_trials.png"), help="PNG for --demo-plot")
    args = parser.parse_args(argv)
    try:
        print(summarize(args.file))
        if args.plot:
            print(f"wrote {plot_trajectory(args.file, args.plot, args.traj)}")
        if args.demo_plot is not None:
            print(f"wrote {plot_demo_trials(args.file, args.demo_plot, args.out)}")
    except DatasetError as err:
        return print_error(err)
    return 0


if __name__ == "__main__":
    sys.exit(main())
