"""torchhrc.sim."""
