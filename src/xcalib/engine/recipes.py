"""Training recipes (optimisation defaults of ``xcalib.train``); torch-free so the CLI can read
them without importing torch."""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any, Literal

__all__ = ["Recipe", "REFERENCE_RECIPE", "XCALIB_RECIPE"]


@dataclass(frozen=True)
class Recipe:
    """Optimisation defaults of :func:`train`. :data:`REFERENCE_RECIPE` (the reference package's
    defaults) is what ``xcalib.train`` uses when nothing is passed; :data:`XCALIB_RECIPE` (the
    paper's from-scratch recipe: Adam, 5 warm-up epochs, cosine, 100 epochs) is what
    ``xcalib train`` (the CLI) and ``scripts/train_weights.py`` use."""

    epochs: int
    lr: float
    weight_decay: float
    optimizer: Literal["adam", "adamw"]
    warmup_epochs: float
    scheduler: Literal["cosine", "none"]
    min_lr: float
    label_smoothing: float

    def kwargs(self, **over: Any) -> dict[str, Any]:
        """Keyword arguments of :func:`train` (``over`` replaces fields)."""
        return asdict(replace(self, **over))


REFERENCE_RECIPE = Recipe(epochs=10, lr=1e-4, weight_decay=1e-4, optimizer="adamw", warmup_epochs=0,
                          scheduler="none", min_lr=1e-5, label_smoothing=0.05)
XCALIB_RECIPE = Recipe(epochs=100, lr=1e-3, weight_decay=0.0, optimizer="adam", warmup_epochs=5,
                       scheduler="cosine", min_lr=1e-6, label_smoothing=0.0)
