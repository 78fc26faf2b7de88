"""Acceptance of the shipped predictors on skills they never trained on: ``python -m studies.acceptance.acceptance``."""
