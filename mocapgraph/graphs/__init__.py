"""Building factor graphs and initial values from captures; batch (LM) and incremental solvers."""
