"""Image / point-cloud loading for the dataset readers (thin wrappers over :mod:`xcalib.io`)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

__all__ = ["load_rgb", "image_size", "load_cloud", "IMAGE_EXTS"]

IMAGE_EXTS = (".png", ".jpg", ".jpeg")


def load_rgb(path) -> np.ndarray:
    """[H,W,3] uint8 RGB."""
    from ..io.images import read_image

    return read_image(path)


def image_size(path) -> tuple[int, int]:
    """(width, height) in pixels read from a PNG/JPEG header (full decode only as a fallback)."""
    from ..io.files import open_regular

    p = Path(path)
    with open_regular(p, what="image file") as fh:
        head = fh.read(1 << 16)
    if head[:8] == b"\x89PNG\r\n\x1a\n":
        return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    if head[:2] == b"\xff\xd8":  # walk JPEG segments to the first SOFn
        i = 2
        while i + 9 < len(head):
            if head[i] != 0xFF:
                break
            marker = head[i + 1]
            seg = struct.unpack(">H", head[i + 2:i + 4])[0]
            if marker in (0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF):
                h, w = struct.unpack(">HH", head[i + 5:i + 9])
                return int(w), int(h)
            i += 2 + seg
    img = load_rgb(p)
    return int(img.shape[1]), int(img.shape[0])


def load_cloud(path, columns=None):
    """``(points [P,C] float32, field names)`` of a .pcd / .bin / .npy file (LiDAR frame, metres)."""
    from ..io.pointcloud import read_point_cloud

    pc = read_point_cloud(path, columns=columns)
    return pc.points, tuple(pc.fields)
