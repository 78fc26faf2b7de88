"""Robot-free stiffness tuning: a force model replaces robot trials in multi-objective optimisation."""
