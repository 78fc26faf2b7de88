"""The lab: the studies behind the project's findings, their configs and reports.

Studies import :mod:`dcm`; the product never imports them, so a study may change or go without touching
what a user runs. Run a study from the repository root: ``python -m studies.<study>.<module>`` (README.md).
"""
