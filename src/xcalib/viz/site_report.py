"""The report of a calibration run, made once from its result: per camera the calibration files,
summary, overlays and HTML page; for the site ``site_calibration.json`` (the transform tree),
``ros/`` (tf_static YAML, static_transform_publisher lines, URDF, CameraInfo YAML), the Foxglove
review file ``review.mcap`` and, with several cameras, an index ``report.html``.

One camera: its files go straight into ``out_dir`` (``calibration.json``, ``summary.txt``,
``overlays/``, ``report.html``), as ``xcalib calibrate`` always wrote them; several cameras:
one sub-folder per camera.
"""

from __future__ import annotations

import html
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ..io.files import atomic_write

__all__ = ["SiteReportPaths", "write_site_report", "site_table"]


@dataclass
class SiteReportPaths:
    html: Path
    site_json: Path
    review_mcap: Path
    ros: list[Path] = field(default_factory=list)
    cameras: dict[str, Path] = field(default_factory=dict)  # camera -> its summary.txt

    def relocated(self, old, new) -> "SiteReportPaths":
        """The same paths after the folder ``old`` was moved to ``new``."""
        def mv(p: Path) -> Path:
            return Path(new) / Path(p).relative_to(old)

        return SiteReportPaths(mv(self.html), mv(self.site_json), mv(self.review_mcap), [mv(p) for p in self.ros],
                               {k: mv(v) for k, v in self.cameras.items()})


def _fmt(v, nd=3) -> str:
    return "-" if v is None else f"{v:.{nd}f}"


def site_table(site) -> list[str]:
    """Plain-text table: one row per camera (verdict, pairs, uncertainty, error vs truth), then the
    agreement of camera pairs."""
    rows = [f"{'camera':<18} {'verdict':<10} {'frames':>6} {'pairs':>5} {'rot std deg':>11} {'trans std m':>11} "
            f"{'err deg':>8} {'err m':>7}  message"]
    for c in site.cameras:
        r = c.result
        err = c.error_vs_truth
        rs = max(r.rotation_std_deg) if r.success else None
        ts = max(r.translation_std_m) if r.success else None
        rows.append(f"{c.camera:<18} {c.verdict:<10} {c.num_frames:>6} {r.n_pairs:>5} {_fmt(rs):>11} {_fmt(ts):>11} "
                    f"{_fmt(err[0] if err else None):>8} {_fmt(err[1] if err else None):>7}  "
                    f"{'' if r.success else r.message}")
    if site.agreements:
        rows.append("")
        rows.append("cameras that matched the same LiDAR objects:")
        for a in site.agreements:
            extra = "" if a.relative_error_deg is None else \
                f"; relative pose vs truth {a.relative_error_deg:.3f} deg / {a.relative_error_m:.3f} m"
            rows.append(f"  {a.camera_a} & {a.camera_b}: {a.shared_objects} shared object(s), median IoU "
                        f"{a.iou_a_median:.2f} / {a.iou_b_median:.2f}, relative rotation {a.relative_rotation_deg:.2f} "
                        f"deg, baseline {a.baseline_m:.3f} m{extra}")
    return rows


def _index_html(title: str, site, cams: dict[str, Path], out: Path) -> str:
    rows = site_table(site)
    from .advice import plain_advice

    results = {c.camera: c.result for c in site.cameras}
    links = "".join(f'<li><a href="{html.escape(p.relative_to(out).as_posix())}/report.html">'
                    f"{html.escape(c)}</a>: {'<br>'.join(html.escape(line) for line in plain_advice(results[c]))}</li>"
                    for c, p in cams.items())
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title></head><body>"
            f"<h1>{html.escape(title)}</h1><p>Transforms: LiDAR frame <code>{html.escape(site.lidar_frame)}</code> "
            "-&gt; each camera's OpenCV optical frame <code>&lt;camera&gt;_optical_frame</code> (x right, y down, "
            "z forward); <code>site_calibration.json</code> holds the tree, <code>ros/</code> the tf_static YAML, "
            "static_transform_publisher lines, URDF (body <code>&lt;camera&gt;_link</code> + optical joint) and "
            "CameraInfo YAML, <code>review.mcap</code> opens in Foxglove.</p>"
            f"<pre>{html.escape(chr(10).join(rows))}</pre><h2>Cameras</h2><ul>{links}</ul></body></html>")


def write_site_report(out_dir, site, frames_by_camera: dict[str, Sequence], *, max_overlays: int = 8,
                      title: str = "xcalib site calibration",
                      progress: Callable[[str, int, int], None] | None = None,
                      review_max_points: int | None = None, review_frames: int | None = None) -> SiteReportPaths:
    """Write every report file of ``site`` (a :class:`xcalib.site.SiteCalibration`) from the
    frames each camera was calibrated on; see the module docstring for the layout. ``review_frames``:
    frames in review.mcap, spread over the recording (0: every one; None: ``max_overlays``, at least 1)."""
    from ..calib.report import write_report
    from ..site import write_site_ros
    from ..site.calibration import camera_folders
    from .report import write_calibration_report
    from .review import write_review_mcap

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    single = len(site.cameras) == 1
    cams: dict[str, Path] = {}
    summaries: dict[str, Path] = {}
    page = None
    folders = camera_folders([c.camera for c in site.cameras])  # safe, distinct: never outside out
    for c in site.cameras:
        d = out if single else out / folders[c.camera]
        frames = frames_by_camera[c.camera]
        paths = write_report(c.result, frames, d, max_overlays=max_overlays, progress=progress)
        page = write_calibration_report(d, c.result, frames, ground_truth=c.ground_truth,
                                        calibration_overlays=paths.overlays, max_frames=max_overlays,
                                        title=f"{title}: {c.camera}").html
        cams[c.camera], summaries[c.camera] = d, paths.summary
    site_json = site.save(out / "site_calibration.json")
    ros = write_site_ros(site, out / "ros")
    review = write_review_mcap(out / "review.mcap", site, frames_by_camera, max_frames=(max_overlays or 1) if review_frames is None else review_frames,
                               max_points=review_max_points)
    if not single:
        page = atomic_write(out / "report.html", [_index_html(title, site, cams, out).encode()])
    atomic_write(out / "site_summary.txt", ["\n".join(site_table(site)).encode() + b"\n"])
    return SiteReportPaths(page, site_json, review, ros, summaries)
