"""Training: train.py's logic and the run-directory format it owns."""
