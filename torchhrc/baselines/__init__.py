"""torchhrc.baselines."""
