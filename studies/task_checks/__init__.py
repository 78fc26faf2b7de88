"""Checks of the task itself, with the simulator as oracle: what could any predictor gain?

    python -m studies.task_checks.task_check ...     # does the simulated task reward stiffness?
    python -m studies.task_checks.spread_check ...   # what is a model of the force distribution worth?
    python -m studies.task_checks.sensor_check ...   # could a robot's F/T sensor rank the schedules?
"""
