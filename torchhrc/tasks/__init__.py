"""torchhrc.tasks."""
