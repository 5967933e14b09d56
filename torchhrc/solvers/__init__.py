"""torchhrc.solvers."""
