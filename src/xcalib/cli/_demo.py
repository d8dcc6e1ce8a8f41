"""The steps of ``xcalib demo`` as plain functions returning dataclasses (the command prints them).

1. ``synthetic_site``: a roadside site with exact ground truth (``xcalib.data.synth``);
2. ``match_frames``: the shipped matcher on every frame, scored against the true matches;
3. ``calibrate_frames``: ``xcalib.calibrate`` with no labels and no initial guess, scored
   against the true ``T_cam_lidar`` (degrees, metres) and the true matches;
4. ``real_frames``: the same calibration on a real frame folder (A9 sample) -> residuals.

Every step degrades to an ``ok=False`` outcome with a message instead of raising when a piece
(e.g. shipped weights) is missing.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

Progress = Optional[Callable[[int, int], None]]


@dataclass
class SyntheticData:
    """Frames of one synthetic site (``frames[i].extrinsics`` = true ``T_cam_lidar``)."""

    site: Any
    frames: list
    seconds: float

    @property
    def truth(self) -> np.ndarray:
        return np.asarray(self.site.T_cam_lidar, dtype=np.float64)


@dataclass
class MatchingOutcome:
    """Matcher accuracy against ground truth: per camera detection with a true partner."""

    ok: bool
    message: str = ""
    model: str = ""
    top1: float = float("nan")
    top3: float = float("nan")
    mrr: float = float("nan")
    n_rows: int = 0
    latency_ms_p50: float = float("nan")
    results: list = field(default_factory=list)
    matcher: Any = None
    seconds: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"ok": self.ok, "message": self.message, "model": self.model, "top1": _j(self.top1),
                "top3": _j(self.top3), "mrr": _j(self.mrr), "n_detections": self.n_rows,
                "latency_ms_p50": _j(self.latency_ms_p50), "seconds": round(self.seconds, 3)}


@dataclass
class CalibrationOutcome:
    """One calibration run, its report and (synthetic) its errors against ground truth."""

    ok: bool
    message: str = ""
    result: Any = None
    rotation_error_deg: float = float("nan")
    translation_error_m: float = float("nan")
    pair_precision: float = float("nan")
    pair_recall: float = float("nan")
    report: Optional[Path] = None
    figures: list = field(default_factory=list)
    seconds: float = 0.0
    n_frames: int = 0

    def to_dict(self) -> dict[str, Any]:
        r = self.result
        d = {"ok": self.ok, "message": self.message, "frames": self.n_frames, "seconds": round(self.seconds, 3),
             "report": None if self.report is None else str(self.report),
             "figures": [] if self.report is None else [str(self.report.parent / f.path) for f in self.figures]}
        if r is not None:
            d.update(success=bool(r.success), pairs=int(r.n_pairs), residual_px_median=_j(r.residual_px_median),
                     residual_px_mean=_j(r.reproj_error_px), iou_median=_j(r.iou_median),
                     centre_offset_px_median=_j(None if r.diagnostics is None else r.diagnostics.centre_offset_px_median),
                     rotation_std_deg=[_j(v) for v in r.rotation_std_deg],
                     translation_std_m=[_j(v) for v in r.translation_std_m],
                     extrinsics_T_cam_lidar=r.extrinsics.tolist() if r.success else None)
        if np.isfinite(self.rotation_error_deg):
            d.update(rotation_error_deg=_j(self.rotation_error_deg), translation_error_m=_j(self.translation_error_m),
                     pair_precision=_j(self.pair_precision), pair_recall=_j(self.pair_recall))
        return d


def _j(v):
    if v is None:
        return None
    v = float(v)
    return v if np.isfinite(v) else None


SHIPPED_SITE_SEED = 0  # the shipped "synthetic" weights were trained on sample_site(0, "roadside")


def synthetic_site(n_frames: int, seed: int, *, site_seed: int = SHIPPED_SITE_SEED,
                   progress: Progress = None) -> SyntheticData:
    """``n_frames`` rendered frames (1920x1200) of one traffic sequence (``seed``) at the roadside
    site ``sample_site(site_seed)``; the default is the site the shipped weights belong to (its
    training used traffic seeds 1-3 and 100+, so other seeds are unseen traffic)."""
    from ..data.synth import iter_frames, sample_site

    t0 = time.perf_counter()
    site = sample_site(site_seed, "roadside")
    frames = []
    for k, fr in enumerate(iter_frames(site, n_frames, seed=seed)):
        frames.append(fr)
        if progress:
            progress(k + 1, n_frames)
    return SyntheticData(site, frames, time.perf_counter() - t0)


def load_matcher(model: str, weights: Optional[Path], site: str = "synthetic", config: Optional[Path] = None,
                 device: str = "cpu", *, own_site: bool = False):
    """``Matcher.from_pretrained`` or (None, why) — never raises. ``own_site``: the frames are
    the shipped weights' own synthetic site, so their warning that they do not know it is not said."""
    import contextlib

    try:
        from ..engine.matcher import Matcher, without_shipped_weights_note

        quiet = own_site and weights is None and site == "synthetic"
        with without_shipped_weights_note() if quiet else contextlib.nullcontext():
            return Matcher.from_pretrained(model, weights=weights, config=config, site=site, device=device), ""
    except Exception as exc:  # noqa: BLE001 - the demo reports and goes on
        return None, f"{type(exc).__name__}: {exc}"


def match_frames(matcher, frames: list, progress: Progress = None) -> MatchingOutcome:
    """Run ``matcher.match_frame`` on every frame; Top-1/Top-3/MRR against ``frame.match_matrix``."""
    from ..engine.metrics import MetricsAccumulator

    t0 = time.perf_counter()
    acc = MetricsAccumulator()
    results = []
    for k, fr in enumerate(frames):
        # one-to-one pairs; a pair probability below 0.5 is "no partner" (e.g. a box the other sensor missed)
        r = matcher.match_frame(fr, assignment="hungarian", match_threshold=0.5, validate="off",
                                 geometry="off")  # the model itself
        results.append(r)
        if fr.match_matrix is not None:
            acc.add(r.full_similarity(fr.num_2d, fr.num_3d, fill=-np.inf), fr.match_matrix, r.latency_ms)
        if progress:
            progress(k + 1, len(frames))
    m = acc.result()
    return MatchingOutcome(True, "", matcher.model_name, m.top1, m.top3, m.mrr, m.n_cameras_with_match,
                           float(m.latency.get("latency_ms_p50", np.nan)), results, matcher,
                           time.perf_counter() - t0)


def pair_accuracy(result, frames: list) -> tuple[float, float]:
    """(precision, recall) of the calibration's per-frame pairs against the true match matrices."""
    n_pred = n_ok = n_true = 0
    for p, fr in zip(result.pairs, frames):
        mm = fr.match_matrix
        if mm is None:
            continue
        n_true += int(mm.any(axis=1).sum())
        if len(p):
            n_pred += len(p)
            n_ok += int(mm[p[:, 0], p[:, 1]].sum())
    return (n_ok / n_pred if n_pred else float("nan")), (n_ok / n_true if n_true else float("nan"))


@dataclass(frozen=True)
class ReportStyle:
    """How a demo calibration's report looks: its ``title``, ``extra`` rows (label -> value) and
    how many frames it draws (``max_frames``)."""

    title: str = "xcalib calibration"
    extra: dict | None = None
    max_frames: int = 4


def calibrate_frames(frames: list, intrinsics, out_dir: Path, *, truth=None, matcher=None, matches=None,
                     style: ReportStyle = ReportStyle(),
                     progress: Optional[Callable[[str, int, int], None]] = None) -> CalibrationOutcome:
    """``xcalib.calibrate(frames, intrinsics)`` (no labels, no prior), save it and write the report."""
    title, extra, max_frames = style.title, style.extra, style.max_frames
    from ..calib.api import calibrate
    from ..viz.report import write_calibration_report

    t0 = time.perf_counter()
    try:
        res = calibrate(frames, intrinsics, matcher=matcher, progress=progress)
    except Exception as exc:  # noqa: BLE001
        return CalibrationOutcome(False, f"calibration raised {type(exc).__name__}: {exc}", n_frames=len(frames),
                                  seconds=time.perf_counter() - t0)
    secs = time.perf_counter() - t0
    out = CalibrationOutcome(bool(res.success), res.message, res, seconds=secs, n_frames=len(frames))
    if truth is not None and res.success:
        out.rotation_error_deg, out.translation_error_m = res.pose_error(truth)
        out.pair_precision, out.pair_recall = pair_accuracy(res, frames)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    ex = dict(extra or {})
    if truth is not None and res.success:
        ex["matched pairs correct vs ground truth (precision)"] = out.pair_precision
        ex["true pairs recovered (recall)"] = out.pair_recall
    try:
        from ..calib.report import write_report  # calibration.json/.npz, summary.txt, overlays/ (as `xcalib calibrate`)

        paths = write_report(res, frames, out_dir, max_overlays=max_frames)
        rep = write_calibration_report(out_dir, res, frames, ground_truth=truth, matches=matches, extra=ex,
                                       title=title, max_frames=max_frames, calibration_overlays=paths.overlays)
        out.report, out.figures = rep.html, rep.figures
    except Exception as exc:  # noqa: BLE001 - numbers first; a drawing failure must not hide them
        res.save(out_dir / "calibration.json")
        out.message = (out.message + "; " if out.message else "") + f"report failed: {type(exc).__name__}: {exc}"
    return out


def matcher_agreement(matcher, frames: list, result) -> tuple[float, int]:
    """Fraction of the calibration's pairs (pseudo-labels, no ground truth) that the matcher's
    one-to-one matches reproduce, and the number of pairs compared."""
    hit = total = 0
    for fr, p in zip(frames, result.pairs):
        if not len(p):
            continue
        r = matcher.match_frame(fr, assignment="hungarian", validate="off", geometry="off")  # the model itself
        mine = {int(i): int(j) for i, j, _ in r.matches}
        hit += sum(mine.get(int(i)) == int(j) for i, j in p)
        total += len(p)
    return (hit / total if total else float("nan")), total


def find_real_frames(explicit: Optional[Path]) -> Optional[Path]:
    """``explicit``, else ``../shared/data/a9_sample`` beside the cwd or the repository, else
    ``$XCALIB_SHARED_DATA/a9_sample``; None when absent."""
    import os

    if explicit is not None:
        return explicit
    cands = [Path.cwd().parent / "shared" / "data" / "a9_sample"]
    repo = Path(__file__).resolve().parents[3]
    cands.append(repo.parent / "shared" / "data" / "a9_sample")
    env = os.environ.get("XCALIB_SHARED_DATA")
    if env:
        cands.insert(0, Path(env) / "a9_sample")
    return next((c for c in cands if (c / "manifest.json").is_file()), None)


def quick_match_demo(matcher, n_image: int = 3, n_lidar: int = 5, seed: int = 0) -> list[str]:
    """The reference's ``xcalib demo``: one synthetic 720x1280 frame with 12k points and
    ``n_image`` / ``n_lidar`` boxes, ``match(top_k=3, return_latency=True)``; returns the printed
    lines (similarity shape, argmax, latency, the first 10 matches)."""
    rng = np.random.default_rng(seed)
    image = rng.integers(0, 256, (720, 1280, 3), dtype=np.uint8)
    xy = np.column_stack([rng.uniform(0, 1100, n_image), rng.uniform(0, 560, n_image)])
    b2 = np.hstack([xy, xy + rng.uniform(40, 160, (n_image, 2))]).astype(np.float32)
    ctr = np.column_stack([rng.uniform(8, 40, n_lidar), rng.uniform(-10, 10, n_lidar), np.zeros(n_lidar)])
    dims = np.column_stack([rng.uniform(3.5, 4.8, n_lidar), rng.uniform(1.6, 2.0, n_lidar),
                            rng.uniform(1.4, 1.8, n_lidar)])
    b3 = np.hstack([ctr, dims]).astype(np.float32)
    per = 12000 // max(n_lidar, 1)
    pts = np.vstack([c + rng.uniform(-0.5, 0.5, (per, 3)) * d for c, d in zip(ctr, dims)] +
                    [rng.uniform([0, -20, -2], [60, 20, 0], (12000 - per * n_lidar, 3))]).astype(np.float32)
    r = matcher.match(image, pts, b2, b3, top_k=3, return_latency=True, validate="off")
    return [f"similarity shape: {tuple(r.similarity.shape)}", f"argmax per camera box: {r.top_indices.tolist()}",
            f"latency: {r.latency_ms:.2f} ms (forward)",
            "matches (2D, 3D, score): " + ", ".join(f"({i}, {j}, {s:.3f})" for i, j, s in r.matches[:10])]
