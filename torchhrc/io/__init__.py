"""torchhrc.io."""
