"""Point-cloud I/O: PCD in all three encodings, .bin, .npy, and every bad-input case."""

from __future__ import annotations

import re
import struct

import lzf
import numpy as np
import pytest

from conftest import shared_path
from xcalib.errors import FormatError
from xcalib.io.pointcloud import PointCloud, load_points, read_point_cloud, write_pcd, write_points

ENCODINGS = ("ascii", "binary", "binary_compressed")


def _cloud(rng, n=200, extra=("intensity", "ring")):
    pts = rng.normal(0, 20, size=(n, 3 + len(extra))).astype(np.float32)
    return pts, ("x", "y", "z", *extra)


def _raw_pcd(fields, sizes, types, counts, columns, *, data="binary", width=None, height=1, points=None):
    """Build PCD bytes by hand (independent of write_pcd). ``columns``: one [P, count] array per field."""
    P = len(columns[0])
    width = P if width is None else width
    points = width * height if points is None else points
    head = (f"# hand-made\nVERSION 0.7\nFIELDS {' '.join(fields)}\nSIZE {' '.join(map(str, sizes))}\n"
            f"TYPE {' '.join(types)}\nCOUNT {' '.join(map(str, counts))}\nWIDTH {width}\nHEIGHT {height}\n"
            f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {points}\nDATA {data}\n").encode()
    dts = [np.dtype({"F": "f", "U": "u", "I": "i"}[t] + str(s)).newbyteorder("<") for t, s in zip(types, sizes)]
    cols = [np.asarray(c, dtype=d).reshape(P, n) for c, d, n in zip(columns, dts, counts)]
    if data == "ascii":
        lines = [" ".join(" ".join(repr(v.item()) for v in c[i]) for c in cols) for i in range(P)]
        return head + ("\n".join(lines) + "\n").encode()
    if data == "binary":
        rec = np.zeros(P, dtype=[(f"f{i}", d, (n,)) for i, (d, n) in enumerate(zip(dts, counts))])
        for i, c in enumerate(cols):
            rec[f"f{i}"] = c
        return head + rec.tobytes()
    raw = b"".join(np.ascontiguousarray(c).tobytes() for c in cols)
    comp = lzf.compress(raw, len(raw) * 2 + 64)
    return head + struct.pack("<II", len(comp), len(raw)) + comp


# --------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("encoding", ENCODINGS)
def test_pcd_round_trip_keeps_values_and_extra_fields(tmp_path, rng, encoding):
    pts, fields = _cloud(rng)
    path = write_pcd(tmp_path / "c.pcd", pts, fields, encoding=encoding)
    pc = read_point_cloud(path)
    assert pc.fields == fields
    assert pc.points.dtype == np.float32
    np.testing.assert_array_equal(pc.points, pts)
    np.testing.assert_array_equal(pc.xyz, pts[:, :3])
    np.testing.assert_array_equal(pc.column("ring"), pts[:, 4])


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_organised_cloud_round_trip_keeps_width_and_height(tmp_path, rng, encoding):
    pts, fields = _cloud(rng, n=8 * 16, extra=("intensity",))
    write_pcd(tmp_path / "o.pcd", pts, fields, encoding=encoding, width=16, height=8)
    pc = read_point_cloud(tmp_path / "o.pcd")
    assert (pc.width, pc.height, pc.is_organized) == (16, 8, True)
    np.testing.assert_array_equal(pc.points, pts)
    # a PointCloud written back keeps its organisation
    write_pcd(tmp_path / "o2.pcd", pc, encoding="binary")
    assert read_point_cloud(tmp_path / "o2.pcd").height == 8


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_empty_cloud_round_trips(tmp_path, encoding):
    write_pcd(tmp_path / "e.pcd", np.zeros((0, 3), np.float32), encoding=encoding)
    pc = read_point_cloud(tmp_path / "e.pcd")
    assert pc.points.shape == (0, 3)


@pytest.mark.parametrize("data", ENCODINGS)
def test_mixed_types_counts_and_padding_are_read_with_xyz_first(tmp_path, rng, data):
    P = 37
    t = rng.uniform(1e9, 2e9, P)  # F8
    ring = rng.integers(0, 128, P)  # U2
    x, y, z = (rng.normal(0, 10, P).astype(np.float32) for _ in range(3))
    normal = rng.normal(size=(P, 3)).astype(np.float32)  # F4 COUNT 3
    label = rng.integers(-5, 5, P)  # I1
    pad = np.zeros((P, 2))
    raw = _raw_pcd(["timestamp", "ring", "x", "_", "y", "z", "normal", "label"],
                   [8, 2, 4, 1, 4, 4, 4, 1], ["F", "U", "F", "U", "F", "F", "F", "I"], [1, 1, 1, 2, 1, 1, 3, 1],
                   [t, ring, x, pad, y, z, normal, label], data=data)
    (tmp_path / "m.pcd").write_bytes(raw)
    pc = read_point_cloud(tmp_path / "m.pcd")
    assert pc.fields == ("x", "y", "z", "timestamp", "ring", "normal_0", "normal_1", "normal_2", "label")
    np.testing.assert_array_equal(pc.xyz, np.stack([x, y, z], 1))
    np.testing.assert_allclose(pc.column("timestamp"), t.astype(np.float32))
    np.testing.assert_array_equal(pc.column("ring"), ring)
    np.testing.assert_array_equal(pc.points[:, 5:8], normal)
    np.testing.assert_array_equal(pc.column("label"), label)


def test_columns_selects_and_orders_fields(tmp_path, rng):
    pts, fields = _cloud(rng)
    write_pcd(tmp_path / "c.pcd", pts, fields)
    pc = read_point_cloud(tmp_path / "c.pcd", columns=("x", "y", "z", "ring"))
    assert pc.fields == ("x", "y", "z", "ring")
    np.testing.assert_array_equal(pc.points[:, 3], pts[:, 4])
    with pytest.raises(FormatError, match="not in the file"):
        read_point_cloud(tmp_path / "c.pcd", columns=("x", "y", "z", "rgb"))


def test_kitti_bin_and_nuscenes_bin_with_columns(tmp_path, rng):
    pts4 = rng.normal(size=(50, 4)).astype(np.float32)
    pts4.tofile(tmp_path / "000000.bin")
    pc = read_point_cloud(tmp_path / "000000.bin")
    assert pc.fields == ("x", "y", "z", "intensity")
    np.testing.assert_array_equal(pc.points, pts4)
    pts5 = rng.normal(size=(48, 5)).astype(np.float32)
    pts5.tofile(tmp_path / "lidar.pcd.bin")
    pc5 = read_point_cloud(tmp_path / "lidar.pcd.bin", columns=5)
    assert pc5.fields == ("x", "y", "z", "intensity", "ring")
    np.testing.assert_array_equal(pc5.points, pts5)
    named = read_point_cloud(tmp_path / "lidar.pcd.bin", columns=("x", "y", "z", "i", "r"))
    assert named.fields[3:] == ("i", "r")


def test_bin_with_size_not_a_multiple_of_columns_is_an_error(tmp_path, rng):
    rng.normal(size=(7, 5)).astype(np.float32).tofile(tmp_path / "odd.bin")
    with pytest.raises(FormatError, match="not a multiple of 4 float32 columns") as ei:
        read_point_cloud(tmp_path / "odd.bin")
    assert ei.value.path.endswith("odd.bin") and ei.value.field == "columns"


def test_npy_plain_and_structured(tmp_path, rng):
    pts = rng.normal(size=(20, 4))
    np.save(tmp_path / "p.npy", pts)
    pc = read_point_cloud(tmp_path / "p.npy")
    assert pc.points.dtype == np.float32 and pc.fields == ("x", "y", "z", "intensity")
    np.testing.assert_allclose(pc.points, pts.astype(np.float32))
    rec = np.zeros(5, dtype=[("i", "f4"), ("x", "f4"), ("y", "f4"), ("z", "f4")])
    rec["x"] = np.arange(5)
    np.save(tmp_path / "s.npy", rec)
    pcs = read_point_cloud(tmp_path / "s.npy")
    assert pcs.fields == ("x", "y", "z", "i")
    np.testing.assert_array_equal(pcs.points[:, 0], np.arange(5))
    np.save(tmp_path / "bad.npy", np.zeros((4, 2)))
    with pytest.raises(FormatError, match=r"\[P, >=3\]"):
        read_point_cloud(tmp_path / "bad.npy")


def test_write_points_by_extension_round_trips(tmp_path, rng):
    pts = rng.normal(size=(10, 4)).astype(np.float32)
    for name in ("a.pcd", "a.bin", "a.npy"):
        np.testing.assert_array_equal(load_points(write_points(tmp_path / name, pts)), pts)


def test_write_is_atomic_and_leaves_no_temp_files(tmp_path, rng):
    pts, fields = _cloud(rng)
    write_pcd(tmp_path / "c.pcd", pts, fields)
    with pytest.raises(ValueError, match="field names"):
        write_pcd(tmp_path / "c.pcd", pts, fields[:3])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.pcd"]
    np.testing.assert_array_equal(read_point_cloud(tmp_path / "c.pcd").points, pts)


# ---------------------------------------------------------------------------- bad input
def _good_bytes(rng, data="binary"):
    x = rng.normal(size=(10, 3)).astype(np.float32)
    return _raw_pcd(["x", "y", "z"], [4, 4, 4], ["F", "F", "F"], [1, 1, 1], [x[:, 0], x[:, 1], x[:, 2]], data=data)


def test_missing_file_raises_file_not_found_naming_it(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.pcd"):
        read_point_cloud(tmp_path / "nope.pcd")


@pytest.mark.parametrize("data", ENCODINGS)
def test_truncated_pcd_is_a_format_error(tmp_path, rng, data):
    raw = _good_bytes(rng, data)
    (tmp_path / "t.pcd").write_bytes(raw[:-40])  # loses the last rows (ascii) or bytes
    with pytest.raises(FormatError) as ei:
        read_point_cloud(tmp_path / "t.pcd")
    assert ei.value.path.endswith("t.pcd") and ei.value.field == "DATA"


def test_header_without_data_line_is_a_format_error(tmp_path, rng):
    raw = _good_bytes(rng)
    (tmp_path / "h.pcd").write_bytes(raw[: raw.index(b"DATA")])
    with pytest.raises(FormatError, match="no DATA line"):
        read_point_cloud(tmp_path / "h.pcd")


def test_corrupt_lzf_payload_is_a_format_error(tmp_path, rng):
    raw = bytearray(_good_bytes(rng, "binary_compressed"))
    start = raw.index(b"DATA binary_compressed\n") + len(b"DATA binary_compressed\n") + 8
    raw[start:] = bytes(len(raw) - start)  # zero the LZF stream: wrong back-references/lengths
    raw[start] = 0xE0  # a back-reference before the start of the output
    (tmp_path / "z.pcd").write_bytes(bytes(raw))
    with pytest.raises(FormatError, match="LZF") as ei:
        read_point_cloud(tmp_path / "z.pcd")
    assert ei.value.field == "DATA"


def test_unknown_data_kind_is_a_format_error(tmp_path, rng):
    raw = _good_bytes(rng).replace(b"DATA binary", b"DATA binary_lz4")
    (tmp_path / "u.pcd").write_bytes(raw)
    with pytest.raises(FormatError, match="unknown DATA kind 'binary_lz4'") as ei:
        read_point_cloud(tmp_path / "u.pcd")
    assert ei.value.field == "DATA"


def test_points_not_width_times_height_is_a_format_error(tmp_path, rng):
    x = rng.normal(size=(12, 3)).astype(np.float32)
    raw = _raw_pcd(["x", "y", "z"], [4] * 3, ["F"] * 3, [1] * 3, list(x.T), width=4, height=3, points=10)
    (tmp_path / "p.pcd").write_bytes(raw)
    with pytest.raises(FormatError, match=r"POINTS 10 != WIDTH 4 x HEIGHT 3") as ei:
        read_point_cloud(tmp_path / "p.pcd")
    assert ei.value.field == "POINTS"


@pytest.mark.parametrize("header_edit, field", [
    ((b"FIELDS x y z", b"FIELDS x y w"), "FIELDS"),
    ((b"SIZE 4 4 4", b"SIZE 4 4"), "SIZE"),
    ((b"TYPE F F F", b"TYPE F F Q"), "TYPE"),
    ((b"WIDTH 10", b"WIDTH ten"), "WIDTH"),
    ((b"VIEWPOINT 0 0 0 1 0 0 0", b"VIEWPOINT 0 0"), "VIEWPOINT"),
])
def test_malformed_header_fields_are_named(tmp_path, rng, header_edit, field):
    raw = _good_bytes(rng).replace(*header_edit)
    (tmp_path / "b.pcd").write_bytes(raw)
    with pytest.raises(FormatError) as ei:
        read_point_cloud(tmp_path / "b.pcd")
    assert ei.value.field == field


def test_ascii_with_a_non_number_is_a_format_error(tmp_path, rng):
    raw = _good_bytes(rng, "ascii")
    raw = re.sub(rb"\n([-0-9.e]+) ", b"\nabc ", raw, count=1)
    (tmp_path / "a.pcd").write_bytes(raw)
    with pytest.raises(FormatError, match="ascii data"):
        read_point_cloud(tmp_path / "a.pcd")


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_nonfinite_coordinates_error_by_default_and_drop_on_request(tmp_path, rng, encoding):
    pts, fields = _cloud(rng, n=30)
    pts[[3, 17], 1] = np.nan
    pts[5, 2] = np.inf
    pts[8, 3] = np.nan  # NaN intensity is not a coordinate: kept
    write_pcd(tmp_path / "n.pcd", pts, fields, encoding=encoding)
    with pytest.raises(FormatError, match="3 of 30 point") as ei:
        read_point_cloud(tmp_path / "n.pcd")
    assert ei.value.field == "x,y,z"
    pc = read_point_cloud(tmp_path / "n.pcd", drop_nonfinite=True)
    assert pc.num_dropped == 3 and pc.num_points == 27
    assert np.isfinite(pc.xyz).all()
    assert np.isnan(pc.points[:, 3]).sum() == 1


def test_unknown_extension_is_a_format_error(tmp_path):
    (tmp_path / "cloud.xyz").write_text("1 2 3\n")
    with pytest.raises(FormatError, match="unknown point-cloud format"):
        read_point_cloud(tmp_path / "cloud.xyz")


def test_pointcloud_dataclass_helpers(rng):
    pts = rng.normal(size=(4, 4)).astype(np.float32)
    pc = PointCloud(pts, ("x", "y", "z", "intensity"), 4)
    assert len(pc) == 4 and not pc.is_organized
    with pytest.raises(KeyError, match="rgb"):
        pc.column("rgb")


# ------------------------------------------------------------------------------ real data
_CALIBANYTHING = [
    "sensorscalibration/manual_calib/0.pcd",                  # ascii, x y z intensity
    "johanna0626_lab_data_0304/pc/000000.pcd",                # ascii, organised 512 x 128
    "sensorscalibration/auto_calib/calib.pcd",                # binary_compressed, 6 fields
    "sensorscalibration/auto_calib_v2.0/ours/1/calib.pcd",
    "sensorscalibration/auto_calib_v2.0/ours/2/calib.pcd",
]


def _header_value(path, key):
    with open(path, "rb") as f:
        for line in f:
            if line.startswith(key.encode() + b" "):
                return line.decode().split()[1:]
    raise AssertionError(f"{key} not in {path}")


@pytest.mark.shared_data
@pytest.mark.parametrize("rel", _CALIBANYTHING)
def test_calibanything_pcds_load_with_header_point_counts(rel):
    path = shared_path("calibanything", rel)
    pc = read_point_cloud(path)
    assert pc.num_points == int(_header_value(path, "POINTS")[0])
    assert pc.width == int(_header_value(path, "WIDTH")[0])
    assert pc.height == int(_header_value(path, "HEIGHT")[0])
    fields = tuple(_header_value(path, "FIELDS"))
    assert pc.fields == fields  # x y z already lead in these files; nothing dropped
    assert np.isfinite(pc.xyz).all() and np.abs(pc.xyz).max() < 1000


@pytest.mark.shared_data
def test_calibanything_binary_compressed_agrees_with_pypcd4():
    from pypcd4 import PointCloud as P4

    path = shared_path("calibanything", "sensorscalibration", "auto_calib", "calib.pcd")
    ours = read_point_cloud(path)
    theirs = P4.from_path(path).numpy().astype(np.float32)
    np.testing.assert_array_equal(ours.points, theirs)


@pytest.mark.shared_data
def test_kitti_velodyne_bin_loads():
    path = shared_path("kitti", "openpcdet_pr653", "training", "velodyne", "000000.bin")
    pc = read_point_cloud(path)
    assert pc.num_points * 16 == path.stat().st_size and pc.points.shape[1] == 4
