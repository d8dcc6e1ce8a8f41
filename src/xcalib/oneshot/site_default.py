"""A calibrated site's default matching path, decided without labels during bootstrap.

Issue 17: if the adapted model cannot beat geometry at a calibrated site, ``match``'s default
there is geometry. Bootstrap measures, on the held-out buffer frames (the same every-k-th-frame
rule as ``adapt``'s held-out split), how far the adapted model's own matches
(``geometry="off"``, no fusion) agree with the pose-only matches (``derive_matches``: the 3D
boxes projected with the site pose, one-to-one by IoU). The pose-only matches are the reference,
so they agree with themselves at 1.00; the model beats them only when it reproduces them exactly
(Top-1, precision and recall all 1.00), and otherwise the default is ``"geometry"``. The choice
is saved in the model config (``site_default``, beside the site weights); ``match(geometry=
"auto")`` then projects through the site calibration, ``geometry="off"`` keeps the model (fused
with the calibration unless ``use_calibration=False``), and ``use_calibration=True`` fuses.
On A9 (bootstrap on frames 0-11): adapted model 0.87 / 0.81 / 0.87 Top-1 / precision / recall
vs pose 1.00 / 1.00 / 1.00 on frames 12-15 (``benchmarks/bench_matching_sites.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Sequence

__all__ = ["SiteDefault", "choose_site_default"]


@dataclass(frozen=True)
class SiteDefault:
    """The default ``source`` of ``match`` at the site and the evidence: the adapted model's
    matches against the pose-only matches on ``n_frames`` held-out frames (``n_pose`` pose pairs)."""

    source: Literal["geometry", "fused"]
    model_top1: float
    model_precision: float
    model_recall: float
    pose_top1: float
    pose_precision: float
    pose_recall: float
    n_frames: int
    n_pose: int


def choose_site_default(matcher, frames, calibration, *, holdout: float = 0.2,
                        held: Sequence[int] | None = None) -> SiteDefault | None:
    """Model-only vs pose-only agreement on the held-out ``frames`` (None without pose pairs):
    ``held`` (indices into ``frames``, e.g. adapt's held-out frames), else the ``holdout_split``."""
    from ..calib.matching import derive_matches
    from .adapt import holdout_split

    frames = list(frames)
    if held is None:
        _, held = holdout_split(len(frames), holdout) if holdout > 0 and len(frames) > 1 else ([], [])
    held = list(held) or list(range(len(frames)))
    n_pose = n_model = hit = top_hit = n_rows = 0
    for k in held:
        f = frames[int(k)]
        pose = {(int(i), int(j)) for i, j in derive_matches(f, calibration).pairs}
        r = matcher.match_frame(f, validate="off", geometry="off", use_calibration=False)
        model = {(int(i), int(j)) for i, j, _ in r.matches}
        n_pose, n_model, hit = n_pose + len(pose), n_model + len(model), hit + len(pose & model)
        best = {int(i): int(j) for i, j, _ in r.matches}
        top_hit += sum(best.get(i) == j for i, j in pose)
        n_rows += len(pose)
    if n_pose == 0:
        return None
    top1, prec, rec = top_hit / n_rows, (hit / n_model if n_model else 0.0), hit / n_pose
    beats = min(top1, prec, rec) >= 1.0  # the pose agrees with itself at 1.0: the model must reproduce it
    return SiteDefault(source="fused" if beats else "geometry", model_top1=float(top1), model_precision=float(prec),
                       model_recall=float(rec), pose_top1=1.0, pose_precision=1.0, pose_recall=1.0,
                       n_frames=len(held), n_pose=n_pose)
