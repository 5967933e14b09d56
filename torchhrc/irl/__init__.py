"""torchhrc.irl."""
