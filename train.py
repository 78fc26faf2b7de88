"""Train a force model (the DCM or the single-pass baseline); settings in conf/train.yaml.

    python train.py                                       # the shipped DCM's recipe on dataset=diverse_contact
    python train.py model=baseline                        # the shipped baseline's recipe
    python train.py dataset=tiny trainer=fast             # a smoke run on the tiny preset
    python train.py data.path=/abs/logs.h5                # an existing file (e.g. imported robot logs)
    python train.py -m model.diffusion_steps=1,5,10,30 seed=0,1,2      # sweep: one run dir per job
    python train.py stage=finetune init_from=<ckpt> dataset=realistic checkpoint.monitor=val/R_pooled
    python train.py resume=<run_dir>                      # continue a killed run from its checkpoints/last.ckpt
    python train.py resume=<run_dir> trainer.max_epochs=400   # ... or extend it (key=value overrides apply)
    python train.py --config-dir studies/conf dataset=diverse_contact_fine   # a research preset
    python train.py -m hydra/launcher=joblib hydra.launcher.n_jobs=4 seed=0,1,2,3   # runs in parallel

A preset's own file (data/<name>.h5) is generated first if it is absent; a data.path you name must exist.
Each run directory holds config.yaml, summary.json, checkpoints/ (top-k on checkpoint.monitor + last.ckpt)
and tb/ (TensorBoard): see dcm/training/run_dir.py. The logic is dcm.training.train; this is dcm-train.
"""

from dcm.training.cli import main

if __name__ == "__main__":
    main()
