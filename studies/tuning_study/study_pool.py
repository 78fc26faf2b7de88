"""Pool tuning studies of one skill that differ only in the trained predictors: one study per training seed.

    python -m studies.tuning_study.study_pool seed0=outputs/study/<a> seed1=outputs/study/<b> seed2=outputs/study/<c>
        [--subject dcm] [--out pool.md]

One study (``python -m studies.tuning_study.study``) compares tuners on ONE pair of checkpoints, so a DCM ahead
of the baseline there may be that checkpoint's luck. Whether the method is ahead needs the study repeated with
predictors trained from other seeds. This command takes such studies, keeps the tuning seeds they share, and
reports per training seed the median I_H of every tuner and the subject's paired test, then the subject
against each control over all (training seed, tuning seed) pairs. That pooled test holds the trained
checkpoints fixed; the training seeds themselves are few, so the per-seed rows say how far the result
carries over to a new training run.

``--versus LABEL=FOLDER ... [--versus-name NAME]`` adds, per label, a study of another design on the same
skill and training seed (the same checkpoints tuned otherwise, e.g. without a prior): its tuners join as
``<tuner> (NAME)``, paired with the subject by (label, tuning seed), so one table says whether the change of
design helps. Tuners whose values are the same in both designs (the prior, the robot-based search) join once.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

from studies.tuning_study.study_report import label
from studies.tuning_study.study_stats import aggregate


def load_study(folder: Path) -> dict:
    """A finished study's ``study.json``; a clear error when the folder holds none."""
    path = Path(folder) / "study.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no study.json "
                                f"(is {folder} a finished `python -m studies.tuning_study.study` run?)")
    return json.loads(path.read_text())


def _same_reference(name: str, study: Mapping, first_name: str, first: Mapping) -> None:
    """Studies of one skill share the reference point (a rollout at the demo's stiffness); others are refused."""
    ref, ref0 = study["reference_point"], first["reference_point"]
    for key in ("L_task_N", "L_comp_kNpm"):
        if not math.isclose(ref[key], ref0[key], rel_tol=1e-9):
            raise ValueError(f"{name}: reference point {key}={ref[key]:.6g} differs from {first_name}'s "
                             f"{ref0[key]:.6g}; pool studies of one skill (same demo, simulator and stiffness space)")


def seed_values(study: Mapping, tuner: str, seeds: Sequence[int]) -> list[float]:
    """I_H of ``tuner`` in a loaded ``study.json`` at each of ``seeds`` (all must be in the study); NaN for a
    failed run."""
    by_seed = dict(zip(study["seeds"], study["hypervolume"][tuner]))
    return [math.nan if by_seed[s] is None else float(by_seed[s]) for s in seeds]


def pool(studies: Mapping[str, Mapping], subject: str = "dcm", alpha: float = 0.05,
         versus: Mapping[str, Mapping] | None = None, versus_name: str = "other design") -> dict:
    """Per study and pooled: ``study_stats.aggregate`` of I_H over the shared tuning seeds (summaries per
    tuner, the subject's paired tests), and per control the number of studies whose subject median is above.

    ``studies`` maps a label (e.g. the training seed) to a loaded ``study.json``. Tuners missing from any study
    are left out; the subject must be in all of them. ``versus`` maps the same labels to studies of another
    design, whose tuners join each label's as ``<tuner> (versus_name)``.
    """
    if not studies:
        raise ValueError("study_pool: give at least one study")
    names = list(studies)
    versus = dict(versus or {})
    if versus and set(versus) != set(names):
        raise ValueError(f"study_pool: --versus needs one study per label {names}, got {list(versus)}")
    for name in names[1:]:
        _same_reference(name, studies[name], names[0], studies[names[0]])
    for name in versus:
        _same_reference(f"{name} ({versus_name})", versus[name], names[0], studies[names[0]])
    seeds = sorted(set.intersection(*(set(s["seeds"]) for s in [*studies.values(), *versus.values()])))
    if not seeds:
        raise ValueError("study_pool: the studies share no tuning seed (" +
                         "; ".join(f"{n}: {studies[n]['seeds']}" for n in names) + ")")
    tuners = [t for t in studies[names[0]]["tuners"] if all(t in s["tuners"] for s in studies.values())]
    if subject not in tuners:
        raise ValueError(f"study_pool: the subject tuner {subject!r} is not in every study (shared tuners: {tuners})")

    hv = {name: {t: seed_values(study, t, seeds) for t in tuners} for name, study in studies.items()}
    if versus:  # a tuner that repeats its values in both designs (a control such as the prior) joins once
        others = [t for t in versus[names[0]]["tuners"] if all(t in s["tuners"] for s in versus.values())
                  and not (t in tuners and all(hv[n][t] == seed_values(versus[n], t, seeds) for n in names))]
        for name in names:
            hv[name].update({f"{t} ({versus_name})": seed_values(versus[name], t, seeds) for t in others})
        tuners = tuners + [f"{t} ({versus_name})" for t in others]
    per_study = {name: aggregate(hv[name], subject, alpha) for name in names}
    pooled = aggregate({t: [x for name in names for x in hv[name][t]] for t in tuners}, subject, alpha)
    pooled["studies_ahead"] = {
        t: sum(per_study[n]["tuners"][subject]["median"] > per_study[n]["tuners"][t]["median"] for n in names)
        for t in tuners if t != subject}
    return {"subject": subject, "alpha": alpha, "seeds": seeds, "tuners": tuners, "studies": names,
            "per_study": per_study, "pooled": pooled}


def _label(tuner: str) -> str:
    """``label`` of a tuner, keeping the design a ``--versus`` tuner comes from: ``dcm (no prior)`` -> ``DCM (no prior)``."""
    base, sep, design = tuner.partition(" (")
    return label(base) + (f" ({design}" if sep else "")


def _p(test: Mapping) -> str:
    return "—" if test["p"] is None else f"{test['p']:.2g}"


def pool_table(report: Mapping) -> str:
    """Markdown: one row per study (median I_H per tuner; subject better/worse and p against each control),
    then the pooled row."""
    subject, tuners = report["subject"], report["tuners"]
    controls = [t for t in tuners if t != subject]
    n_seeds = len(report["seeds"])
    lines = [
        f"Median I_H over the {n_seeds} tuning seeds the studies share ({report['seeds'][0]}–{report['seeds'][-1]}); "
        f"in brackets {_label(subject)} better / worse of the seeds and the two-sided Wilcoxon p, paired by seed. "
        f"The pooled row pairs every (study, tuning seed); its last line counts the studies whose "
        f"{_label(subject)} median is above the control's.",
        "",
        "| study | " + " | ".join(_label(t) for t in [subject, *controls]) + " |",  # the subject first, as in the rows
        "|---|" + "---|" * len(tuners),
    ]

    def row(name: str, stats: Mapping) -> str:
        medians, tests = {t: stats["tuners"][t]["median"] for t in tuners}, stats["tests"]
        cells = [f"{medians[subject]:.3f}"]
        for t in controls:
            test = tests[t]
            cells.append(f"{medians[t]:.3f} ({test['wins']} / {test['losses']}, p = {_p(test)})")
        return f"| {name} | " + " | ".join(cells) + " |"

    for name in report["studies"]:
        lines.append(row(name, report["per_study"][name]))
    pooled = report["pooled"]
    lines.append(row(f"**pooled, {len(report['studies'])} × {n_seeds}**", pooled))
    lines.append(f"| {_label(subject)} median above, studies | – | "
                 + " | ".join(f"{pooled['studies_ahead'][t]} of {len(report['studies'])}" for t in controls) + " |")
    return "\n".join(lines) + "\n"


def parse_labelled(items: Sequence[str], form: str) -> dict[str, str]:
    """``LABEL=VALUE`` command-line items -> {label: value}; ``form`` says what an item should look like in the
    error for a malformed one. A label given twice is refused."""
    parsed: dict[str, str] = {}
    for item in items:
        label, sep, value = item.partition("=")
        if not sep or not label or not value:
            raise ValueError(f"{item!r}: give each {form}")
        if label in parsed:
            raise ValueError(f"{item!r}: label {label!r} given twice")
        parsed[label] = value
    return parsed


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("studies", nargs="+", help="LABEL=FOLDER of a finished study, one per training seed")
    parser.add_argument("--subject", default="dcm", help="the tuner tested against every other (default dcm)")
    parser.add_argument("--versus", nargs="+", default=[],
                        help="LABEL=FOLDER of a study of another design per label, paired with the subject")
    parser.add_argument("--versus-name", default="other design", help="what --versus tuners are called")
    parser.add_argument("--alpha", type=float, default=0.05)
    parser.add_argument("--out", type=Path, default=None, help="write the table here (and the numbers beside it as .json)")
    args = parser.parse_args(argv)
    try:
        folders = {name: Path(folder) for name, folder in
                   parse_labelled(args.studies, "study as LABEL=FOLDER (e.g. seed0=outputs/study/<run>)").items()}
        others = {name: Path(folder) for name, folder in
                  parse_labelled(args.versus, "--versus study as LABEL=FOLDER").items()}
        report = pool({name: load_study(folder) for name, folder in folders.items()}, args.subject, args.alpha,
                      {name: load_study(folder) for name, folder in others.items()}, args.versus_name)
    except (ValueError, OSError) as err:
        raise SystemExit(f"error: {err}") from None
    table = pool_table(report)
    print(table)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(table)
        report["folders"] = {name: str(folder) for name, folder in folders.items()}
        if others:
            report["versus"] = {"name": args.versus_name, "folders": {n: str(f) for n, f in others.items()}}
        args.out.with_suffix(".json").write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
