"""Reports of the paper's model studies, each a Hydra experiment run as one sweep (studies/conf/experiment/):

    python train.py -m --config-dir studies/conf +experiment=diffusion_steps   # or usage_rate, realistic, ...
    python -m studies.model_study outputs/studies/diffusion_steps               # -> reports/study_diffusion_steps

The report scores every finished run's selected checkpoint on the valid and test splits of its dataset
(cached in the run), aggregates over seeds, tests the differences the paper claims (Welch's t-test) and
writes study.md, study.png and study.json. Re-running either command only computes what is missing.
``python -m studies.model_study.model_table`` puts chosen runs side by side on any dataset split.
"""

from pathlib import Path

REPORTS = Path(__file__).resolve().parent / "reports"  # where this study's reports live
