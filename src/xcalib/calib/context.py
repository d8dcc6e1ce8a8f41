"""``FitContext``: what every refit of a pose with the matches held fixed needs, in one frozen record.

The pose refinement (``refine.lsq``), the misfit checks (``misfit``) and the uncertainty
(``uncertainty``) all refit the pose from the same inputs: the calibration frames, the matched
pairs per frame, the camera, the pose to start from (and linearise at), the per-edge noise model,
the robust scale and the cost description. They take one :class:`FitContext` instead of those
eight values one by one; a stage that refits on a subset of the matches or on moved frames makes a
new record with :meth:`FitContext.with_pairs` / :meth:`FitContext.with_frames`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable

from .cost import Occlusion
from .diagnostics import NoiseModel
from .pose import Pose

__all__ = ["FitContext", "RefineOptions", "F_SCALE"]

#: default soft-L1 scale of the robust fits (sigma units of the box-edge residuals)
F_SCALE = 2.0


@dataclass(frozen=True)
class FitContext:
    """One fit's inputs (matches held fixed).

    ``frames``: the ``inputs.CalibFrame`` list; ``pairs``: per frame, the matched rows [n,2]
    (2D index, 3D index into that frame's arrays); ``intr``: the camera (``CameraIntrinsics`` or a
    ``CameraModel``); ``pose``: the camera<-LiDAR pose the fit starts from; ``noise``: the per-edge
    error model (None: the default one); ``f_scale``: the soft-L1 scale; ``occlusion``: the cost
    description -- a ``terms.CostSpec`` (the occlusion shaping and the config's named terms), an
    ``Occlusion`` (the box-edge term alone) or None (no occlusion shaping)."""

    frames: list
    pairs: list
    intr: Any
    pose: Pose
    noise: NoiseModel | None = None
    f_scale: float = F_SCALE
    occlusion: Any = Occlusion()
    #: results computed from this record alone (``cached``); a new record (``with_*``) starts empty
    _results: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def cached(self, key: str, make: Callable[[], Any]) -> Any:
        """``make()`` computed once for this record: a result that depends only on its fields (and
        ``key`` naming which), shared by the stages that need it (the fields are never changed in
        place, so the record is its own key)."""
        if key not in self._results:
            self._results[key] = make()
        return self._results[key]

    def __reduce__(self):  # sent to a worker without the cached results (they need not pickle)
        return (FitContext, (self.frames, self.pairs, self.intr, self.pose, self.noise, self.f_scale, self.occlusion))

    def with_pairs(self, pairs: list) -> "FitContext":
        """The same fit on other matches (a subset, a resample)."""
        return replace(self, pairs=pairs)

    def with_frames(self, frames: list) -> "FitContext":
        """The same fit on other frames (moved 3D outlines, another box model)."""
        return replace(self, frames=frames)

    def with_pose(self, pose: Pose) -> "FitContext":
        """The same fit from another pose."""
        return replace(self, pose=pose)


@dataclass(frozen=True)
class RefineOptions:
    """The schedule of ``refine.refine_pose``: ``gates``, the (IoU gate, centre-distance gate) of each
    outer iteration (the last repeats); at least ``min_pairs`` matches; ``max_nfev`` evaluations per
    fit; stop when the robust cost improves by less than ``tol`` (relative), at most ``max_outer``
    iterations (None: the gates + 4); ``adapt_noise``: refit the per-edge error model from the
    second iteration on."""

    gates: tuple = ((0.1, 1.0), (0.2, 0.5), (0.3, 0.0), (0.3, 0.0), (0.3, 0.0), (0.3, 0.0))
    min_pairs: int = 3
    max_nfev: int = 60
    tol: float = 1e-3
    max_outer: int | None = None
    adapt_noise: bool = True
