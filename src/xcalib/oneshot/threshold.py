"""A site's match threshold, chosen without labels during bootstrap.

``match``'s default assignment gives every camera box its best LiDAR box, also when it has none
(a far object, a box the LiDAR detector missed): at a site, the matches' precision then falls
to the share of 2D boxes that have a partner. The threshold below which a score means "no
partner" depends on the model and the site, so bootstrap chooses it from its own pseudo-labels
(the matches the site pose implies, ``derive_matches``): the smallest score threshold at which
the default matches of the adapted matcher agree with the pseudo-labels at ``TARGET_PRECISION``
or better (else the one with the best F1). It is saved in the model config
(``match_threshold``, beside the site weights) and ``match`` uses it when no
``match_threshold`` is given.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ThresholdChoice", "choose_threshold", "TARGET_PRECISION"]

TARGET_PRECISION = 0.97
CANDIDATES = tuple(np.round(np.arange(0.05, 0.96, 0.05), 2))


@dataclass(frozen=True)
class ThresholdChoice:
    """The chosen ``threshold`` and, at it, the default matches' ``precision`` / ``recall``
    against the pseudo-labels of ``n_frames`` frames (``n_pseudo`` pseudo-labelled pairs)."""

    threshold: float
    precision: float
    recall: float
    n_frames: int
    n_pseudo: int


def choose_threshold(matcher, frames, calibration, *, target: float = TARGET_PRECISION) -> ThresholdChoice | None:
    """Label-free threshold for ``matcher``'s default ``match`` (see the module docstring); None
    without pseudo-labelled pairs."""
    from ..calib.matching import derive_matches

    scored, pseudo = [], set()
    for k, f in enumerate(frames):
        r = matcher.match_frame(f, validate="off", match_threshold=-np.inf, geometry="off")
        scored += [(k, i, j, s) for i, j, s in r.matches]
        pseudo |= {(k, int(i), int(j)) for i, j in derive_matches(f, calibration).pairs}
    if not pseudo or not scored:
        return None
    keys = np.array([(k, i, j) in pseudo for k, i, j, _ in scored])
    s = np.array([x[3] for x in scored])
    rows = []
    for t in CANDIDATES:
        sel = s >= t
        n, hit = int(sel.sum()), int((sel & keys).sum())
        p, rec = (hit / n if n else 1.0), hit / len(pseudo)
        rows.append((float(t), p, rec, 2 * p * rec / (p + rec) if p + rec else 0.0))
    ok = [r for r in rows if r[1] >= target and r[2] > 0]
    t, p, rec, _ = ok[0] if ok else max(rows, key=lambda r: r[3])
    return ThresholdChoice(threshold=t, precision=p, recall=rec, n_frames=len(frames), n_pseudo=len(pseudo))
