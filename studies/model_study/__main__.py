"""CLI: ``python -m studies.model_study <sweep_dir> [--out <folder>] [--splits valid test]``."""

from __future__ import annotations

import argparse
import logging
import shlex
import sys
from pathlib import Path

from studies.model_study import REPORTS
from studies.model_study.collect import SPLITS, collect
from studies.model_study.report import write


def main(argv: list[str] | None = None) -> dict[str, Path]:
    """Collect the sweep, write the report; a user error ends in one ``error: ...`` line and exit code 2."""
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(prog="python -m studies.model_study", description=__doc__)
    parser.add_argument("sweep_dir", type=Path, help="hydra.sweep.dir of the study, e.g. outputs/studies/usage_rate")
    parser.add_argument("--out", type=Path, default=None,
                        help="report folder (default: studies/model_study/reports/study_<name>)")
    parser.add_argument("--splits", nargs="+", default=list(SPLITS), help="splits to score (those the file has)")
    args = parser.parse_args(argv)
    try:
        study = collect(args.sweep_dir, tuple(args.splits))
    except (ValueError, FileNotFoundError) as err:  # StudyError, DatasetError, CheckpointKindError, a lost checkpoint
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    out = args.out or REPORTS / f"study_{study['study']['name']}"
    paths = write(study, out, "python -m studies.model_study " + " ".join(shlex.quote(a) for a in argv))
    print(f"wrote {paths['md']}, {paths['png']}, {paths['json']}")
    return paths


if __name__ == "__main__":
    main()
