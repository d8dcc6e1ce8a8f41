"""Model inputs and synthetic data: ``crops`` (per-detection model inputs), ``synth`` (generator)."""
