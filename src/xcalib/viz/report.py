"""HTML report of one calibration run: the numbers and overlay PNGs (linked by relative paths).

``write_calibration_report(out_dir, result, frames)`` writes ``<out_dir>/report.html`` and
``<out_dir>/img/*.png``: per shown frame, the calibration overlay (LiDAR points coloured by camera
depth, projected 3D boxes, 2D boxes, matched pairs) after calibration — and before it when an
initial pose is known — plus the matching overlay (image beside the bird's-eye view).
"""

from __future__ import annotations

import datetime as _dt
import html
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..io.files import atomic_write, safe_name
from ..options import Options, document, resolve

__all__ = ["ReportFigure", "CalibrationReport", "ReportOptions", "write_calibration_report", "frame_arrays"]

_MAX_WIDTH = 1280  # px of the written overlay PNGs


@dataclass
class ReportFigure:
    """One picture of the report: ``path`` relative to the report folder, a caption, a kind
    (``calibration`` / ``calibration_before`` / ``matching``) and the frame key."""

    path: str
    caption: str
    kind: str
    frame_key: str = ""


@dataclass
class CalibrationReport:
    """What :func:`write_calibration_report` wrote: the HTML file, its figures and its numbers."""

    html: Path
    figures: list[ReportFigure] = field(default_factory=list)
    numbers: dict[str, Any] = field(default_factory=dict)


def frame_arrays(frame, index: int = 0):
    """(image, point_cloud, bboxes_2d, bboxes_3d, key, match_matrix) of a ``Frame`` or a 4-tuple.

    ``bboxes_3d`` is the box7 [M,7] with yaw when the frame's meta carries it (synthetic frames).
    """
    if hasattr(frame, "inputs"):
        image, pc, b2, b3 = frame.inputs()
        b7 = (frame.meta or {}).get("box7")
        if b7 is not None and len(b7) == len(b3):
            b3 = b7
        return image, pc, b2, b3, frame.frame_key or f"{index:04d}", frame.match_matrix
    if isinstance(frame, (tuple, list)) and len(frame) >= 4:
        return frame[0], frame[1], frame[2], frame[3], f"{index:04d}", None
    raise TypeError(f"frames[{index}]: expected a Frame or (image, point_cloud, bboxes_2d, bboxes_3d), "
                    f"got {type(frame).__name__}")


def _pick(n: int, k: int) -> list[int]:
    if n <= k:
        return list(range(n))
    return sorted({int(round(v)) for v in np.linspace(0, n - 1, k)})


def _write_png(path: Path, rgb: np.ndarray, max_width: int = _MAX_WIDTH) -> None:
    from ..io.images import write_image

    write_image(path, _shrink(rgb, max_width))
    path.chmod(0o644)  # readable by a web server like the HTML beside it


def _shrink(rgb: np.ndarray, max_width: int = _MAX_WIDTH) -> np.ndarray:
    import cv2

    if rgb.shape[1] <= max_width:
        return rgb
    s = max_width / rgb.shape[1]
    return cv2.resize(rgb, (max_width, int(round(rgb.shape[0] * s))), interpolation=cv2.INTER_AREA)


def _initial_pose(result, before):
    from ..calib.pose import Pose

    if before is not None:
        p = Pose.parse(before, "before")
        return p.R, p.T[:3, 3]
    diag = getattr(result, "diagnostics", None)
    if diag is not None and diag.bringup_T is not None:  # the calibrator's best bring-up pose, before refinement
        p = Pose.parse(np.asarray(diag.bringup_T, dtype=np.float64))
        return p.R, p.t
    meta = getattr(result, "meta", {}) or {}
    if "initial_rotation" in meta and "initial_translation" in meta:
        return np.asarray(meta["initial_rotation"], float), np.asarray(meta["initial_translation"], float)
    return None


def calibrator_boxes(frame, intrinsics, b3: np.ndarray) -> np.ndarray:
    """The 3D boxes as the calibrator used them (box7; yaw re-estimated from the points for
    yaw-less [M,6] boxes), in the caller's numbering; ``b3`` as box7 when that fails."""
    from ..geometry.boxes import as_box7

    out = as_box7(b3) if len(b3) else np.zeros((0, 7))
    if np.asarray(b3).shape[-1] == 7 or intrinsics is None or not len(b3):
        return out
    try:
        from ..calib.inputs import prepare_frames

        cf, _, _ = prepare_frames([frame], intrinsics)
        out[cf[0].idx3d] = cf[0].boxes3d
    except Exception:  # noqa: BLE001 - drawing falls back to the boxes as given
        pass
    return out


def _fmt(v: Any) -> str:
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (float, np.floating)):
        return "n/a" if not np.isfinite(v) else f"{v:.4g}"
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_fmt(x) for x in np.asarray(v, dtype=object).ravel()) + "]"
    return str(v)


def result_numbers(result, ground_truth=None) -> dict[str, Any]:
    """The headline numbers of a ``CalibrationResult`` (pixels, IoU, degrees, metres)."""
    from ..geometry.rotations import matrix_to_euler

    diag = getattr(result, "diagnostics", None)
    co = None if diag is None else diag.centre_offset_px_median
    frames_line = getattr(result, "frames_line", None)
    nums: dict[str, Any] = {
        "success": bool(result.success),
        "message": result.message or "-",
        "method": result.method or "-",
        "frames": (frames_line() if frames_line else "") or len(result.frame_keys),  # "N of M used (...)"
        "matched pairs": int(result.n_pairs),
        "pairs with IoU >= 0.5": int(result.n_inliers),
        "residual median (px)": float(result.residual_px_median),
        "residual mean (px)": float(result.reproj_error_px),
        "IoU median": float(result.iou_median),
        "IoU mean": float(result.iou_mean),
        "box-centre offset median (px)": float(np.nan if co is None else co),
        "rotation 1-sigma (deg)": np.asarray(result.rotation_std_deg, float),
        "translation 1-sigma (m)": np.asarray(result.translation_std_m, float),
    }
    if result.rotation is not None and result.translation is not None:  # a failed result has no pose
        nums["translation t (m)"] = np.asarray(result.translation, float)
        nums["rotation xyz Euler (deg)"] = matrix_to_euler(np.asarray(result.rotation, float), "xyz", degrees=True)
    if diag is not None:
        nums["calibration time (s)"] = float(diag.elapsed_s)
    if ground_truth is not None and result.success:
        rot_deg, trans_m = result.pose_error(ground_truth)
        nums["rotation error vs ground truth (deg)"] = float(rot_deg)
        nums["translation error vs ground truth (m)"] = float(trans_m)
    return nums


@dataclass(frozen=True)
class ReportOptions(Options):
    """What :func:`write_calibration_report` shows (the defaults in one place; the function
    documents each): ground_truth, matches, before, extra, title, max_frames, point_radius,
    calibration_overlays."""

    ground_truth: Any = None
    matches: Any = None
    before: Any = None
    extra: dict[str, Any] | None = None
    title: str = "xcalib calibration"
    max_frames: int = 4
    point_radius: int = 2
    calibration_overlays: Sequence | None = None


@document(ReportOptions)
def write_calibration_report(out_dir, result, frames: Sequence, *, options: ReportOptions | None = None,
                             **overrides: Any) -> CalibrationReport:
    """Write ``<out_dir>/report.html`` + ``<out_dir>/img/*.png`` for one calibration run.

    Args:
        result: ``CalibrationResult`` (its ``pairs`` are per frame, in ``frames`` order).
        frames: the calibrated ``Frame``s or (image, point_cloud, bboxes_2d, bboxes_3d) tuples.
        ground_truth: optional true ``T_cam_lidar`` [4,4] -> pose error rows.
        matches: optional per-frame matcher output (``MatchResult`` or (i, j, score) rows) for
            the matching overlays; default = the calibration's pairs (score = projected IoU).
        before: optional initial pose (CalibrationResult, (R, t) or 4x4) for "before" overlays
            (default: ``result.meta["initial_rotation"/"initial_translation"]`` when present).
        extra: more rows for the numbers table (e.g. matching accuracy).
        max_frames: frames shown (evenly spaced).
        calibration_overlays: PNGs already drawn (``xcalib.calib.report.write_report``'s
            ``overlays/<key>.png`` and ``<key>_bringup.png``) to show instead of drawing new ones.
        title, point_radius: the page title and the overlays' point size (px).
        The keyword settings are the fields of :class:`ReportOptions` (or one whole as ``options=``).
    Returns:
        :class:`CalibrationReport` with the HTML path, figures and numbers.
    """
    o = resolve(ReportOptions, options, overrides, where="write_calibration_report")
    ground_truth, matches, before, extra, title = o.ground_truth, o.matches, o.before, o.extra, o.title
    max_frames, point_radius, calibration_overlays = o.max_frames, o.point_radius, o.calibration_overlays
    from ..geometry.boxes import as_box7, box7_corners, boxes2d_from_points, iou_matrix
    from .calibration import REPORT_MAX_POINTS, draw_calibration_overlay
    from .matching import REPORT_HEIGHT, draw_matching_overlay

    out = Path(out_dir)
    (out / "img").mkdir(parents=True, exist_ok=True)
    frames = frames if isinstance(frames, Sequence) else list(frames)  # a lazy sequence stays lazy
    figures: list[ReportFigure] = []
    initial = _initial_pose(result, before)
    existing: dict[str, list[tuple[Path, bool]]] = {}
    for p in calibration_overlays or []:
        p = Path(p)
        key, before_fig = (p.stem[:-len("_bringup")], True) if p.stem.endswith("_bringup") else (p.stem, False)
        existing.setdefault(key, []).append((p, before_fig))
    if existing:  # show the frames that were drawn
        keys = [frame_arrays(f, i)[4] for i, f in enumerate(frames)]
        shown = [i for i, k in enumerate(keys) if safe_name(k) in existing]  # overlay names are safe_name(key)
    else:
        shown = _pick(len(frames), max_frames)
    have_pose = result.intrinsics is not None and bool(result.success)
    for idx in shown:
        image, pc, b2, b3, key, truth = frame_arrays(frames[idx], idx)
        pairs = result.pairs[idx] if idx < len(result.pairs) else np.zeros((0, 2), np.int64)
        stem = f"frame_{idx:03d}"
        given_yaw = np.asarray(b3).shape[-1] == 7
        b3 = calibrator_boxes(frames[idx], result.intrinsics, np.asarray(b3))
        if existing and have_pose:
            for path, before_fig in sorted(existing.get(safe_name(key), []), key=lambda e: not e[1]):  # before first
                figures.append(ReportFigure(
                    Path(os.path.relpath(path, out)).as_posix(),
                    f"Frame {key}, " + ("bring-up pose, before refinement: LiDAR points coloured by camera "
                                        "depth, projected 3D boxes (orange), 2D boxes (green)" if before_fig else
                                        "refined pose: LiDAR points coloured by camera depth (blue near, red far), "
                                        "projected 3D boxes (orange), 2D boxes (green), matched pairs linked"),
                    "calibration_before" if before_fig else "calibration", key))
        elif have_pose:
            ov = draw_calibration_overlay(image, pc, calibration=result, bboxes_3d=b3, bboxes_2d=b2, pairs=pairs,
                                          point_radius=point_radius, max_points=REPORT_MAX_POINTS,
                                          title=f"{key}: after calibration")
            _write_png(out / "img" / f"{stem}_calibration.png", ov)
            figures.append(ReportFigure(f"img/{stem}_calibration.png",
                                        f"Frame {key}, estimated pose: LiDAR points coloured by camera depth "
                                        f"(blue near, red far), projected 3D boxes (orange), 2D boxes (green), "
                                        f"{len(pairs)} matched pairs linked (cyan)", "calibration", key))
        if initial is not None and result.intrinsics is not None and not existing:
            ov = draw_calibration_overlay(image, pc, intrinsics=result.intrinsics, rotation=initial[0],
                                          translation=initial[1], bboxes_3d=b3, bboxes_2d=b2,
                                          point_radius=point_radius, max_points=REPORT_MAX_POINTS,
                                          title=f"{key}: before refinement")
            _write_png(out / "img" / f"{stem}_before.png", ov)
            figures.append(ReportFigure(f"img/{stem}_before.png", f"Frame {key}, initial pose (before refinement)",
                                        "calibration_before", key))
        m = None
        if matches is not None and idx < len(matches) and matches[idx] is not None:
            m, source = matches[idx], "matcher scores"
        elif have_pose and len(pairs):
            b7 = as_box7(b3)
            uv, _ = result.project(box7_corners(b7[pairs[:, 1]]).reshape(-1, 3))
            proj = boxes2d_from_points(uv.reshape(len(pairs), 8, 2))
            iou = np.diag(iou_matrix(np.asarray(b2, float)[pairs[:, 0]], proj)) if len(pairs) else np.zeros(0)
            m, source = [(int(i), int(j), float(s)) for (i, j), s in zip(pairs, np.nan_to_num(iou))], "projected IoU"
        if m is not None:
            mo = draw_matching_overlay(image, pc, b2, b3, m, output_height=REPORT_HEIGHT, match_matrix=truth,
                                       camera=result if have_pose else None,
                                       title=f"{key}: matching ({source})")
            _write_png(out / "img" / f"{stem}_matching.png", mo, 1600)
            figures.append(ReportFigure(f"img/{stem}_matching.png",
                                        f"Frame {key}: camera image with 2D boxes beside the LiDAR bird's-eye view "
                                        f"(+x up, +y left) with 3D boxes; pairs coloured by {source}, unmatched "
                                        "boxes grey and dashed"
                                        + ("" if given_yaw else "; box yaw re-estimated from the points")
                                        + ("; red crosses = wrong vs ground truth"
                                                                   if truth is not None else "")
                                        + "; the amber wedge is the camera's field of view", "matching", key))
    nums = result_numbers(result, ground_truth)
    if extra:
        nums.update(extra)
    html_path = out / "report.html"
    atomic_write(html_path, [_render_html(title, result, nums, figures, out).encode()])
    return CalibrationReport(html=html_path, figures=figures, numbers=nums)


def _render_html(title: str, result, nums: dict[str, Any], figures: list[ReportFigure], out: Path) -> str:
    from .. import __version__

    e = html.escape
    ok = bool(result.success)
    badge = ('<span class="ok">calibrated</span>' if ok else '<span class="bad">not calibrated</span>')
    rows = "\n".join(f"<tr><th>{e(str(k))}</th><td>{e(_fmt(v))}</td></tr>" for k, v in nums.items())
    T = np.asarray(result.extrinsics, float) if result.rotation is not None else np.full((4, 4), np.nan)
    mat = "\n".join("<tr>" + "".join(f"<td>{v:+.6f}</td>" for v in row) + "</tr>" for row in T)
    files = [p for p in ("calibration.json", "calibration.npz", "summary.txt", "summary.json") if (out / p).exists()]
    links = " · ".join(f'<a href="{e(p)}">{e(p)}</a>' for p in files) or "-"
    figs = "\n".join(
        f'<figure><a href="{e(f.path)}"><img src="{e(f.path)}" alt="{e(f.caption)}"></a>'
        f"<figcaption>{e(f.caption)}</figcaption></figure>" for f in figures)
    now = _dt.datetime.now().strftime("%Y-%m-%d %H:%M")
    from .advice import plain_advice

    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{e(title)}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 24px; color: #222; max-width: 1700px; }}
h1 {{ font-size: 1.5em; }} .ok {{ background: #1a7f37; color: white; padding: 2px 8px; border-radius: 4px; }}
.bad {{ background: #b42318; color: white; padding: 2px 8px; border-radius: 4px; }}
table {{ border-collapse: collapse; margin: 8px 0 16px; }} th, td {{ border: 1px solid #ddd; padding: 3px 10px; }}
th {{ text-align: left; background: #f5f5f5; font-weight: 500; }} td {{ font-family: ui-monospace, monospace; }}
figure {{ margin: 0 0 24px; }} img {{ max-width: 100%; border: 1px solid #ccc; }}
figcaption {{ color: #444; font-size: 0.92em; margin-top: 4px; }}
</style></head><body>
<h1>{e(title)} {badge}</h1>
<p>{e(result.message or ("Camera<-LiDAR extrinsics estimated." if ok else ""))}</p>
<p><b>{"<br>".join(e(line) for line in plain_advice(result))}</b></p>
<p>xcalib {e(__version__)} · {e(now)} · camera {e(result.camera_name or "-")} · files: {links}</p>
<h2>Numbers</h2>
<table>{rows}</table>
<h2>Extrinsics T_cam_lidar (LiDAR -&gt; camera, metres)</h2>
<table>{mat}</table>
<h2>Overlays</h2>
{figs or "<p>No overlays (no pose).</p>"}
</body></html>
"""
