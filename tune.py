"""Robot-free stiffness tuning of a new skill: `python tune.py ckpt=<model.ckpt> [demo=wavelike] [k=v ...]`.

The entry lives in dcm/tuning/cli.py (also the console script `dcm-tune`); conf/tune.yaml lists every option.
"""

from dcm.tuning.cli import main

if __name__ == "__main__":
    main()
