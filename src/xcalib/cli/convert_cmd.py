"""``xcalib convert``: between calibration file formats (see ``xcalib.formats.export``)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import typer

from ..errors import FormatError

_EX = ("Example: xcalib convert ../shared/data/calibanything/format_examples/lucid_calib.json --to calib_json "
       "--out calib.json\n\n"
       "Formats: kitti, calib_json, lucid, calib_txt, opencalib, openlabel, ros, urdf, tf_static, nuscenes, json, npz "
       "(waymo .tfrecord, mmdetection3d KITTI .pkl and SUSTechPOINTS calib/camera/<cam>.json as input only). Every reader returns and every "
       "writer takes T_cam_lidar (LiDAR -> OpenCV camera); each format's own direction is documented "
       "in xcalib.formats.\n\n"
       "Camera files (intrinsics only, the camera model kept): --to camera_info | kalibr | opencv_yaml | "
       "opencv_json | intrinsics_json, from any of them, e.g. xcalib convert camchain.yaml --to camera_info "
       "--camera cam0 --out fisheye.yaml; a model the target cannot express is refused.\n\n"
       "Installed packages add formats through the entry-point group xcalib.formats (detected on read by "
       "their sniff()).")


def register(app: typer.Typer) -> None:
    @app.command("convert", help=f"Convert a camera-LiDAR calibration file to another format.\n\n{_EX}")
    def convert(
        src: Path = typer.Argument(..., help="Input calibration file (or nuScenes table / OpenCalib folder)."),
        to: str = typer.Option(..., "--to", "-t", help="Output format name."),
        out: Path = typer.Option(None, "--out", "-o", help="Output path (default: the format's usual file "
                                                           "name next to the input)."),
        src_format: str = typer.Option(None, "--from", "-f", help="Input format (default: detected)."),
        repair: bool = typer.Option(False, "--repair", help="Fix unambiguous problems: re-orthonormalise "
                                                            "rotations off by <= 1e-3, normalise quaternions."),
        image_size: str = typer.Option(None, "--image-size", help="WIDTHxHEIGHT of the images, for formats that "
                                                                   "store it (ros / camera_info CameraInfo) when the "
                                                                   "input has none."),
        as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
        force: bool = typer.Option(False, "--force", help="Replace existing output file(s)."),
        camera: str = typer.Option(None, "--camera", help="Camera files: which camera of a Kalibr camchain "
                                                          "(cam0, cam1, ...)."),
    ) -> None:
        from ..formats.cameras import CAMERA_FORMATS

        if to in CAMERA_FORMATS:
            size = None if image_size is None else _size(image_size)
            _convert_camera(src, to, out, src_format, camera, size, as_json=as_json, force=force)
            return
        from ..formats.export import calib_formats, default_filename, detect_format, export_calibration, read_calibration

        formats = calib_formats()  # xcalib's own and the installed plugins' (xcalib.formats)
        if to not in formats or formats[to].write is None:
            writable = ", ".join(n for n, f in formats.items() if f.write is not None)
            raise typer.BadParameter(f"unknown or read-only output format {to!r}; choose one of: {writable}",
                                     param_hint="--to")
        try:
            fmt_in = src_format or detect_format(src)
            result = read_calibration(src, fmt_in, repair=repair)
        except FormatError as exc:
            cam_fmt = None if src_format is not None else _camera_file_format(src)
            if cam_fmt is None:
                raise
            raise FormatError(src, f"a camera file ({cam_fmt}: intrinsics only, no LiDAR pose) cannot become a "
                                   f"calibration ({to}); convert it --to a camera format ({', '.join(CAMERA_FORMATS)})"
                                   f" [reading it as a calibration: {exc}]") from None
        if image_size is not None:
            result = dataclasses.replace(result, image_size=_size(image_size))
        if out is None:
            base = src if src.is_dir() else src.parent
            out = base / default_filename(to)
        if out.exists() and src.exists() and out.resolve() == src.resolve():
            raise typer.BadParameter(f"output {out} would overwrite the input; give --out", param_hint="--out")
        written = export_calibration(result, to, out, overwrite=force)
        if as_json:
            typer.echo(json.dumps({"input": str(src), "from": fmt_in, "to": to, "written": [str(p) for p in written],
                                   "T_cam_lidar": result.extrinsics.tolist(),
                                   "intrinsics": None if result.intrinsics is None else result.intrinsics.to_dict()}))
            return
        t = result.translation
        typer.echo(f"{src} ({fmt_in}) -> {to}")
        typer.echo(f"  T_cam_lidar translation (m) = [{t[0]:+.4f}, {t[1]:+.4f}, {t[2]:+.4f}]")
        for p in written:
            typer.echo(f"  wrote {p}")


def _camera_file_format(src: Path) -> str | None:
    """The camera format of ``src`` when it is a camera file other than a CameraInfo (which is also a
    calibration format, with its transform), else None."""
    from ..formats.cameras import detect_camera_format

    try:
        fmt = detect_camera_format(src) if src.is_file() else None
    except (FormatError, OSError, ValueError):
        return None
    return fmt if fmt in ("kalibr", "opencv_yaml", "opencv_json", "intrinsics_json") else None


def _size(text: str) -> tuple[int, int]:
    parts = text.lower().split("x")
    try:
        w, h = (int(v) for v in parts)
    except ValueError:
        w = h = 0
    if len(parts) != 2 or w <= 0 or h <= 0:
        raise typer.BadParameter(f"{text!r}: expected WIDTHxHEIGHT, e.g. 1920x1200", param_hint="--image-size")
    return w, h


def _convert_camera(src: Path, to: str, out: Path | None, src_format: str | None, camera: str | None,
                    size: tuple[int, int] | None, *, as_json: bool, force: bool) -> None:
    from ..formats.cameras import (CAMERA_FORMATS, UnsupportedModelError, detect_camera_format, read_camera,
                                   split_camera_ref, write_camera)

    if src_format is not None and src_format not in CAMERA_FORMATS:
        raise typer.BadParameter(f"a camera file converts from {', '.join(CAMERA_FORMATS)}, not {src_format!r}",
                                 param_hint="--from")
    from ..errors import FormatError

    try:  # camchain.yaml#cam1 names the camera as --camera cam1 does
        src, camera = split_camera_ref(src, camera)
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="SOURCE / --camera") from None
    fmt_in = src_format or detect_camera_format(src)
    try:
        cam = read_camera(src, fmt_in, camera=camera)
    except FormatError:
        if src_format is not None:
            raise
        cam, fmt_in = _calibration_camera(src) or (None, fmt_in)
        if cam is None:
            raise
    if size is not None:
        cam = dataclasses.replace(cam, width=size[0], height=size[1])
    if to == "camera_info" and (cam.width is None or cam.height is None):
        # camera_calibration_parsers (ROS) will not load a CameraInfo YAML without them
        raise typer.BadParameter(f"{src}: a CameraInfo YAML needs image_width and image_height, and the "
                                 "input does not hold the image size; pass --image-size WIDTHxHEIGHT",
                                 param_hint="--image-size")
    if out is None:
        out = src.with_name(f"{src.stem}_{to}{'.json' if to.endswith('json') else '.yaml'}")
    if out.exists() and src.exists() and out.resolve() == src.resolve():
        raise typer.BadParameter(f"output {out} would overwrite the input; give --out", param_hint="--out")
    try:
        write_camera(cam, out, to, camera_name=camera or "camera", overwrite=force)
    except UnsupportedModelError as exc:
        raise typer.BadParameter(str(exc), param_hint="--to") from None
    if as_json:
        typer.echo(json.dumps({"input": str(src), "from": fmt_in, "to": to, "written": [str(out)],
                               "camera": cam.to_dict()}))
        return
    typer.echo(f"{src} ({fmt_in}) -> {to}: {cam.name} camera")
    typer.echo(f"  wrote {out}")


def _calibration_camera(src: Path):
    """``(camera model, format)`` of the intrinsics in a camera-LiDAR calibration file (lucid,
    OpenCalib, KITTI, ...), for a camera format asked of one; None when it is none or holds none."""
    from ..errors import FormatError
    from ..formats.export import detect_format, read_calibration
    from ..geometry.camera_models import as_camera_model

    try:
        fmt = detect_format(src)
        result = read_calibration(src, fmt)
    except (FormatError, ValueError, KeyError, OSError):
        return None
    if result.intrinsics is None:
        return None
    return as_camera_model(result.intrinsics), fmt
