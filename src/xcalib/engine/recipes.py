"""Training recipes (optimisation defaults of ``xcalib.train``); torch-free so the CLI can read
them without importing torch."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any, Literal, Mapping

from ..options import Options, resolve

__all__ = ["Recipe", "REFERENCE_RECIPE", "XCALIB_RECIPE", "TrainOptions"]


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


_R = REFERENCE_RECIPE


@dataclass(frozen=True)
class TrainOptions(Options):
    """Every setting of :func:`xcalib.train` with its default (the optimisation fields default to
    :data:`REFERENCE_RECIPE`'s; :meth:`from_recipe` takes another recipe whole). ``train`` takes one
    (``options=``) and/or the same names as keyword arguments.

    model_name: must agree with the model's name when given. config: model config merged over the
    model's defaults (a registered name only). site: without ``config``, the config of that site's
    weights of this model (when there are some). temperature / stage1_weight / stage2_weight: None
    = the model config's values. label_smoothing: of the row/column cross-entropy.
    pairwise_batch_size: accepted for the reference's API; no effect (all N x M pairs of a batch
    are scored at once). weights: warm start (strict). frames_per_batch: frames per step (scores
    across frames are masked). grad_clip: gradient-norm clip. resume: ``last.pt`` path, or True for
    ``output_dir/last.pt``. box_jitter: training-time box perturbation (fraction of box size).
    max_3d: negative sampling (3D boxes per frame; None keeps all). weights_dtype: of ``best.pth``.
    """

    model_name: str | None = None
    config: Mapping[str, Any] | None = None
    site: str | None = None
    epochs: int = _R.epochs
    lr: float = _R.lr
    weight_decay: float = _R.weight_decay
    optimizer: str = _R.optimizer
    warmup_epochs: float = _R.warmup_epochs
    scheduler: str = _R.scheduler
    min_lr: float = _R.min_lr
    temperature: float | None = None
    label_smoothing: float = _R.label_smoothing
    stage1_weight: float | None = None
    stage2_weight: float | None = None
    weights: str | Path | None = None
    output_dir: str | Path = "runs/train"
    device: Any = "auto"  # str ("auto", "cpu", "cuda:0") or torch.device
    seed: int = 42
    limit_train_frames: int | None = None
    limit_val_frames: int | None = None
    pairwise_batch_size: int = 64
    frames_per_batch: int = 4
    grad_clip: float = 5.0
    resume: str | Path | bool | None = None
    progress: bool = True
    weights_dtype: str = "float32"
    box_jitter: float = 0.02
    max_3d: int | None = None

    @classmethod
    def from_recipe(cls, recipe: Recipe, **overrides: Any) -> "TrainOptions":
        """The defaults with ``recipe``'s optimisation settings, then ``overrides``."""
        return resolve(cls, cls(**{f.name: getattr(recipe, f.name) for f in fields(Recipe)}), overrides,
                       where="TrainOptions.from_recipe")

    @property
    def recipe(self) -> Recipe:
        """The optimisation settings as a :class:`Recipe`."""
        return Recipe(**{f.name: getattr(self, f.name) for f in fields(Recipe)})
