"""Matching models: registry (``create_model``, ``list_models``, ``default_config``), backbones
and YAML configs. Importing this package imports torch."""

from . import calibrefine, crlite, fastmatch, vit_models  # noqa: F401  (register the models)
from .base import Embeddings, MatchingModel, TrainLogits
from .inputs import ModelBatch
from .registry import UnknownModelError, create_model, default_config, list_models, merge_config

__all__ = ["create_model", "list_models", "default_config", "merge_config", "UnknownModelError",
           "MatchingModel", "Embeddings", "TrainLogits", "ModelBatch"]
