"""``xcalib convert``: between calibration file formats (see ``xcalib.formats.export``)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import typer

_EX = ("Example: xcalib convert cam03/lucid_calib.json --to calib_json --out calib.json\n\n"
       "Formats: kitti, calib_json, lucid, calib_txt, opencalib, openlabel, ros, urdf, tf_static, nuscenes, json, npz "
       "(waymo .tfrecord and mmdetection3d KITTI .pkl as input only). Every reader returns and every "
       "writer takes T_cam_lidar (LiDAR -> OpenCV camera); each format's own direction is documented "
       "in xcalib.formats.")


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
                                                                   "store it (ros CameraInfo) when the input has none."),
        as_json: bool = typer.Option(False, "--json", help="Machine-readable output."),
        force: bool = typer.Option(False, "--force", help="Replace existing output file(s)."),
    ) -> None:
        from ..formats.export import FORMATS, default_filename, detect_format, export_calibration, read_calibration

        if to not in FORMATS or FORMATS[to].write is None:
            writable = ", ".join(n for n, f in FORMATS.items() if f.write is not None)
            raise typer.BadParameter(f"unknown or read-only output format {to!r}; choose one of: {writable}",
                                     param_hint="--to")
        fmt_in = src_format or detect_format(src)
        result = read_calibration(src, fmt_in, repair=repair)
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


def _size(text: str) -> tuple[int, int]:
    parts = text.lower().split("x")
    try:
        w, h = (int(v) for v in parts)
    except ValueError:
        w = h = 0
    if len(parts) != 2 or w <= 0 or h <= 0:
        raise typer.BadParameter(f"{text!r}: expected WIDTHxHEIGHT, e.g. 1920x1200", param_hint="--image-size")
    return w, h
