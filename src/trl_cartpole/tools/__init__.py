"""Tools over many runs: comparisons of runs, Optuna tuning, sweeps."""
