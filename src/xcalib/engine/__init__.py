"""Inference and training engine: ``Matcher`` (matcher.py), ``train`` (trainer.py), metrics,
checkpoints. Importing this package does not import torch; its modules do."""
