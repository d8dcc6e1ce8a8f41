"""``xcalib detect``: 2D and 3D detections for a recording that has none, written as a bag/MCAP
with standard vision_msgs topics (xcalib.detect)."""

from __future__ import annotations

from pathlib import Path

import typer

from ..errors import FormatError

_HELP = (
    "Detect objects in every frame of SOURCE and write them, with the sensor data, to OUT.\n\n"
    "Camera: the shipped YOLOX-Nano (COCO, Apache-2.0) with ONNX Runtime on the CPU, or your own ONNX detector "
    "(--detector-2d; YOLOX, YOLOv5 or YOLOv8 output layout). LiDAR: label-free boxes from the clouds (ground "
    "removal, background model for a static LiDAR, clustering, oriented boxes).\n\n"
    "OUT (.bag, .db3 or .mcap) holds the images, CameraInfo and clouds of SOURCE with "
    "vision_msgs/Detection2DArray and Detection3DArray stamped like their sensor messages: xcalib calibrate OUT "
    "reads it as it is (xcalib calibrate SOURCE --detect skips the file). SOURCE is any frame source (a bag "
    "without detection topics, a frame folder, KITTI, ...); a source's own boxes are replaced. Needs the onnx "
    "extra of xcalib (onnx, onnxruntime).\n\n"
    "Example: xcalib detect raw.mcap --out detected.mcap\n\n"
    "Example: xcalib detect ../shared/data/a9_sample --out a9_detected.mcap --lidar-mode moving\n"
)


def detect_options(detector_2d, classes_file, score_min, input_size, lidar_mode):
    """A DetectConfig from the command-line options (shared with ``calibrate --detect``)."""
    from ..detect import DetectConfig, Detector2DConfig, LidarDetectConfig

    classes = None
    if classes_file is not None:
        classes = tuple(s.strip() for s in Path(classes_file).read_text().splitlines() if s.strip())
    try:
        cam = Detector2DConfig(score_min=score_min, input_long_side=input_size)
        lid = LidarDetectConfig(mode=lidar_mode)
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--score-min / --input-size / --lidar-mode") from None
    return DetectConfig(camera=cam, lidar=lid, detector_2d=None if detector_2d is None else str(detector_2d),
                        classes_2d=classes)


def detect_flag():
    """``--detect`` of ``calibrate`` and ``calibrate-many`` (one help text, one meaning)."""
    return typer.Option(False, "--detect", help="Make the detections with xcalib's detectors (shipped YOLOX-Nano + "
                                                "label-free LiDAR boxes), replacing any the source has; see "
                                                "`xcalib detect`.")


def detector_2d_flag():
    return typer.Option(None, "--detector-2d", help="With --detect: your ONNX 2D detector.")


def lidar_mode_flag():
    return typer.Option("auto", "--lidar-mode", help="With --detect: auto | static | moving.")


def detect_request(detect: bool, detector_2d, lidar_mode: str):
    """The DetectConfig of ``--detect`` / ``--detector-2d`` / ``--lidar-mode`` (``calibrate`` and
    ``calibrate-many``), None without ``--detect``; checked before any frame is read: a bad
    ``--lidar-mode``, a ``--detector-2d`` that is not a file, or either without ``--detect`` is a
    usage error."""
    if not detect:
        if detector_2d is not None or lidar_mode != "auto":
            raise typer.BadParameter("--detector-2d and --lidar-mode apply only with --detect",
                                     param_hint="--detector-2d / --lidar-mode")
        return None
    if detector_2d is not None and not Path(detector_2d).is_file():
        raise typer.BadParameter(f"{detector_2d}: no such file", param_hint="--detector-2d")
    return detect_options(detector_2d, None, 0.3, 1280, lidar_mode)


def open_detected(seq, config, progress=None):
    """``seq`` with xcalib's detections (DetectedFrames), every frame detected now."""
    from ..detect import DetectedFrames

    return DetectedFrames(seq, config, progress=progress).run(progress)


def register(app: typer.Typer) -> None:
    @app.command("detect", help=_HELP)
    def detect_command(
        source: Path = typer.Argument(..., metavar="SOURCE", help="Frame source (bag, folder, ...)."),
        out: Path = typer.Option(..., "--out", "-o", help="Output .bag, .db3 or .mcap (written atomically)."),
        camera: str = typer.Option(None, "--camera", "-c", help="Camera (default: the source's only one)."),
        frame_range: str = typer.Option(None, "--frames", help="Frames: 0:8, 0,3,5, 8: (indices)."),
        intrinsics: Path = typer.Option(None, "--intrinsics", "-k", help="Bags: intrinsics when the bag has no "
                                        "CameraInfo: JSON (with or without a camera \"model\") or a CameraInfo / Kalibr / OpenCV camera file "
                                        "(one camera of a Kalibr camchain: FILE#cam1)."),
        tolerance: float = typer.Option(0.05, "--tolerance", help="Bags: largest LiDAR/image stamp difference (s)."),
        detector_2d: Path = typer.Option(None, "--detector-2d", help="Your ONNX detector (default: the shipped "
                                                                     "YOLOX-Nano)."),
        classes_file: Path = typer.Option(None, "--classes", help="Class names of --detector-2d, one a line "
                                                                  "(default: COCO for 80 classes)."),
        score_min: float = typer.Option(0.3, "--score-min", help="Smallest 2D detection score kept."),
        input_size: int = typer.Option(1280, "--input-size", help="Detector input long side, pixels (multiple of "
                                                                  "32; models with a free input size)."),
        lidar_mode: str = typer.Option("auto", "--lidar-mode", help="auto | static (roadside: background model) | "
                                                                    "moving (ground removal + clustering)."),
        image_format: str = typer.Option("raw", "--image-format", help="raw | png | jpeg images in OUT."),
        force: bool = typer.Option(False, "--force", help="Replace an existing OUT."),
    ) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        from ..io.bags import write_bag
        from ..formats.cameras import read_intrinsics

        if out.suffix.lower() not in (".bag", ".db3", ".mcap"):
            raise typer.BadParameter(f"{out.name}: expected a .bag, .db3 or .mcap name", param_hint="--out")
        if out.exists() and not force:
            raise typer.BadParameter(f"{out} exists; pass --force to replace it", param_hint="--out")
        if image_format not in ("raw", "png", "jpeg"):
            raise typer.BadParameter(f"{image_format!r}: choose raw, png or jpeg", param_hint="--image-format")
        config = detect_options(detector_2d, classes_file, score_min, input_size, lidar_mode)
        intr = read_intrinsics(intrinsics) if intrinsics is not None else None
        seq = open_sensors(source, camera, frame_range, intr, tolerance)
        with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      console=Console(stderr=True)) as bar:
            tasks: dict[str, int] = {}

            def progress(stage: str, done: int, total: int) -> None:
                if stage not in tasks:
                    tasks[stage] = bar.add_task(stage, total=total)
                bar.update(tasks[stage], completed=done, total=total)

            det = open_detected(seq, config, progress)
            n = len(det)
            frames = (det[i] for i in range(n))
            path = write_bag(out, frames, image_format=image_format, overwrite=force)
        n2, n3 = det.counts()
        if det.replaced:
            typer.echo(f"the source's own detections in {det.replaced} frame(s) were replaced", err=True)
        typer.echo(f"{n} frame(s): {n2} 2D boxes ({det.detector.path.name}, {det.detector.layout}), {n3} 3D boxes "
                   f"(LiDAR {det.mode})")
        typer.echo(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB); next: xcalib calibrate {path}")


def open_sensors(source: Path, camera, frame_range, intr, tolerance: float):
    """A source's frames for detection: a bag is read without its detection topics (``intr``:
    its intrinsics when it has no CameraInfo)."""
    from ..detect import open_sensors as open_for_detection

    options: dict = {"tolerance_s": tolerance}
    if intr is not None:
        options["intrinsics"] = intr
    try:
        seq = open_for_detection(source, camera, frame_range, **options)
    except ValueError as exc:
        if isinstance(exc, FormatError):
            raise
        raise typer.BadParameter(str(exc), param_hint="--frames") from None
    if len(seq) == 0:
        raise typer.BadParameter(f"{source}: no frames found", param_hint="SOURCE")
    return seq
