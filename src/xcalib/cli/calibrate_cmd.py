"""``xcalib calibrate``: targetless camera<-LiDAR calibration of one or several cameras, with a report."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from ..errors import FormatError
from .detect_cmd import detect_flag, detect_request, detector_2d_flag, lidar_mode_flag

_HELP = """Estimate T_cam_lidar from the frames' 2D and 3D detections (no target, no labels, no guess).

SOURCE is any frame source: frame folder, HDF5 cache, KITTI folder, nuScenes/mmdet3d pickle,
CalibAnything scene, ROS 1 .bag / ROS 2 .db3 / .mcap. --camera (repeatable) picks cameras of a
multi-camera source; each is calibrated against the LiDAR and the run writes one site
calibration (DIR/site_calibration.json: every transform with its uncertainty and verdict), the
ROS files (DIR/ros/: tf_static YAML, static_transform_publisher lines, URDF, CameraInfo YAML), a
Foxglove review file (DIR/review.mcap) and the report (DIR/report.html; with several cameras one
sub-folder per camera). One camera: DIR/calibration.json + .npz, DIR/summary.txt, DIR/overlays/.
Exit code 1 when a camera's frames do not determine its pose (the reason is printed and saved).

A recording without detections (only images, CameraInfo and clouds): --detect makes them in memory with xcalib's own detectors (see xcalib detect; needs the onnx extra).

Example: xcalib calibrate ../shared/data/a9_sample --out runs/a9_calib

Example: xcalib calibrate raw.mcap --detect --out runs/raw

Example: xcalib calibrate nus.mcap --camera CAM_FRONT --camera CAM_BACK --out runs/nus
"""
# one line per paragraph: the help formatter wraps to the terminal, and a source line break inside
# a paragraph would break the sentence there too
_HELP = "\n\n".join(" ".join(p.split()) for p in _HELP.split("\n\n"))


def register(app: typer.Typer) -> None:
    @app.command("calibrate", help=_HELP)
    def calibrate_command(
        frames: Path = typer.Argument(..., metavar="SOURCE", help="Frame source (xcalib.io.sources)."),
        camera: list[str] = typer.Option(None, "--camera", "-c", help="Camera to calibrate (repeat for several)."),
        frame_range: str = typer.Option(None, "--frames", help="Frames to use: 0:8, 0,3,5, 8: (indices)."),
        intrinsics: Path = typer.Option(None, "--intrinsics", "-k",
                                        help="Intrinsics: xcalib intrinsics JSON {fx, fy, cx, cy, distortion}, or with a \"model\" "
                                             "(kannala_brandt, unified, ucm, eucm, double_sphere: docs/camera-models.md), or a "
                                             "camera file (ROS CameraInfo YAML, Kalibr camchain, OpenCV YAML/JSON) "
                                             "(one camera; a camchain's: FILE#cam1); default: the source's."),
        out: Path = typer.Option(Path("calibration_report"), "--out", "-o", help="Report folder."),
        prior: Path = typer.Option(None, "--prior", help="Initial guess: a calibration file of any "
                                                         "format xcalib convert reads (skips bring-up; one camera)."),
        box_model: str = typer.Option("auto", "--box-model", help="auto | corners | points (3D box outline)."),
        max_overlays: int = typer.Option(8, "--max-overlays", help="Overlay PNGs to draw per camera (0: none), "
                                         "spread over the recording."),
        review_frames: int = typer.Option(50, "--review-frames", min=0,
                                          help="Frames in review.mcap, spread evenly over the whole recording "
                                               "(first and last included; 0: every frame: about 1 MB each "
                                               "with whole clouds, see --review-max-points)."),
        limit: int = typer.Option(0, "--limit", help="Use only the first N frames (0: all)."),
        max_frames: int = typer.Option(None, "--max-frames", help="Most frames one calibration uses (default 200): a "
                                                                 "longer recording is reduced to its informative "
                                                                 "frames (distinct objects, places, depths); 0: all."),
        tolerance: float = typer.Option(0.05, "--tolerance", help="Bags: largest LiDAR/image stamp difference (s)."),
        fisheye: str = typer.Option("rectify", "--fisheye", help="Bags with an equidistant CameraInfo: rectify "
                                                                 "(to pinhole) | keep (calibrate in the fisheye "
                                                                 "image, kannala_brandt model)."),
        seed: int = typer.Option(0, "--seed", help="Random seed of the hypothesis sampling."),
        refine_intrinsics: str = typer.Option("auto", "--refine-intrinsics",
                                              help="auto | none | focal | focal+center: estimate the focal length "
                                                   "(and principal point) with the pose; auto: only where the "
                                                   "detections constrain it and disagree with the given one."),
        time_offset: str = typer.Option("none", "--time-offset",
                                        help="none | auto | estimate | SECONDS: camera-minus-LiDAR time offset; "
                                             "auto/estimate fit it from moving objects (auto falls back to none "
                                             "when not observable, estimate refuses)."),
        lidar_frame: str = typer.Option(None, "--lidar-frame", help="tf frame of the LiDAR in the outputs "
                                                                    "(default: the recording's cloud header.frame_id, "
                                                                    "else lidar)."),
        camera_frame: list[str] = typer.Option(None, "--camera-frame",
                                               help="tf frame of a camera's optical frame: FRAME (one camera) or "
                                                    "CAMERA=FRAME (repeat); default: the recording's image "
                                                    "header.frame_id, else <camera>_optical_frame."),
        review_max_points: int = typer.Option(0, "--review-max-points", help="Decimate the clouds of review.mcap to "
                                                                             "about N points (0: the whole cloud)."),
        tf_prior: bool = typer.Option(False, "--tf-prior", help="Bags: start from the recording's own tf between the "
                                                                "cloud's and the image's frames (skips bring-up)."),
        as_json: bool = typer.Option(False, "--json", help="Print the result as JSON."),
        force: bool = typer.Option(False, "--force", help="Replace an existing report folder."),
        detect: bool = detect_flag(),
        detector_2d: Path = detector_2d_flag(),
        lidar_mode: str = lidar_mode_flag(),
        cost_term: list[str] = typer.Option(None, "--cost-term",
                                            help="An extra cost term for every fit: NAME or NAME:KEY=VALUE,... "
                                                 "(repeat), registered in the xcalib.cost_terms entry-point group "
                                                 "(built in: pose_prior; see docs/contributing.md)."),
        max_memory: str = typer.Option("1536M", "--max-memory",
                                       help="Most memory the frames may take (e.g. 2G, 1500M; 0: no limit): each "
                                            "frame is read once and only its boxes and the points near them are "
                                            "kept; an input that would need more is refused up front."),
    ) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        from ..calib.api import calibrate
        from ..calib.config import CalibConfig
        from ..formats.export import read_calibration
        from ..io.files import atomic_dir, claim_output
        from ..formats.cameras import read_intrinsics
        from ..site import calibrate_site
        from ..site.calibration import is_frame_id
        from ..site.stream import StreamConfig, parse_memory, stream_views
        from ..viz.review import review_indices
        from ..viz.site_report import site_table, write_site_report

        try:
            selfcal = CalibConfig(refine_intrinsics=refine_intrinsics, time_offset=time_offset,
                                  cost_terms=tuple(cost_term or ()))
        except ValueError as exc:
            raise typer.BadParameter(str(exc), param_hint="--refine-intrinsics / --time-offset / --cost-term") from None
        if max_frames is not None:
            try:
                selfcal = selfcal.replace(max_frames=max_frames or None)
            except ValueError as exc:
                raise typer.BadParameter(str(exc), param_hint="--max-frames") from None
        try:
            offset = selfcal.time_offset if isinstance(selfcal.time_offset, float) else 0.0
            stream_cfg = StreamConfig(max_memory_mb=parse_memory(max_memory), margin_m=0.25 + 40.0 * abs(offset))
        except ValueError as exc:
            raise typer.BadParameter(str(exc), param_hint="--max-memory") from None
        dcfg = detect_request(detect, detector_2d, lidar_mode)  # a bad detector option: said before any frame
        if lidar_frame is not None and not is_frame_id(lidar_frame):
            raise typer.BadParameter(f"{lidar_frame!r} is not a tf frame name (letters, digits, _ . / -)",
                                     param_hint="--lidar-frame")
        if out.exists() and not force and (not out.is_dir() or any(out.iterdir())):
            raise FileExistsError(f"{out} already exists; pass --force to replace it")
        with claim_output(out, "output folder"):  # a second run to the same --out is refused now, not after
            _check_camera_names(camera)
            cams = list(camera or [])
            if intrinsics is not None and len(cams) > 1:
                raise typer.BadParameter("--intrinsics applies to one camera; give one --camera",
                                         param_hint="--intrinsics")
            if prior is not None and len(cams) > 1:
                raise typer.BadParameter("--prior applies to one camera; give one --camera", param_hint="--prior")
            intr = read_intrinsics(intrinsics) if intrinsics is not None else None
            if fisheye not in ("rectify", "keep"):
                raise typer.BadParameter(f"expected rectify or keep, got {fisheye!r}", param_hint="--fisheye")
            views = _open_views(frames, cams, frame_range, limit, intr, (tolerance, fisheye, detect))
            name0 = next(iter(views))
            if len(views) == 1 and intr is None and getattr(views[name0], "intrinsics", None) is None and len(views[name0]) \
                    and views[name0][0].intrinsics is None:
                raise typer.BadParameter(f"{frames} has no intrinsics; pass --intrinsics K.json", param_hint="--intrinsics")
            prior_res = read_calibration(prior) if prior is not None else None  # any format, plugins' too
            if tf_prior and prior is not None:
                raise typer.BadParameter("give --prior or --tf-prior, not both", param_hint="--tf-prior")
            priors = _tf_priors(views, frames) if tf_prior else {}

            cam_frames = _camera_frames(camera_frame, list(views))
            console = Console(stderr=True)
            with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                          console=console, disable=as_json, transient=False) as bar:
                tasks: dict[str, int] = {}

                def progress(stage: str, done: int, total: int) -> None:
                    if stage not in tasks:
                        tasks[stage] = bar.add_task(stage, total=total)
                    bar.update(tasks[stage], completed=done, total=total)

                if dcfg is not None:
                    from .detect_cmd import open_detected

                    views = {k: open_detected(v, dcfg, progress) for k, v in views.items()}
                    for k, v in views.items():
                        if v.replaced:
                            console.print(f"--detect: {k}: the source's own detections in {v.replaced} frame(s) "
                                          "were replaced by xcalib's", markup=False)

                # each frame read once, slimmed to its boxes and the points near them (bounded memory)
                views = stream_views(views, stream_cfg, source=str(frames), progress=progress)

                def run(items, k, stage, prior=None):
                    res = calibrate(items, k, selfcal, prior=prior_res if prior is None else prior, box_model=box_model,
                                    seed=seed, progress=stage)
                    note = None if detect else _mixed_detections_note(items)
                    if note:  # frames disagree on who made their boxes: said, not decided silently
                        console.print(note, markup=False)
                    if detect or _own_detections(items):  # a refusal names weak detections where they are the cause
                        from ..detect import explain_refusal

                        res = explain_refusal(res, items, k)
                    return res

                site, loaded = calibrate_site(views, {name0: intr} if intr is not None else None, source=str(frames),
                                              calibrate=run, progress=progress, lidar_frame=lidar_frame,
                                              camera_frames=cam_frames, priors=priors)
                with atomic_dir(out, overwrite=force) as tmp:  # the whole folder is swapped in at once
                    n_seq = min(len(views[k]) for k in loaded)
                    pick = review_indices(n_seq, review_frames)
                    drawn = {k: views[k].for_report(max_overlays, pick) for k in loaded}  # drawn frames re-read whole
                    paths = write_site_report(tmp, site, drawn, max_overlays=max_overlays, progress=progress,
                                              title=f"xcalib calibrate: {frames}",
                                              review_max_points=review_max_points or None,
                                              review_frames=review_frames)
                paths = paths.relocated(tmp, out)
            _print(site, paths, as_json, site_table)
            if not as_json:
                typer.echo(_review_line(len(pick), n_seq))
            if not as_json:
                for line in _recorded_lines(site):
                    typer.echo(line)
            if not all(c.result.success for c in site.cameras):
                raise typer.Exit(1)


def _detection_origins(frames) -> tuple[int, int]:
    """(frames whose boxes xcalib's own detectors made, frames with boxes from elsewhere), over every
    frame (``Frame.detections``; a frame without boxes counts for neither)."""
    from ..types import OWN_DETECTIONS

    own = other = 0
    for f in frames:
        made = getattr(f, "detections", None)
        if made is not None and made.source == OWN_DETECTIONS:
            own += 1
        elif len(f.bboxes_2d) or len(f.bboxes_3d):
            other += 1
    return own, other


def _own_detections(frames) -> bool:
    """Some of the frames' boxes were made by xcalib's own detectors (a bag `xcalib detect` wrote),
    decided from every frame: a refusal then names the detections where they are the cause (the
    verdict is the calibration's either way)."""
    return _detection_origins(frames)[0] > 0


def _mixed_detections_note(frames) -> str | None:
    """A line when the frames disagree: some carry xcalib detect's boxes, others boxes from elsewhere."""
    own, other = _detection_origins(frames)
    if not (own and other):
        return None
    return (f"note: {own} frame(s) hold boxes made by `xcalib detect` and {other} frame(s) boxes from elsewhere "
            "(a recording joined from two sources?); a refusal is explained as for xcalib's own detections")


def _check_camera_names(cameras) -> None:
    """Each --camera once: a name given twice would calibrate one camera twice into one folder."""
    seen = set()
    for c in cameras or []:
        if c in seen:
            raise typer.BadParameter(f"camera {c!r} is given twice", param_hint="--camera")
        seen.add(c)


def _open_views(source: Path, cams: list[str], frame_range, limit: int, intr, bag_options: tuple) -> dict:
    """camera name -> its frames (lazy), for each ``--camera`` (or the source's default camera);
    ``bag_options`` = (tolerance_s, fisheye, detect) for a bag (``detect``: read without its
    detection topics, which xcalib.detect makes)."""
    from ..io.sources import find_source, open_source

    if frame_range is None and limit > 0:
        frame_range = f"0:{limit}"
    options = {}
    if find_source(source).name == "bag":
        options["tolerance_s"], fisheye, detect = bag_options
        if detect:
            options["detections"] = False
        if fisheye != "rectify":
            options["fisheye"] = fisheye
        if intr is not None:
            options["intrinsics"] = intr
    views = {}
    try:
        for c in cams or [None]:
            seq = open_source(source, camera=c, frames=frame_range, **options)
            if len(seq) == 0:
                raise typer.BadParameter(f"{source}: no frames found", param_hint="SOURCE")
            own = getattr(seq, "camera", None)  # a source's camera attribute (KITTI's is the camera number)
            name = c or (own if isinstance(own, str) and own else "") or seq[0].camera_name or "camera"
            if name in views:  # two cameras of one name: never drop one silently
                raise typer.BadParameter(f"{source}: two cameras resolve to the name {name!r}; name each by its "
                                         "image topic (--camera /ns/image)", param_hint="--camera")
            views[name] = seq
    except ValueError as exc:
        if isinstance(exc, FormatError):
            raise
        raise typer.BadParameter(str(exc), param_hint="--frames") from None
    return views


def _camera_frames(values: list[str] | None, cams: list[str]) -> dict[str, str]:
    """--camera-frame FRAME (one camera) / CAMERA=FRAME -> {camera: frame}."""
    from ..site.calibration import is_frame_id

    out = {}
    for v in values or []:
        cam, sep, frame = v.rpartition("=")
        if not sep:
            if len(cams) != 1:
                raise typer.BadParameter(f"{v!r}: with several cameras write CAMERA=FRAME", param_hint="--camera-frame")
            cam = cams[0]
        if cam not in cams or not frame:
            raise typer.BadParameter(f"{v!r}: cameras are {', '.join(cams)}", param_hint="--camera-frame")
        if not is_frame_id(frame):
            raise typer.BadParameter(f"{frame!r} is not a tf frame name (letters, digits, _ . / -)",
                                     param_hint="--camera-frame")
        out[cam] = frame
    return out


def _tf_priors(views: dict, source) -> dict:
    """camera -> the recording's own T_cam_lidar (its tf), for --tf-prior; refused when a camera has none."""
    out = {}
    for name, seq in views.items():
        T = getattr(seq, "tf_T_cam_lidar", None)
        if T is None:
            frames = (getattr(seq, "lidar_frame_id", "?"), getattr(seq, "camera_frame_id", "?"))
            raise typer.BadParameter(f"{source}: camera {name}: the recording has no tf between the cloud's frame "
                                     f"{frames[0]!r} and the image's {frames[1]!r}", param_hint="--tf-prior")
        out[name] = T
    return out


def _review_line(n_review: int, n_frames: int) -> str:
    """What review.mcap holds: every frame, or a sample spread over the recording (and how to get all)."""
    if n_review >= n_frames:
        return f"review.mcap holds all {n_frames} frame(s) of the recording (open it in Foxglove)"
    return (f"review.mcap holds {n_review} of the recording's {n_frames} frames, spread evenly from the first "
            "to the last (--review-frames 0: every frame)")


def _recorded_lines(site) -> list[str]:
    """One line per camera whose recording holds its own tf: how far it is from this calibration."""
    out = []
    for c in site.cameras:
        d = c.vs_recorded
        if d is not None:
            out.append(f"camera {c.camera}: the recording's tf ({site.lidar_frame} -> {c.child_frame}) is "
                       f"{d[0]:.2f} deg / {d[1]:.3f} m from this calibration")
    return out


def _print(site, paths, as_json: bool, site_table) -> None:
    from ..viz.advice import plain_advice

    if len(site.cameras) == 1:
        result = site.cameras[0].result
        if as_json:
            typer.echo(json.dumps(result.to_dict(), indent=2))
            return
        summary = next(iter(paths.cameras.values()))
        typer.echo(summary.read_text())
        typer.echo("\n".join(plain_advice(result)) + "\n")
        typer.echo(f"wrote {summary.parent / 'calibration.json'}, {paths.site_json}, {paths.review_mcap} "
                   f"and {len(paths.ros)} ROS file(s) under {paths.site_json.parent / 'ros'}")
        typer.echo(f"report: {paths.html}")
        return
    if as_json:
        typer.echo(json.dumps(json.loads(paths.site_json.read_text()), indent=1))
        return
    typer.echo("\n".join(site_table(site)))
    for c in site.cameras:
        typer.echo("\n".join([f"camera {c.camera}:"] + ["  " + line for line in plain_advice(c.result)]))
    typer.echo(f"wrote {paths.site_json}, {paths.review_mcap}, ros/ ({len(paths.ros)} files) and one folder per camera")
    typer.echo(f"report: {paths.html}")
