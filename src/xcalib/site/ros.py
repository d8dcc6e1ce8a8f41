"""A site calibration as the files a ROS system uses: one tf_static YAML with every camera, the
``static_transform_publisher`` lines (ROS 1 ``rosrun`` and ROS 2 ``ros2 run``), a launch file
for each (ROS 1 XML ``static_transforms.launch``, ROS 2 Python ``static_transforms.launch.py``),
a URDF with each camera's body and optical frames, and a CameraInfo YAML per camera. Refused
cameras are left out (and named in the shell script). Frame names are the site's: the
recording's own ``header.frame_id``s when it had them."""

from __future__ import annotations

import logging
import re
from pathlib import Path

from ..formats.ros import (camera_info_dict, printable, ros_name, static_transform_args, static_transform_command,
                           static_transform_ros1_args, static_transform_ros1_command, tf_static_dict, urdf_joints)
from ..geometry.transforms import invert_transform
from ..io.files import atomic_write
from .calibration import SiteCalibration, camera_folders

__all__ = ["write_site_ros"]

log = logging.getLogger(__name__)


def _yaml_text(d) -> bytes:
    import yaml

    return yaml.safe_dump(d, sort_keys=False).encode()


def _node_name(child: str) -> str:
    """A valid ROS node name (letters, digits, underscores; a letter first) for a publisher."""
    return "xcalib_tf_" + (re.sub(r"[^A-Za-z0-9_]", "_", child).strip("_") or "camera")


def _launch_ros1(edges) -> str:
    from xml.sax.saxutils import quoteattr

    nodes = [f'  <node pkg="tf2_ros" type="static_transform_publisher" name={quoteattr(_node_name(child))}\n'
             f'        args={quoteattr(" ".join(static_transform_ros1_args(T, parent, child)))}/>'
             for parent, child, T in edges]
    return ('<?xml version="1.0"?>\n<!-- xcalib site calibration (ROS 1): roslaunch static_transforms.launch -->\n'
            "<launch>\n" + "\n".join(nodes) + "\n</launch>\n")


def _launch_ros2(edges) -> str:
    nodes = [f"        Node(package='tf2_ros', executable='static_transform_publisher', name={_node_name(child)!r},\n"
             f"             arguments={static_transform_args(T, parent, child)!r}),"
             for parent, child, T in edges]
    return ('"""xcalib site calibration (ROS 2): ros2 launch ./static_transforms.launch.py"""\n\n'
            "from launch import LaunchDescription\nfrom launch_ros.actions import Node\n\n\n"
            "def generate_launch_description():\n    return LaunchDescription([\n" + "\n".join(nodes) + "\n    ])\n")


def _shell(site: SiteCalibration, edges, lidar: str) -> str:
    lines = ["#!/bin/sh", "# xcalib site calibration: each line publishes a camera's OpenCV optical frame",
             printable(f"# (x right, y down, z forward) in the LiDAR frame {lidar!r}."),
             "# sh static_transforms.sh [1|2]: ROS 1 (rosrun) or ROS 2 (ros2 run); default $ROS_VERSION, else 2."]
    # every comment goes through printable() (no newline can end it), every argument through
    # shlex.quote (the *_command helpers): no name or message from the data runs as a command
    lines += [printable(f"# {c.camera}: refused ({c.result.message})") for c in site.cameras if not c.result.success]
    lines += ['ROS="${1:-${ROS_VERSION:-2}}"', 'if [ "$ROS" = "1" ]; then']
    lines += [static_transform_ros1_command(T, parent, child) + " &" for parent, child, T in edges]
    lines += [":"] if not edges else []  # no calibrated camera: an empty branch is a shell syntax error
    lines += ["else"]
    lines += [static_transform_command(T, parent, child) + " &" for parent, child, T in edges]
    lines += [":"] if not edges else []
    lines += ["fi", "wait"]
    return "\n".join(lines) + "\n"


def write_site_ros(site: SiteCalibration, out_dir) -> list[Path]:
    """Write ``tf_static.yaml``, ``static_transforms.sh``, ``static_transforms.launch`` (ROS 1),
    ``static_transforms.launch.py`` (ROS 2), ``site.urdf`` and ``<camera>_camera_info.yaml`` into
    ``out_dir``; returns the files written."""
    out = Path(out_dir)
    ok = [c for c in site.cameras if c.result.success]
    lidar = ros_name(site.lidar_frame, "lidar")  # names read from a recording: valid tf names only
    edges = [(lidar, ros_name(c.child_frame, "camera_optical_frame"), invert_transform(c.result.extrinsics))
             for c in ok]
    written = [atomic_write(out / "tf_static.yaml", [_yaml_text(tf_static_dict(edges))])]
    written.append(atomic_write(out / "static_transforms.sh", [_shell(site, edges, lidar).encode()]))
    written.append(atomic_write(out / "static_transforms.launch", [_launch_ros1(edges).encode()]))
    written.append(atomic_write(out / "static_transforms.launch.py", [_launch_ros2(edges).encode()]))
    body = "\n".join(urdf_joints(c.result.extrinsics, lidar, c.camera, ros_name(c.child_frame)) for c in ok)
    urdf = f'<?xml version="1.0"?>\n<robot name="xcalib_site">\n  <link name="{lidar}"/>\n{body}\n</robot>\n'
    written.append(atomic_write(out / "site.urdf", [urdf.encode()]))
    folders = camera_folders([c.camera for c in site.cameras])  # file names: safe and distinct
    for c in ok:
        if c.result.intrinsics is not None:
            try:
                d = camera_info_dict(c.result.intrinsics, ros_name(c.camera, "camera"),
                                     c.result.image_size or c.image_size)
            except ValueError as exc:  # no image size anywhere (a YAML without it loads in no ROS tool), or
                # a camera model CameraInfo cannot express (the message names the formats that can)
                log.warning("camera %s: no CameraInfo YAML written (%s)", c.camera, exc)
                continue
            written.append(atomic_write(out / f"{folders[c.camera]}_camera_info.yaml", [_yaml_text(d)]))
    return written
