"""Image I/O: RGB order, grayscale/RGBA/16-bit conversion, JPEG encoding, clear errors."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from conftest import shared_path
from xcalib.errors import FormatError
from xcalib.io.images import decode_image, encode_image, encode_jpeg, read_image, write_image


def _rgb(rng, h=24, w=32):
    return rng.integers(0, 256, size=(h, w, 3), dtype=np.uint8)


def test_png_round_trip_is_exact_and_rgb_ordered(tmp_path, rng):
    img = _rgb(rng)
    write_image(tmp_path / "a.png", img)
    np.testing.assert_array_equal(read_image(tmp_path / "a.png"), img)
    # OpenCV itself sees BGR on disk: channel 0 on disk is our blue
    on_disk = cv2.imread(str(tmp_path / "a.png"), cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(on_disk[..., 0], img[..., 2])


def test_pure_red_stays_red_through_jpeg(rng):
    img = np.zeros((16, 16, 3), np.uint8)
    img[..., 0] = 255
    out = decode_image(encode_jpeg(img, quality=95))
    assert out.shape == (16, 16, 3) and out.dtype == np.uint8
    assert out[..., 0].min() > 240 and out[..., 1:].max() < 15


def test_jpeg_quality_changes_size_and_is_checked(rng):
    img = _rgb(rng, 64, 64)
    assert len(encode_jpeg(img, quality=30)) < len(encode_jpeg(img, quality=95))
    with pytest.raises(ValueError, match="quality"):
        encode_jpeg(img, quality=0)


def test_grayscale_rgba_and_16bit_files_become_rgb_uint8(tmp_path, rng):
    gray = rng.integers(0, 256, size=(10, 12), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "g.png"), gray)
    g = read_image(tmp_path / "g.png")
    assert g.shape == (10, 12, 3)
    np.testing.assert_array_equal(g[..., 1], gray)
    bgra = rng.integers(0, 256, size=(10, 12, 4), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "a.png"), bgra)
    np.testing.assert_array_equal(read_image(tmp_path / "a.png"), bgra[..., [2, 1, 0]])
    deep = (gray.astype(np.uint16) * 257)
    cv2.imwrite(str(tmp_path / "d.png"), deep)
    np.testing.assert_array_equal(read_image(tmp_path / "d.png")[..., 0], gray)


def test_missing_image_raises_file_not_found_naming_it(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.png"):
        read_image(tmp_path / "missing.png")


def test_corrupt_and_empty_images_are_format_errors(tmp_path, rng):
    data = encode_image(_rgb(rng), ".png")
    (tmp_path / "trunc.png").write_bytes(data[:20])
    with pytest.raises(FormatError, match="could not decode") as ei:
        read_image(tmp_path / "trunc.png")
    assert ei.value.path.endswith("trunc.png")
    (tmp_path / "empty.jpg").write_bytes(b"")
    with pytest.raises(FormatError, match="empty"):
        read_image(tmp_path / "empty.jpg")
    with pytest.raises(FormatError, match="<input>"):
        decode_image(b"not an image at all")


def test_encoding_rejects_wrong_shapes_and_dtypes(tmp_path):
    with pytest.raises(ValueError, match=r"\[H, W, 3\]"):
        encode_jpeg(np.zeros((4, 4, 4), np.uint8))
    with pytest.raises(ValueError, match="uint8"):
        write_image(tmp_path / "f.png", np.zeros((4, 4, 3), np.float32))
    assert not (tmp_path / "f.png").exists()


@pytest.mark.shared_data
def test_a9_png_decodes_to_full_hd_rgb():
    img = read_image(shared_path("a9_sample", "frame_0000", "image.png"))
    assert img.shape == (1200, 1920, 3) and img.dtype == np.uint8
