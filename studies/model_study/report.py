"""Write a collected study as study.md (tables and tests), study.png (metric vs setting) and study.json."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import yaml

from dcm.models.references import STIFFNESS_RIDGE
from studies.model_study.runs import reference_values
from studies.model_study.stats import ALPHA, p_text

LABELS = {"L_MSE": "L_MSE (normalised)", "force_rmse_N": "force RMSE [N]", "force_rmse_ratio_copy": "÷ copy-F_demo",
          "R_within": "R within skill", "R_within_spearman": "Spearman within", "R_pooled": "R pooled",
          "L_task_mae_N": "L_task MAE [N]"}
# the reference drawn beside each metric: force errors against copying F_demo, rankings against the ridge
REFERENCE_OF = {"force_rmse_N": "copy-F_demo", "force_rmse_ratio_copy": "copy-F_demo", "R_within": "stiffness-only ridge",
                "R_within_spearman": "stiffness-only ridge", "R_pooled": "stiffness-only ridge",
                "L_task_mae_N": "stiffness-only ridge"}


def _num(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


def _fmt(value: float, sign: str = "") -> str:
    """Three decimals; values below 0.01 (a normalised L_MSE) in three significant digits, so they stay visible."""
    return format(value, f"{sign}.3f") if value == 0 or abs(value) >= 0.01 else format(value, f"{sign}.2e")


def _cell_text(summary: dict[str, Any]) -> str:
    """mean ± std [min–max] over the seeds (one value when there is one seed)."""
    n, mean = summary["n"], _num(summary.get("mean"))
    if not n or mean is None:
        return "–"
    if n == 1:
        return _fmt(mean)
    return f"{_fmt(mean)} ± {_fmt(summary['std'])} [{_fmt(summary['min'])}–{_fmt(summary['max'])}]"


def markdown(study: dict[str, Any], report_command: str) -> str:
    """The study as Markdown: provenance, one table per split, the significance tests."""
    spec, metrics = study["study"], study["study"]["metrics"]
    lines = [f"# {spec['title'] or spec['name']}", "",
             f"Sweep `{study['sweep_dir']}`: {sum(c['n_seeds'] for c in study['cells'])} scored runs in "
             f"{len(study['cells'])} settings, on `{study['dataset']}`.", "",
             f"- Runs (config: `studies/conf/experiment/{spec['name']}.yaml`; every run's resolved config is its "
             "`config.yaml`), one command per setting:",
             *[f"  - {c['label'] or 'default'}: `{c['command']}`" for c in study["cells"] if c.get("command")],
             f"- Report: `{report_command}`.",
             f"- Evaluations ran on: {study['machine']}.",
             "- Cells: mean ± std [min–max] over the n seeds of each setting; each run scored with its checkpoint "
             "selected on the experiment's `checkpoint.monitor`. References on the same trajectories: copy-F_demo "
             "and the stiffness-only ridge fitted on the dataset's train split."]
    if spec.get("evaluate_init"):
        lines.append("- `stage=pretrain` rows: the runs' `init_from` checkpoints scored as they are (no fine-tuning); "
                     "n counts distinct checkpoints.")
    if any(c["values"].get("model") == STIFFNESS_RIDGE for c in study["cells"]):
        lines.append(f"- `model={STIFFNESS_RIDGE}` rows: the stiffness-only ridge fitted on each run's own training "
                     "subset (the same usage rate and seed), so it sees exactly the data the models saw.")
    if study["unfinished"]:
        lines.append(f"- Left out, unfinished (no summary.json): {', '.join(f'`{p}`' for p in study['unfinished'])}.")
    for split, info in study["splits"].items():
        lines += ["", f"## {split} ({info['n']} trajectories, {info['n_skills']} skill(s))", "",
                  "| setting | n | " + " | ".join(LABELS.get(m, m) for m in metrics) + " |",
                  "|---|---|" + "---|" * len(metrics)]
        for cell in study["cells"]:
            summary = cell["summary"][split]
            lines.append(f"| {cell['label']} | {cell['n_seeds']} | "
                         + " | ".join(_cell_text(summary[m]) for m in metrics) + " |")
        for name, ref in study["references"].get(split, {}).items():
            values = [_fmt(ref[m]) if _num(ref.get(m)) is not None else "–" for m in metrics]
            lines.append(f"| {name} | – | " + " | ".join(values) + " |")
    if study["tests"]:
        lines += ["", f"## Significance (Welch's t-test, two-sided; bold: p < {ALPHA})", "",
                  "| split | metric | setting | against | mean − mean against | n / n against | t | p |",
                  "|---|---|---|---|---|---|---|---|"]
        for t in study["tests"]:
            diff, stat = _num(t["difference"]), _num(t["t"])
            lines.append(f"| {t['split']} | {t['metric']} | {t['cell']} | {t['against']} | "
                         f"{'–' if diff is None else _fmt(diff, '+')} | {t['n']} / {t['n_against']} | "
                         f"{'–' if stat is None else format(stat, '.2f')} | {p_text(t['p'])} |")
    common = study["common_config"]
    lines += ["", "<details><summary>Resolved config shared by every run</summary>", "", "```yaml",
              yaml.safe_dump(common, sort_keys=True, width=120).rstrip(), "```", "", "</details>", ""]
    return "\n".join(lines)


def _x_values(cells: list[dict[str, Any]], spec: dict[str, Any]) -> tuple[list[Any], bool]:
    """The distinct x values in cell order (the x comparison's reference first), and whether all are numbers."""
    key = spec["x"]
    xs = list(dict.fromkeys(c["values"][key] for c in cells))
    against = reference_values(spec.get("comparisons") or ()).get(key)
    xs.sort(key=lambda x: against is None or str(x) != str(against))  # stable: the rest keep their order
    numeric = all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in xs)
    return xs, numeric


def figure(study: dict[str, Any], path: Path) -> None:
    """Metric vs the swept value, one line per series, error bars = std over seeds, references dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    spec, cells, metrics, splits = study["study"], study["cells"], study["study"]["metrics"], list(study["splits"])
    xs, numeric = _x_values(cells, spec)
    series = list(dict.fromkeys(c["values"].get(spec["series"]) if spec["series"] else None for c in cells))
    fig, axes = plt.subplots(len(splits), len(metrics), figsize=(3.6 * len(metrics), 3.0 * len(splits)),
                             squeeze=False)
    for row, split in enumerate(splits):
        for col, metric in enumerate(metrics):
            ax = axes[row][col]
            for s_index, name in enumerate(series):
                members = [c for c in cells if not spec["series"] or c["values"].get(spec["series"]) == name]
                points = [(c["values"][spec["x"]], c["summary"][split][metric]) for c in members]
                points = [(x, s) for x, s in points if _num(s["mean"]) is not None]
                # a line in axis order, whatever the cell order (the compared-against cell comes first)
                points.sort(key=lambda point: point[0] if numeric else xs.index(point[0]))
                if not points:
                    continue
                pos = [x if numeric else xs.index(x) + 0.08 * s_index for x, _ in points]
                ax.errorbar(pos, [s["mean"] for _, s in points],
                            yerr=[0.0 if _num(s["std"]) is None else s["std"] for _, s in points],
                            marker="o", capsize=3, label=str(name) if spec["series"] else None)
            ref_name = REFERENCE_OF.get(metric)
            ref = _num(study["references"].get(split, {}).get(ref_name, {}).get(metric)) if ref_name else None
            if ref is not None:
                ax.axhline(ref, color="grey", linestyle="--", linewidth=1, label=ref_name)
            if numeric and spec.get("log_x"):
                ax.set_xscale("log")
                ax.minorticks_off()
            ax.set_xticks(xs if numeric else range(len(xs)), [str(x) for x in xs], rotation=0 if numeric else 30)
            ax.set_title(f"{split}: {LABELS.get(metric, metric)}", fontsize=9)
            ax.set_xlabel(spec["x"], fontsize=8)
            if ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=7)
    fig.suptitle(f"{spec['title'] or spec['name']} (mean ± std over seeds)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write(study: dict[str, Any], out_dir: Path, report_command: str) -> dict[str, Path]:
    """study.md, study.png and study.json in ``out_dir``; returns their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"md": out_dir / "study.md", "png": out_dir / "study.png", "json": out_dir / "study.json"}
    paths["md"].write_text(markdown(study, report_command))
    figure(study, paths["png"])
    paths["json"].write_text(json.dumps({**study, "report_command": report_command}, indent=1, default=str) + "\n")
    return paths
