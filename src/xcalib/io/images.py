"""Images: files and encoded bytes <-> ``[H, W, 3]`` uint8 **RGB** arrays (OpenCV underneath).

Grayscale is replicated to three channels, alpha is dropped, 16-bit images are scaled to
8 bits. Failures raise :class:`xcalib.errors.FormatError` naming the file (a missing file is a
``FileNotFoundError``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import FormatError
from .files import atomic_write, read_bytes

__all__ = ["read_image", "decode_image", "encode_image", "encode_jpeg", "write_image", "image_header_size",
           "MAX_IMAGE_PIXELS", "MAX_IMAGE_FILE_BYTES"]

#: Largest image (width x height) any reader decodes: 100 Mpx (a 20000x20000 PNG is refused
#: from its header, before OpenCV allocates 1.2 GB).
MAX_IMAGE_PIXELS = 100_000_000
#: largest image file read (bytes)
MAX_IMAGE_FILE_BYTES = 512 << 20
_SOF = (0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF)


def image_header_size(buf: bytes) -> tuple[int, int] | None:
    """(width, height) from a PNG IHDR or the first JPEG SOF marker; None for other data."""
    if buf[:8] == b"\x89PNG\r\n\x1a\n" and len(buf) >= 24:
        return int.from_bytes(buf[16:20], "big"), int.from_bytes(buf[20:24], "big")
    if buf[:2] == b"\xff\xd8":
        i = 2
        while i + 9 < len(buf):
            if buf[i] != 0xFF:
                return None
            marker = buf[i + 1]
            if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7 or marker == 0xFF:
                i += 1 if marker == 0xFF else 2
                continue
            seg = int.from_bytes(buf[i + 2:i + 4], "big")
            if marker in _SOF:
                return int.from_bytes(buf[i + 7:i + 9], "big"), int.from_bytes(buf[i + 5:i + 7], "big")
            i += 2 + seg
    return None


def _to_rgb(img: np.ndarray, source) -> np.ndarray:
    import cv2

    if img.dtype == np.uint16:
        img = ((img.astype(np.uint32) + 128) // 257).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise FormatError(source, f"unsupported image sample type {img.dtype}; expected 8- or 16-bit")
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    channels = img.shape[2]
    if channels == 1:
        return cv2.cvtColor(img[:, :, 0], cv2.COLOR_GRAY2RGB)
    if channels == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    if channels == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    raise FormatError(source, f"unsupported channel count {channels}; expected 1, 3 or 4")


def decode_image(data: bytes | bytearray | memoryview | np.ndarray, *, source=None) -> np.ndarray:
    """Decode PNG/JPEG (any format OpenCV reads) bytes to ``[H, W, 3]`` uint8 RGB.

    ``source`` names the origin in error messages (a path, an HDF5 dataset, ...).
    """
    import cv2

    buf = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data.reshape(-1).view(np.uint8)
    if buf.size == 0:
        raise FormatError(source, "image data is empty (0 bytes)")
    size = image_header_size(buf[:1 << 20].tobytes())
    if size is not None and size[0] * size[1] > MAX_IMAGE_PIXELS:
        raise FormatError(source, f"image header declares {size[0]}x{size[1]} = {size[0] * size[1]} pixels; the limit "
                                  f"is {MAX_IMAGE_PIXELS}", field="size")
    try:
        img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    except (cv2.error, MemoryError) as exc:
        raise FormatError(source, f"could not decode {buf.size} bytes as an image ({type(exc).__name__})") from None
    if img is not None and img.ndim >= 2 and img.shape[0] * img.shape[1] > MAX_IMAGE_PIXELS:
        raise FormatError(source, f"image is {img.shape[1]}x{img.shape[0]} pixels; the limit is {MAX_IMAGE_PIXELS}",
                          field="size")
    if img is None or img.size == 0:
        raise FormatError(source, f"could not decode {buf.size} bytes as an image (PNG/JPEG expected; "
                                  "truncated or corrupt?)")
    return _to_rgb(img, source)


def read_image(path) -> np.ndarray:
    """Read a PNG/JPEG file as ``[H, W, 3]`` uint8 RGB."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"image file not found: {p}")
    return decode_image(read_bytes(p, max_bytes=MAX_IMAGE_FILE_BYTES, what="image file"), source=p)


def _check_rgb(rgb, name: str = "image") -> np.ndarray:
    a = np.asarray(rgb)
    if a.ndim == 2:
        a = np.repeat(a[:, :, None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(f"{name}: expected an [H, W, 3] RGB array, got shape {a.shape}")
    if a.dtype != np.uint8:
        raise ValueError(f"{name}: expected dtype uint8 (0-255), got {a.dtype}")
    return a


def encode_image(rgb, ext: str = ".png", *, quality: int = 90) -> bytes:
    """Encode ``[H, W, 3]`` uint8 RGB to bytes of the format of ``ext`` (.png / .jpg)."""
    import cv2

    a = _check_rgb(rgb)
    ext = ext if ext.startswith(".") else "." + ext
    params = []
    if ext.lower() in (".jpg", ".jpeg"):
        if not 1 <= int(quality) <= 100:
            raise ValueError(f"JPEG quality must be in [1, 100], got {quality}")
        params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)]
    ok, enc = cv2.imencode(ext, cv2.cvtColor(np.ascontiguousarray(a), cv2.COLOR_RGB2BGR), params)
    if not ok:
        raise ValueError(f"OpenCV could not encode the image as {ext}")
    return enc.tobytes()


def encode_jpeg(rgb, quality: int = 90) -> bytes:
    """``[H, W, 3]`` uint8 RGB -> JPEG bytes."""
    return encode_image(rgb, ".jpg", quality=quality)


def write_image(path, rgb, *, quality: int = 90) -> Path:
    """Write ``[H, W, 3]`` uint8 RGB to ``path`` (format from the extension), atomically."""
    p = Path(path)
    if not p.suffix:
        raise ValueError(f"write_image: {p} has no extension (expected .png or .jpg)")
    atomic_write(p, [encode_image(rgb, p.suffix, quality=quality)])
    return p
