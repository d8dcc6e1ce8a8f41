"""A site calibration as the files a ROS system uses: one tf_static YAML with every camera, the
``static_transform_publisher`` lines, a URDF with each camera's body and optical frames, and a
CameraInfo YAML per camera. Refused cameras are left out (and named in the shell script)."""

from __future__ import annotations

from pathlib import Path

from ..formats.ros import camera_info_dict, printable, ros_name, static_transform_command, tf_static_dict, urdf_joints
from ..geometry.transforms import invert_transform
from ..io._files import atomic_write
from .calibration import SiteCalibration, camera_folders, optical_frame

__all__ = ["write_site_ros"]


def _yaml_text(d) -> bytes:
    import yaml

    return yaml.safe_dump(d, sort_keys=False).encode()


def write_site_ros(site: SiteCalibration, out_dir) -> list[Path]:
    """Write ``tf_static.yaml``, ``static_transforms.sh``, ``site.urdf`` and
    ``<camera>_camera_info.yaml`` into ``out_dir``; returns the files written."""
    out = Path(out_dir)
    ok = [c for c in site.cameras if c.result.success]
    lidar = ros_name(site.lidar_frame, "lidar")  # names read from a recording: valid ROS names only
    edges = [(lidar, optical_frame(c.camera), invert_transform(c.result.extrinsics)) for c in ok]
    written = [atomic_write(out / "tf_static.yaml", [_yaml_text(tf_static_dict(edges))])]
    lines = ["#!/bin/sh", "# xcalib site calibration: each line publishes a camera's OpenCV optical frame",
             f"# (<camera>_optical_frame: x right, y down, z forward) in the LiDAR frame {lidar!r}."]
    # every comment goes through printable() (no newline can end it), every argument through
    # shlex.quote (static_transform_command): no name or message from the data runs as a command
    lines += [printable(f"# {c.camera}: refused ({c.result.message})") for c in site.cameras if not c.result.success]
    lines += [static_transform_command(T, parent, child) + " &" for parent, child, T in edges] + ["wait"]
    written.append(atomic_write(out / "static_transforms.sh", ["\n".join(lines).encode() + b"\n"]))
    body = "\n".join(urdf_joints(c.result.extrinsics, lidar, c.camera) for c in ok)
    urdf = f'<?xml version="1.0"?>\n<robot name="xcalib_site">\n  <link name="{lidar}"/>\n{body}\n</robot>\n'
    written.append(atomic_write(out / "site.urdf", [urdf.encode()]))
    folders = camera_folders([c.camera for c in site.cameras])
    for c in ok:
        if c.result.intrinsics is not None:
            d = camera_info_dict(c.result.intrinsics, ros_name(c.camera, "camera"))
            written.append(atomic_write(out / f"{folders[c.camera]}_camera_info.yaml", [_yaml_text(d)]))
    return written
