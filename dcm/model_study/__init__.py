"""Reports of the paper's model studies, each a Hydra experiment run as one sweep (conf/experiment/):

    python train.py -m +experiment=diffusion_steps       # usage_rate, realistic, ablation_net, ablation_schedule
    python -m dcm.model_study outputs/studies/diffusion_steps --out reports/study_diffusion_steps

The report scores every finished run's selected checkpoint on the valid and test splits of its dataset
(cached in the run), aggregates over seeds, tests the differences the paper claims (Welch's t-test) and
writes study.md, study.png and study.json. Re-running either command only computes what is missing.
"""
