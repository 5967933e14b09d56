"""torchhrc.experiments."""
