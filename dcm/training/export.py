"""Export a train.py run as a slim, self-describing checkpoint to ship (its format: dcm.models.checkpoint).

    python -m dcm.training.export outputs/train/<run> --out my_dcm.ckpt     # or: <run> my_dcm.ckpt

The export loads the run's selected checkpoint with this code (strict parameter names), so the stamped
``dcm_version`` is one that is known to load it, and stores a card (``dcm_card``): the dataset and its plan
fingerprint, the training overrides and config, and the run's metrics (:func:`dcm.training.run_dir.run_card`).
:func:`dcm.models.checkpoint.checkpoint_card` reads it back without building the model.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dcm.console import print_error
from dcm.models.checkpoint import export_checkpoint
from dcm.models.configuration import ModelInputError
from dcm.models.predict import load_model
from dcm.training.run_dir import run_card, run_checkpoint


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("source", type=Path, help="a train.py run directory (its selected checkpoint) or a .ckpt")
    parser.add_argument("out", type=Path, nargs="?", help="the slim checkpoint to write (or --out)")
    parser.add_argument("--out", dest="out_option", type=Path, metavar="OUT", help="the slim checkpoint to write")
    parser.add_argument("--name", help="a short name stored in the card (e.g. dcm_sim)")
    args = parser.parse_args(argv)
    if (args.out is None) == (args.out_option is None):
        parser.error("give the checkpoint to write once: OUT or --out OUT")
    target = args.out or args.out_option
    try:
        source, card = args.source, {"name": args.name or target.stem}
        if source.is_dir():
            card, source = {**run_card(source), **card}, run_checkpoint(source)
        out = export_checkpoint(source, target, card, verify=load_model)
    except (ModelInputError, OSError) as err:
        return print_error(err)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
