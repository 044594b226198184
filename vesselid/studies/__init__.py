"""Studies built from the layers below: Monte Carlo, the paper's tables, calibration, sea trials,
the trial planner, standard manoeuvres and their figures."""
