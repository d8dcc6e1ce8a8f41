"""``xcalib bag info|frames|write``: ROS 1 / ROS 2 bags and MCAP without ROS (xcalib.io.bags)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

_INFO_EX = "Example: xcalib bag info site.mcap"
_FRAMES_EX = "Example: xcalib bag frames site.mcap --lidar /lidar/points --camera camera --tolerance 0.05"
_WRITE_EX = ("Example: xcalib bag write ../shared/data/nuscenes/mmdet3d_demo/n015-2018-07-24-11-22-45+0800.pkl "
             "nus.mcap --camera CAM_FRONT --camera CAM_BACK")


def register(app: typer.Typer) -> None:
    bag_app = typer.Typer(help="Read ROS 1 .bag, ROS 2 .db3 and .mcap files without ROS.\n\n" + _FRAMES_EX,
                          no_args_is_help=True)
    app.add_typer(bag_app, name="bag")

    @bag_app.command("info", help=f"Topics, message types, counts and rates of a bag.\n\n{_INFO_EX}")
    def info(
        path: Path = typer.Argument(..., help="A .bag, .db3 or .mcap file (or a ROS 2 bag folder)."),
        as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
    ) -> None:
        from ..io.bags import bag_info

        res = bag_info(path)
        typer.echo(json.dumps(res.to_dict(), indent=1) if as_json else "\n".join(res.lines()))

    @bag_app.command("frames", help=f"Show which messages would be paired into frames, and what is dropped and why."
                                    f"\n\n{_FRAMES_EX}")
    def frames(
        path: Path = typer.Argument(..., help="A .bag, .db3 or .mcap file (or a ROS 2 bag folder)."),
        lidar: str = typer.Option(None, "--lidar", help="PointCloud2 topic (default: the only one)."),
        camera: str = typer.Option(None, "--camera", "-c", help="Camera name or image topic (default: the only one)."),
        camera_info: str = typer.Option(None, "--camera-info", help="CameraInfo topic (default: the camera's)."),
        det2d: str = typer.Option(None, "--detections-2d", help="Detection2DArray topic (default: the camera's)."),
        det3d: str = typer.Option(None, "--detections-3d", help="Detection3DArray topic (default: the LiDAR's)."),
        intrinsics: Path = typer.Option(None, "--intrinsics", "-k", help="Intrinsics (JSON, with or without "
                                                                         "a camera \"model\", or a camera file; a Kalibr camchain's camera: "
                                                                         "FILE#cam1) when the bag has no CameraInfo."),
        tolerance: float = typer.Option(0.05, "--tolerance", help="Largest LiDAR/image stamp difference, seconds."),
        fisheye: str = typer.Option("rectify", "--fisheye", help="An equidistant CameraInfo: rectify (to pinhole) | "
                                                                 "keep (the fisheye image, kannala_brandt), as calibrate."),
        as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
    ) -> None:
        from ..formats.cameras import read_intrinsics
        from ..io.bags import BagFrames

        seq = BagFrames(path, camera, lidar=lidar, camera_info=camera_info, detections_2d=det2d,
                        detections_3d=det3d, tolerance_s=tolerance, fisheye=fisheye,
                        intrinsics=None if intrinsics is None else read_intrinsics(intrinsics))
        bad, seen = _undecodable(seq, progress=not as_json)
        if as_json:
            typer.echo(json.dumps({"topics": seq.topics, "camera": seq.camera, "cameras": seq.camera_names,
                                   "frame_keys": seq.frame_keys, **seq.report.to_dict(),
                                   "frames_paired": seq.report.frames, "frames": seq.report.frames - len(bad),
                                   "undecodable": [{"index": i, "frame_key": k, "error": e} for i, k, e in bad],
                                   "camera_model": seen},
                                  indent=1))
        else:
            typer.echo(f"camera {seq.camera} (cameras in the bag: {', '.join(seq.camera_names)})")
            for k, v in seq.topics.items():
                typer.echo(f"  {k:<14} {v}")
            typer.echo("\n".join(seq.report.lines()))
            for d in seq.report.dropped[:20]:
                typer.echo(f"    {d.topic} @ {d.stamp_s:.6f} s: {d.reason}")
            if len(seq.report.dropped) > 20:
                typer.echo(f"    ... {len(seq.report.dropped) - 20} more (--json lists all)")
            typer.echo(f"{seq.report.frames - len(bad)} of {seq.report.frames} paired frame(s) decode")
            if seen:
                typer.echo(f"camera model   {seen}")
            for i, k, e in bad[:20]:
                typer.echo(f"    frame {i} ({k}): {e}")
        if len(bad) == seq.report.frames:
            raise typer.Exit(1)

    @bag_app.command("write", help=f"Write any frame source (one or several cameras) to a .bag, .db3 or .mcap."
                                   f"\n\n{_WRITE_EX}")
    def write(
        source: Path = typer.Argument(..., help="Frame source (frame folder, HDF5, KITTI, nuScenes pickle, ...)."),
        out: Path = typer.Argument(..., help="Output .bag, .db3 or .mcap (written atomically)."),
        camera: list[str] = typer.Option(None, "--camera", "-c", help="Camera(s) to write (repeat); default: the "
                                                                       "source's default camera."),
        frame_range: str = typer.Option(None, "--frames", help="Frames: 0:8, 0,3,5, 8: (indices)."),
        image_format: str = typer.Option("raw", "--image-format", help="raw (Image rgb8) | png | jpeg "
                                                                       "(CompressedImage)."),
        no_detections: bool = typer.Option(False, "--no-detections", help="Sensor topics only (images, CameraInfo, "
                                                                           "clouds), as a raw recording."),
        force: bool = typer.Option(False, "--force", help="Replace an existing output file."),
    ) -> None:
        from ..io.bags import write_bag
        from ..io.sources import merge_cameras, open_source

        if image_format not in ("raw", "png", "jpeg"):
            raise typer.BadParameter(f"{image_format!r}: choose raw, png or jpeg", param_hint="--image-format")
        if out.exists() and not force:
            raise typer.BadParameter(f"{out} exists; pass --force to replace it", param_hint="OUT")
        cams = list(camera or [])
        try:
            views = {c: open_source(source, camera=c, frames=frame_range) for c in cams} or \
                {"": open_source(source, frames=frame_range)}
        except ValueError as exc:
            raise typer.BadParameter(str(exc), param_hint="--frames") from None
        if len(views) > 1:
            frames = merge_cameras(views)
        else:
            seq = next(iter(views.values()))
            frames = (seq[i] for i in range(len(seq)))
        path = write_bag(out, frames, image_format=image_format, overwrite=force, detections=not no_detections)
        typer.echo(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB)")


def _undecodable(seq, progress: bool) -> tuple[list[tuple[int, str, str]], str | None]:
    """Decode every paired frame (one at a time): ``[(index, frame key, error)]`` of those that fail,
    so that the count printed is of frames a calibration can use, not of stamps that pair; and the
    camera model the first decoded frame comes with (:func:`_camera_seen`; None when none decodes)."""
    from rich.console import Console
    from rich.progress import track

    from ..errors import FormatError

    keys, bad, seen = seq.frame_keys, [], None
    for i in track(range(len(seq)), description="decoding frames", disable=not progress, transient=True,
                   console=Console(stderr=True)):
        try:
            f = seq[i]
        except FormatError as exc:
            bad.append((i, keys[i], str(exc)))
        else:
            seen = seen or _camera_seen(f)
    return bad, seen


def _camera_seen(frame) -> str:
    """What camera model the frames come with (a fisheye's rectification said, with how to keep it)."""
    from ..io.bags import rectified_from

    intr = frame.intrinsics
    name = "none" if intr is None else getattr(intr, "name", "pinhole_radtan")
    if rectified_from(frame) == "equidistant":
        return (f"{name}: the CameraInfo is equidistant (fisheye), its images and 2D boxes are rectified to "
                "pinhole; calibrate --fisheye keep calibrates in the fisheye image itself (kannala_brandt)")
    return name
