"""Validating an identified model on measured experiments: free run, k-step prediction and the
manoeuvre figures naval architects compare (overshoot angles, turning circles)."""
