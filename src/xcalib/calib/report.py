"""Calibration report: result files, overlay PNGs and a human-readable summary in one folder.

Layout written by :func:`write_report`::

    DIR/calibration.json        CalibrationResult.save (everything, incl. distortion)
    DIR/calibration.npz         arrays + the same JSON blob
    DIR/summary.txt             result summary + per-frame table
    DIR/overlays/<key>.png      (key made file-name safe: letters, digits, ``._+=-``) points coloured by depth, projected 3D boxes, 2D boxes, matches
    DIR/overlays/<key>_bringup.png   the same through the bring-up pose, before refinement
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..io.files import atomic_write, safe_name
from ..io.images import encode_image
from .inputs import prepare_frames
from .refine import pair_metrics
from .result import CalibrationResult

__all__ = ["ReportPaths", "write_report", "frame_table"]


@dataclass
class ReportPaths:
    """Files written by ``write_report``."""

    json: Path
    npz: Path
    summary: Path
    overlays: list[Path] = field(default_factory=list)


def _prepare(result: CalibrationResult, frames: Sequence):
    """The frames as the calibration prepared them (its config: yaw re-estimation, box model)."""
    cfg = result.config
    kw = {} if cfg is None else {"reestimate_yaw": cfg.reestimate_yaw, "box_model": cfg.box_model}
    return prepare_frames(list(frames), result.intrinsics, **kw)


def frame_table(result: CalibrationResult, frames: Sequence) -> list[dict]:
    """Per frame: key, 2D/3D counts, matched pairs, median edge residual (px) and IoU -- as the
    calibration computed them (``result.diagnostics.frames``), else recomputed at its pose."""
    diag = result.diagnostics
    used = [] if diag is None else list(getattr(diag.selection, "used_indices", []) or [])
    if used and len(diag.frames) == len(used) and max(used) < len(frames):  # a selection: the used frames
        return [{"frame": r.key, "n_2d": int(len(np.asarray(frames[i].bboxes_2d))),
                 "n_3d": int(len(np.asarray(frames[i].bboxes_3d))), "pairs": r.pairs,
                 "px_median": r.px_median if result.success else None,
                 "iou_median": r.iou_median if result.success else None} for r, i in zip(diag.frames, used)]
    if diag is not None and len(diag.frames) == len(frames):
        return [{"frame": r.key, "n_2d": int(len(np.asarray(f.bboxes_2d))), "n_3d": int(len(np.asarray(f.bboxes_3d))),
                 "pairs": r.pairs, "px_median": r.px_median if result.success else None,
                 "iou_median": r.iou_median if result.success else None} for r, f in zip(diag.frames, frames)]
    cframes, intr, _ = _prepare(result, frames)
    rows = []
    for k, (fr, f) in enumerate(zip(cframes, frames)):
        p = result.pairs[k] if k < len(result.pairs) else np.zeros((0, 2), np.int64)
        # caller numbering -> CalibFrame rows
        r2 = {int(v): n for n, v in enumerate(fr.idx2d)}
        r3 = {int(v): n for n, v in enumerate(fr.idx3d)}
        rows_p = np.array([[r2[int(i)], r3[int(j)]] for i, j in p if int(i) in r2 and int(j) in r3],
                          dtype=np.int64).reshape(-1, 2)
        px, iou = pair_metrics([fr], intr, result.rotation, result.translation, [rows_p]) if result.success \
            else (np.zeros(0), np.zeros(0))
        rows.append({"frame": fr.key, "n_2d": int(len(np.asarray(f.bboxes_2d))), "n_3d": int(len(np.asarray(f.bboxes_3d))),
                     "pairs": int(len(p)), "px_median": float(np.median(px)) if len(px) else None,
                     "iou_median": float(np.median(iou)) if len(iou) else None})
    return rows


def _check_value(c) -> str:
    """A misfit check's statistic and limit as read: most checks flag a statistic above the limit;
    ``focal_scale`` is a scale flagged outside x(1 +- limit); ``focal_checkable`` (sigmas from a
    5 % focal error) is flagged at or below it."""
    if c.name == "focal_scale":
        return f"x{c.statistic:.3g} (limit x{1 / (1 + c.limit):.3g}-x{1 + c.limit:.3g})"
    if c.name == "focal_checkable":
        return f"{c.statistic:.3g} (at least {c.limit:.3g})"
    return f"{c.statistic:.3g} (limit {c.limit:.3g})"


def _summary_text(result: CalibrationResult, rows: list[dict]) -> str:
    lines = [result.summary(), ""]
    d = result.diagnostics
    if result.success:
        co = None if d is None else d.centre_offset_px_median
        lines += [f"  pairs with IoU >= 0.5: {result.n_inliers} of {result.n_pairs}",
                  f"  mean edge residual: {result.reproj_error_px:.2f} px",
                  f"  box-centre offset (2D centre vs projected 3D centre): "
                  f"{'n/a' if co is None else f'{co:.1f} px median'}"]
        if d is not None:
            lines.append(f"  bring-up: {d.n_hypotheses} hypotheses ({d.seed_source}); score {d.score:.2f}, "
                         f"runner-up {d.runner_up_score:.2f}")
            lines += [f"  misfit check {c.name}: {_check_value(c)}{' FLAGGED' if c.flagged else ''}"
                      f"{'; ' + c.detail if c.detail else ''}" for c in d.misfit]
        lines.append("")
    if d is not None and getattr(d, "box_fit", None) and not result.success and "sides" in d.box_fit:
        bf = d.box_fit
        lines += [f"  box model: {bf.get('outline') or 'corners'} outlines; 2D boxes inside them by "
                  f"{100 * bf['sides']:+.1f} % (sides), {100 * bf['top']:+.1f} % (top), {100 * bf['bottom']:+.1f} % "
                  "(bottom) of their size", ""]
    if d is not None and d.selfcal.notes:
        lines += [f"  self-calibration: {n}" for n in d.selfcal.notes] + [""]
    line = result.frames_line()
    if line and not result.success:  # a success's summary() holds it already ("frames        = ...")
        lines += [f"  frames: {line}", ""]
    w = max([12] + [len(str(r["frame"])) for r in rows])  # a bag's frames are nanosecond stamps (19 digits)
    lines.append(f"{'frame':>{w}} {'2D':>4} {'3D':>4} {'pairs':>5} {'px med':>7} {'IoU med':>7}")
    for r in rows:
        px = "-" if r["px_median"] is None else f"{r['px_median']:.2f}"
        iou = "-" if r["iou_median"] is None else f"{r['iou_median']:.3f}"
        lines.append(f"{r['frame']:>{w}} {r['n_2d']:>4} {r['n_3d']:>4} {r['pairs']:>5} {px:>7} {iou:>7}")
    return "\n".join(lines) + "\n"


def _unique(name: str, used: set[str]) -> str:
    out, k = name, 1
    while out in used:
        out, k = f"{name}_{k}", k + 1
    used.add(out)
    return out


def write_report(result: CalibrationResult, frames: Sequence, out_dir, *, max_overlays: int = 8,
                 bringup_overlays: bool = True, progress: Callable[[str, int, int], None] | None = None) -> ReportPaths:
    """Write the calibration, overlays of up to ``max_overlays`` frames (spread over the sequence)
    and ``summary.txt`` into ``out_dir``. ``progress(stage, done, total)`` is called per overlay."""
    from ..viz.calibration import REPORT_MAX_POINTS, draw_calibration_overlay

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = ReportPaths(json=result.save(out / "calibration.json"), npz=result.save(out / "calibration.npz"),
                        summary=out / "summary.txt")
    rows = frame_table(result, frames)
    atomic_write(paths.summary, [_summary_text(result, rows).encode()])
    if not result.success or max_overlays <= 0:
        return paths
    sel = None if result.diagnostics is None else result.diagnostics.selection
    pool = np.asarray(sel.used_indices if sel is not None and sel.used_indices else range(len(frames)), dtype=int)
    pool = pool[pool < len(frames)]  # draw the frames the calibration used
    n = len(pool)
    pick = pool[np.unique(np.linspace(0, n - 1, min(max_overlays, n)).round().astype(int))]
    bring = None if result.diagnostics is None else result.diagnostics.bringup_T
    (out / "overlays").mkdir(exist_ok=True)
    used: set[str] = set()
    for k, fi in enumerate(pick):
        f = frames[int(fi)]
        image = np.asarray(f.image)
        if image.ndim != 3 or image.shape[0] < 2:
            w, h = result.image_size or (int(2 * result.intrinsics.cx), int(2 * result.intrinsics.cy))
            image = np.full((h, w, 3), 40, np.uint8)
        cf, _, _ = _prepare(result, [f])
        key = cf[0].key
        p = result.pairs[int(fi)] if int(fi) < len(result.pairs) else None
        # draw the yaw-corrected boxes the calibration used, indexed like the caller's boxes
        b3 = np.zeros((len(np.asarray(f.bboxes_3d)), 7))
        b3[cf[0].idx3d] = cf[0].boxes3d
        img = draw_calibration_overlay(image, f.point_cloud, calibration=result, bboxes_3d=b3,
                                       bboxes_2d=f.bboxes_2d, pairs=p, max_points=REPORT_MAX_POINTS,
                                       title=f"{key}: refined, {0 if p is None else len(p)} pairs")
        name = _unique(safe_name(key), used)  # frame keys are data: never a path
        path = out / "overlays" / f"{name}.png"
        atomic_write(path, [encode_image(img, ".png")])
        paths.overlays.append(path)
        if bringup_overlays and bring is not None and k == 0:
            T = np.asarray(bring)
            img = draw_calibration_overlay(image, f.point_cloud, intrinsics=result.intrinsics, rotation=T[:3, :3],
                                           translation=T[:3, 3], bboxes_3d=b3, bboxes_2d=f.bboxes_2d,
                                           max_points=REPORT_MAX_POINTS, title=f"{key}: bring-up pose (before refinement)")
            bpath = out / "overlays" / f"{name}_bringup.png"
            atomic_write(bpath, [encode_image(img, ".png")])
            paths.overlays.append(bpath)
        if progress:
            progress("overlays", k + 1, len(pick))
    return paths
