"""Point-cloud files: PCD (ascii / binary / binary_compressed), KITTI-style ``.bin`` and ``.npy``.

Every reader returns a :class:`PointCloud` whose ``points`` are float32 ``[P, C]`` in the file's
own frame and units (metres for LiDAR), columns ``x, y, z`` first, then the other fields in
file order (a field with ``COUNT n > 1`` becomes ``name_0 .. name_{n-1}``; PCD padding fields
``_`` are skipped). Every failure is a :class:`xcalib.errors.FormatError` naming the file, the
header field and what was wrong (a missing file is a ``FileNotFoundError``); nothing is returned
half-read.

The PCD parser is our own (numpy + LZF from ``python-neo-lzf``): pypcd4
1.5 accepts POINTS != WIDTH*HEIGHT, short binary payloads, stops reading the header after 10
lines, and lays out ``COUNT > 1`` fields of binary_compressed files differently from PCL.
"""

from __future__ import annotations

import io
import logging
import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import FormatError
from .files import MAX_FILE_BYTES, atomic_write, open_regular, read_bytes

__all__ = ["PointCloud", "read_point_cloud", "load_points", "write_pcd", "write_points",
           "PCD_ENCODINGS", "default_field_names"]

log = logging.getLogger("xcalib.io.pointcloud")

PCD_ENCODINGS = ("ascii", "binary", "binary_compressed")
_DEFAULT_VIEWPOINT = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("F", 2): "<f2",
          ("U", 1): "u1", ("U", 2): "<u2", ("U", 4): "<u4", ("U", 8): "<u8",
          ("I", 1): "i1", ("I", 2): "<i2", ("I", 4): "<i4", ("I", 8): "<i8"}
_MAX_HEADER_BYTES = 1 << 16
#: Largest COUNT of one PCD field (PCL descriptors go to 308, e.g. VFH).
MAX_PCD_COUNT = 1024
#: Largest |x|, |y|, |z| (metres) of a plausible LiDAR point; beyond it the column layout is wrong.
MAX_COORD_M = 1.0e5
_LZF_MAX_RATIO = 300  # LZF cannot expand a payload by more than this (bomb guard)


@dataclass
class PointCloud:
    """A point cloud read from a file.

    points: float32 [P, C], columns named by ``fields`` (``x, y, z`` first, metres).
    width / height: PCD organisation (height 1 for unorganised clouds; P == width * height
    unless points were dropped). viewpoint: PCD VIEWPOINT (tx ty tz qw qx qy qz).
    num_dropped: points removed by ``drop_nonfinite=True``. path: the source file.
    """

    points: np.ndarray
    fields: tuple[str, ...]
    width: int
    height: int = 1
    viewpoint: tuple[float, ...] = _DEFAULT_VIEWPOINT
    num_dropped: int = 0
    path: str | None = None

    @property
    def xyz(self) -> np.ndarray:
        """[P, 3] float32 view of x, y, z (metres)."""
        return self.points[:, :3]

    @property
    def num_points(self) -> int:
        return int(self.points.shape[0])

    @property
    def is_organized(self) -> bool:
        return self.height > 1

    def column(self, name: str) -> np.ndarray:
        """One column by field name, e.g. ``"intensity"``."""
        try:
            return self.points[:, self.fields.index(name)]
        except ValueError:
            raise KeyError(f"point cloud has no field {name!r}; fields: {self.fields}") from None

    def __len__(self) -> int:
        return self.num_points


def default_field_names(num_columns: int) -> tuple[str, ...]:
    """Names for unnamed float columns: x y z intensity [ring] then f5, f6, ..."""
    base = ("x", "y", "z", "intensity", "ring")
    if num_columns < 3:
        raise ValueError(f"a point cloud needs at least 3 columns (x, y, z), got {num_columns}")
    return tuple(base[i] if i < len(base) else f"f{i}" for i in range(num_columns))


# ------------------------------------------------------------------------------ reading
def read_point_cloud(path, *, columns=None, drop_nonfinite: bool = False) -> PointCloud:
    """Read a ``.pcd``, ``.bin`` (KITTI float32 x4 / nuScenes ``.pcd.bin`` with ``columns=5``)
    or ``.npy`` point cloud.

    Args:
        columns: ``.bin``: the number of float32 columns per point or their names (default 4:
            x y z intensity). ``.pcd`` / ``.npy``: optional field names to keep, in that order.
        drop_nonfinite: drop points with NaN/Inf in x, y, z (logged, counted in
            ``num_dropped``) instead of raising.
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"point cloud file not found: {p}")
    open_regular(p, what="point-cloud file").close()  # FIFOs, devices, directories, oversized: refused
    name = p.name.lower()
    if name.endswith(".pcd"):
        pc = _read_pcd(p)
    elif name.endswith(".bin"):
        pc = _read_bin(p, columns)
        columns = None
    elif name.endswith(".npy"):
        pc = _read_npy(p)
    else:
        with open_regular(p, what="point-cloud file") as f:
            head = f.read(64).lstrip()
        if head.startswith(b"#") or head.upper().startswith(b"VERSION") or head.upper().startswith(b"FIELDS"):
            pc = _read_pcd(p)
        else:
            raise FormatError(p, "unknown point-cloud format: expected a .pcd, .bin or .npy file")
    if columns is not None:
        pc = _select(pc, columns)
    return _finite(pc, drop_nonfinite)


def load_points(path, *, columns=None, drop_nonfinite: bool = False) -> np.ndarray:
    """Convenience: the ``[P, C]`` float32 array of :func:`read_point_cloud`."""
    return read_point_cloud(path, columns=columns, drop_nonfinite=drop_nonfinite).points


def _select(pc: PointCloud, columns) -> PointCloud:
    if isinstance(columns, str):
        columns = (columns,)
    names = tuple(columns)
    missing = [c for c in names if c not in pc.fields]
    if missing:
        raise FormatError(pc.path, f"requested field(s) {missing} not in the file; fields: {list(pc.fields)}",
                          field="FIELDS")
    idx = [pc.fields.index(c) for c in names]
    return PointCloud(np.ascontiguousarray(pc.points[:, idx]), names, pc.width, pc.height,
                      pc.viewpoint, pc.num_dropped, pc.path)


def _finite(pc: PointCloud, drop: bool) -> PointCloud:
    if pc.points.shape[1] < 3 or pc.fields[:3] != ("x", "y", "z"):
        return pc
    # a float64 sum of float32 values cannot overflow, so it is finite iff every value is
    xyz = pc.points[:, :3]
    if np.isfinite(xyz.sum(dtype=np.float64)):
        if xyz.size and np.abs(xyz).max() > MAX_COORD_M:
            i = int(np.argmax(np.abs(xyz).max(axis=1)))
            raise FormatError(pc.path, f"point {i} has a coordinate of {float(np.abs(xyz[i]).max()):.3g} m, beyond "
                                       f"{MAX_COORD_M:g} m: corrupt data or wrong layout (LiDAR frames are metres)",
                              field="x,y,z")
        return pc
    bad = ~np.isfinite(xyz).all(axis=1)
    n = int(bad.sum())
    if not drop:
        first = int(np.argmax(bad))
        raise FormatError(pc.path, f"{n} of {pc.num_points} point(s) have NaN/Inf in x, y, z (first at "
                                   f"index {first}); pass drop_nonfinite=True to drop them", field="x,y,z")
    log.info("%s: dropped %d point(s) with NaN/Inf coordinates", pc.path, n)
    kept = np.ascontiguousarray(pc.points[~bad])
    return PointCloud(kept, pc.fields, len(kept), 1, pc.viewpoint, pc.num_dropped + n, pc.path)


@dataclass
class _Header:
    fields: list[str]
    sizes: list[int]
    types: list[str]
    counts: list[int]
    width: int
    height: int
    points: int
    viewpoint: tuple[float, ...]
    data: str
    data_offset: int


def _parse_header(path: Path, raw: bytes) -> _Header:
    values: dict[str, list[str]] = {}
    pos = 0
    data_offset = None
    while pos < len(raw) and pos < _MAX_HEADER_BYTES:
        nl = raw.find(b"\n", pos)
        end = len(raw) if nl < 0 else nl + 1
        line = raw[pos:end].decode("ascii", errors="replace").strip()
        pos = end
        if not line or line.startswith("#"):
            continue
        key, *rest = line.split()
        key = key.upper()
        values[key] = rest
        if key == "DATA":
            data_offset = pos
            break
        if nl < 0:
            break
    if data_offset is None:
        if not raw:
            raise FormatError(path, "file is empty")
        raise FormatError(path, "header has no DATA line (truncated or not a PCD file)", field="DATA")

    def need(key: str) -> list[str]:
        if key not in values or not values[key]:
            raise FormatError(path, f"header field {key} is missing or empty", field=key)
        return values[key]

    def ints(key: str, default=None) -> list[int]:
        if key not in values and default is not None:
            return default
        raw = need(key)
        try:
            out = [int(v) for v in raw]
        except ValueError:
            raise FormatError(path, f"header field {key} must hold integers, got {' '.join(values[key])!r}",
                              field=key) from None
        if any(v < 0 for v in out):
            raise FormatError(path, f"header field {key} must be non-negative, got {out}", field=key)
        return out

    fields = need("FIELDS")
    n = len(fields)
    sizes = ints("SIZE")
    types = [t.upper() for t in need("TYPE")]
    counts = ints("COUNT", [1] * n)
    for key, vals in (("SIZE", sizes), ("TYPE", types), ("COUNT", counts)):
        if len(vals) != n:
            raise FormatError(path, f"{key} has {len(vals)} entries but FIELDS has {n} ({' '.join(fields)})",
                              field=key)
    for f, t, s, c in zip(fields, types, sizes, counts):
        if (t, s) not in _TYPES:
            raise FormatError(path, f"field {f!r} has unsupported TYPE {t} with SIZE {s} "
                                    "(expected F 2/4/8, U or I 1/2/4/8)", field="TYPE")
        if c < 1 or c > MAX_PCD_COUNT:
            raise FormatError(path, f"field {f!r} has COUNT {c}; expected 1..{MAX_PCD_COUNT}", field="COUNT")
    named = [f for f in fields if f != "_"]
    dups = sorted({f for f in named if named.count(f) > 1})
    if dups:
        raise FormatError(path, f"FIELDS names {dups} more than once ({' '.join(fields)})", field="FIELDS")
    for axis in ("x", "y", "z"):
        if axis not in fields:
            raise FormatError(path, f"FIELDS must include x, y and z, got {' '.join(fields)}", field="FIELDS")
        if counts[fields.index(axis)] != 1:
            raise FormatError(path, f"field {axis} has COUNT {counts[fields.index(axis)]}; x, y and z must have "
                                    "COUNT 1", field="COUNT")
    width = ints("WIDTH")[0]
    height = ints("HEIGHT", [1])[0]
    points = ints("POINTS", [width * height])[0]
    if points != width * height:
        raise FormatError(path, f"POINTS {points} != WIDTH {width} x HEIGHT {height} = {width * height}",
                          field="POINTS")
    viewpoint = _DEFAULT_VIEWPOINT
    if "VIEWPOINT" in values:
        try:
            viewpoint = tuple(float(v) for v in values["VIEWPOINT"])
        except ValueError:
            viewpoint = ()
        if len(viewpoint) != 7:
            raise FormatError(path, f"VIEWPOINT must hold 7 numbers (tx ty tz qw qx qy qz), got "
                                    f"{' '.join(values['VIEWPOINT'])!r}", field="VIEWPOINT")
    data = need("DATA")[0].lower()
    if data not in PCD_ENCODINGS:
        raise FormatError(path, f"unknown DATA kind {data!r}; expected one of {PCD_ENCODINGS}", field="DATA")
    return _Header(fields, sizes, types, counts, width, height, points, viewpoint, data, data_offset)


def _columns_of(h: _Header) -> list[tuple[str, str, int, int]]:
    """(column name, numpy dtype, field index, element index) for every non-padding element."""
    cols = []
    for i, (f, t, s, c) in enumerate(zip(h.fields, h.types, h.sizes, h.counts)):
        if f == "_":
            continue
        for k in range(c):
            cols.append((f if c == 1 else f"{f}_{k}", _TYPES[(t, s)], i, k))
    return cols


def _assemble(path: Path, h: _Header, arrays: dict[tuple[int, int], np.ndarray]) -> PointCloud:
    cols = _columns_of(h)
    order = [c for c in cols if c[0] in ("x", "y", "z")]
    order.sort(key=lambda c: "xyz".index(c[0]))
    order += [c for c in cols if c[0] not in ("x", "y", "z")]
    out = np.empty((h.points, len(order)), dtype=np.float32)
    for j, (_, _, fi, k) in enumerate(order):
        out[:, j] = arrays[(fi, k)]
    return PointCloud(out, tuple(c[0] for c in order), h.width, h.height, h.viewpoint, 0, str(path))


def _read_pcd(path: Path) -> PointCloud:
    raw = read_bytes(path, max_bytes=MAX_FILE_BYTES, what="PCD file")
    h = _parse_header(path, raw)
    body = memoryview(raw)[h.data_offset:]
    if h.data == "ascii":
        if h.points * sum(h.counts) > len(body):  # every value needs >= 1 byte: a bomb guard
            raise FormatError(path, f"header declares {h.points} points x {sum(h.counts)} values but the ascii data "
                                    f"holds {len(body)} bytes", field="POINTS")
        return _assemble(path, h, _parse_ascii(path, h, bytes(body)))
    itemsizes = [s * c for s, c in zip(h.sizes, h.counts)]
    point_size = sum(itemsizes)
    nbytes = h.points * point_size
    if h.data == "binary":
        if len(body) != nbytes:
            what = "truncated" if len(body) < nbytes else "followed by trailing bytes"
            raise FormatError(path, f"binary data is {what}: {h.points} points x {point_size} bytes = "
                                    f"{nbytes} bytes expected, {len(body)} found", field="DATA")
        dtype = np.dtype([(f"f{i}", _TYPES[(t, s)], (c,)) for i, (t, s, c)
                          in enumerate(zip(h.types, h.sizes, h.counts))])
        rec = np.frombuffer(body[:nbytes], dtype=dtype, count=h.points)
        arrays = {(fi, k): rec[f"f{fi}"][:, k] for _, _, fi, k in _columns_of(h)}
        return _assemble(path, h, arrays)
    # binary_compressed: uint32 compressed size, uint32 uncompressed size, LZF payload holding
    # each field's values for all points in turn (PCL layout: field-major, COUNT inner).
    if len(body) < 8:
        raise FormatError(path, f"binary_compressed data is truncated: 8-byte size header expected, "
                                f"{len(body)} bytes found", field="DATA")
    csize, usize = struct.unpack("<II", body[:8])
    if usize != nbytes:
        raise FormatError(path, f"binary_compressed uncompressed size {usize} != {h.points} points x "
                                f"{point_size} bytes = {nbytes}", field="DATA")
    if len(body) - 8 < csize:
        raise FormatError(path, f"binary_compressed data is truncated: {csize} compressed bytes declared, "
                                f"{len(body) - 8} found", field="DATA")
    tail = body[8 + csize:]
    if len(tail) and (len(tail) > 1 << 16 or any(bytes(tail))):  # PCL pads with zeros (page size), nothing else
        raise FormatError(path, f"binary_compressed data is followed by {len(tail)} trailing non-padding bytes",
                          field="DATA")
    if usize > _LZF_MAX_RATIO * csize + 4096:
        raise FormatError(path, f"binary_compressed declares {usize} bytes from {csize} compressed bytes: more "
                                "than LZF can expand (corrupt header)", field="DATA")
    if nbytes == 0:
        buf = b""
    else:
        import lzf

        try:
            buf = lzf.decompress(bytes(body[8:8 + csize]), usize)
        except Exception as exc:  # noqa: BLE001 - any decoder failure is a corrupt file
            raise FormatError(path, f"LZF payload could not be decompressed ({exc})", field="DATA") from None
        if buf is None or len(buf) != usize:
            got = 0 if buf is None else len(buf)
            raise FormatError(path, f"LZF payload is corrupt: decompressed to {got} bytes, {usize} expected",
                              field="DATA")
    arrays = {}
    offset = 0
    for fi, (t, s, c) in enumerate(zip(h.types, h.sizes, h.counts)):
        block = np.frombuffer(buf, dtype=_TYPES[(t, s)], count=h.points * c, offset=offset)
        block = block.reshape(h.points, c)
        for k in range(c):
            arrays[(fi, k)] = block[:, k]
        offset += h.points * s * c
    return _assemble(path, h, arrays)




def _parse_ascii(path: Path, h: _Header, body: bytes) -> dict[tuple[int, int], np.ndarray]:
    ncol = sum(h.counts)
    try:
        with np.errstate(all="ignore"):
            table = np.loadtxt(io.BytesIO(body), dtype=np.float64, ndmin=2, comments="#",
                               max_rows=h.points if h.points else None) if h.points else np.zeros((0, ncol))
    except ValueError as exc:
        raise FormatError(path, f"ascii data could not be parsed as {ncol} numbers per line ({exc})",
                          field="DATA") from None
    extra = _extra_ascii_rows(body, h.points)
    if table.shape[0] != h.points or (h.points and table.shape[1] != ncol) or extra:
        raise FormatError(path, f"ascii data holds {table.shape[0]} rows x {table.shape[1]} values; header "
                                f"declares {h.points} points x {ncol} values (truncated or corrupt)", field="DATA")
    arrays = {}
    start = 0
    for fi, c in enumerate(h.counts):
        for k in range(c):
            arrays[(fi, k)] = table[:, start + k]
        start += c
    return arrays


def _extra_ascii_rows(body: bytes, points: int) -> int:
    """Non-blank, non-comment lines after the first ``points`` data lines (trailing data)."""
    lines = [ln for ln in body.split(b"\n") if ln.strip() and not ln.lstrip().startswith(b"#")]
    return max(len(lines) - points, 0)


def _read_bin(path: Path, columns) -> PointCloud:
    if columns is None:
        names = default_field_names(4)
    elif isinstance(columns, (int, np.integer)):
        if columns < 3:
            raise FormatError(path, f"columns must be >= 3 (x, y, z, ...), got {columns}", field="columns")
        names = default_field_names(int(columns))
    else:
        names = tuple(columns)
        if names[:3] != ("x", "y", "z"):
            raise FormatError(path, f"columns must start with x, y, z, got {names}", field="columns")
    n = len(names)
    size = path.stat().st_size
    if size % (4 * n):
        hint = " (nuScenes .pcd.bin files hold 5: pass columns=5)" if n == 4 and size % 20 == 0 else ""
        raise FormatError(path, f"file size {size} bytes is not a multiple of {n} float32 columns "
                                f"({4 * n} bytes per point){hint}", field="columns")
    raw = np.frombuffer(read_bytes(path, what=".bin point cloud"), dtype="<f4")
    pts = raw.reshape(-1, n).astype(np.float32)
    _check_bin_layout(path, raw, pts, n, columns is None)
    return PointCloud(pts, names, len(pts), 1, _DEFAULT_VIEWPOINT, 0, str(path))


def _plausible(xyz: np.ndarray) -> bool:
    with np.errstate(invalid="ignore"):
        a = np.abs(xyz[np.isfinite(xyz).all(axis=1)])
    return a.size == 0 or float(a.max()) <= MAX_COORD_M


def _check_bin_layout(path: Path, raw: np.ndarray, pts: np.ndarray, n: int, defaulted: bool) -> None:
    """Refuse a ``.bin`` read with the wrong column count: the coordinates come out as garbage
    (e.g. Waymo's KITTI-format export holds 6 columns: x y z intensity elongation timestamp)."""
    if _plausible(pts[:, :3]):
        return
    fits = [k for k in (4, 5, 6, 3, 7, 8) if k != n and raw.size % k == 0
            and _plausible(raw.reshape(-1, k)[:, :3])]
    hint = f"; the values fit {fits[0]} columns: pass columns={fits[0]}" if fits else ""
    raise FormatError(path, f"read as {n} float32 columns{' (the default)' if defaulted else ''}, coordinates reach "
                            f"{float(np.nanmax(np.abs(pts[:, :3]))):.3g} m (> {MAX_COORD_M:g} m): wrong column "
                            f"count{hint}", field="columns")


def _read_npy(path: Path) -> PointCloud:
    arr = _load_npy(path)
    if arr.dtype.names:
        if not {"x", "y", "z"} <= set(arr.dtype.names):
            raise FormatError(path, f"structured array must have fields x, y, z, got {arr.dtype.names}",
                              field="dtype")
        names = ["x", "y", "z"] + [n for n in arr.dtype.names if n not in ("x", "y", "z")]
        arr = np.stack([np.asarray(arr[n], dtype=np.float32).reshape(-1) for n in names], axis=1)
        fields = tuple(names)
    else:
        if arr.ndim != 2 or arr.shape[1] < 3:
            raise FormatError(path, f"expected an array of shape [P, >=3], got {arr.shape}", field="shape")
        if arr.dtype.kind not in "fiu":
            raise FormatError(path, f"expected a numeric array, got dtype {arr.dtype}", field="dtype")
        fields = default_field_names(arr.shape[1])
    with np.errstate(over="ignore", invalid="ignore"):
        pts = np.ascontiguousarray(arr, dtype=np.float32)
    return PointCloud(pts, fields, len(pts), 1, _DEFAULT_VIEWPOINT, 0, str(path))


def _load_npy(path: Path) -> np.ndarray:
    """``np.load`` (no pickles) after checking that the header's shape fits the file size."""
    with open_regular(path, what=".npy file") as fh:
        size = os.fstat(fh.fileno()).st_size
        try:
            version = np.lib.format.read_magic(fh)
            shape, _, dtype = (np.lib.format.read_array_header_1_0(fh) if version == (1, 0)
                               else np.lib.format.read_array_header_2_0(fh))
        except Exception as exc:  # noqa: BLE001 - numpy's header parser raises many types (TokenError, ...)
            raise FormatError(path, f"not a readable .npy header ({type(exc).__name__}: {str(exc)[:120]})") from None
        if dtype.hasobject:
            raise FormatError(path, "object arrays (pickles) are refused", field="dtype")
        need = int(np.prod(shape, dtype=object)) * dtype.itemsize
        if need > size:
            raise FormatError(path, f"header declares shape {shape} ({need} bytes) but the file holds {size} bytes",
                              field="shape")
        fh.seek(0)
        try:
            return np.load(fh, allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise FormatError(path, f"not a readable .npy array ({exc})") from None


# ------------------------------------------------------------------------------ writing
def write_pcd(path, points, fields: Sequence[str] | None = None, encoding: str = "binary", *,
              width: int | None = None, height: int | None = None,
              viewpoint: Sequence[float] | None = None) -> Path:
    """Write a PCD v0.7 file (float32 fields, COUNT 1) atomically (temp file, then rename).

    ``points`` is a [P, C] array or a :class:`PointCloud` (its fields / organisation are kept).
    ``fields`` defaults to x y z intensity ... ; ``encoding`` is ascii, binary or
    binary_compressed. ``width * height`` must equal P (default: width P, height 1).
    """
    path = Path(path)
    if isinstance(points, PointCloud):
        fields = fields or points.fields
        if width is None and height is None and points.width * points.height == points.num_points:
            width, height = points.width, points.height
        viewpoint = viewpoint or points.viewpoint
        points = points.points
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise ValueError(f"write_pcd: points must have shape [P, >=3], got {pts.shape}")
    pts = np.ascontiguousarray(pts, dtype="<f4")
    P, C = pts.shape
    fields = tuple(fields) if fields is not None else default_field_names(C)
    if len(fields) != C:
        raise ValueError(f"write_pcd: {len(fields)} field names for {C} columns")
    if any((not f) or any(ch.isspace() for ch in f) for f in fields):
        raise ValueError(f"write_pcd: field names must be non-empty without spaces, got {fields}")
    if encoding not in PCD_ENCODINGS:
        raise ValueError(f"write_pcd: encoding must be one of {PCD_ENCODINGS}, got {encoding!r}")
    width = P if width is None else int(width)
    height = 1 if height is None else int(height)
    if width * height != P:
        raise ValueError(f"write_pcd: width {width} x height {height} != {P} points")
    vp = tuple(float(v) for v in (viewpoint or _DEFAULT_VIEWPOINT))
    if len(vp) != 7:
        raise ValueError(f"write_pcd: viewpoint must have 7 numbers, got {len(vp)}")
    header = "\n".join([
        "# .PCD v0.7 - Point Cloud Data file format", "VERSION 0.7",
        "FIELDS " + " ".join(fields), "SIZE " + " ".join(["4"] * C), "TYPE " + " ".join(["F"] * C),
        "COUNT " + " ".join(["1"] * C), f"WIDTH {width}", f"HEIGHT {height}",
        "VIEWPOINT " + " ".join(f"{v:g}" for v in vp), f"POINTS {P}", f"DATA {encoding}", "",
    ]).encode("ascii")
    if encoding == "ascii":
        buf = io.BytesIO()
        if P:
            np.savetxt(buf, pts, fmt="%.9g")
        body = [buf.getvalue()]
    elif encoding == "binary":
        body = [pts.tobytes()]
    else:
        raw = np.ascontiguousarray(pts.T).tobytes()  # field-major
        if raw:
            import lzf

            comp = lzf.compress(raw, len(raw) + len(raw) // 16 + 64)
            if comp is None:  # pragma: no cover - the bound above always suffices
                raise RuntimeError("LZF compression failed")
        else:
            comp = b""
        body = [struct.pack("<II", len(comp), len(raw)), comp]
    atomic_write(path, [header, *body])
    return path


def write_points(path, points, fields: Sequence[str] | None = None, **kwargs) -> Path:
    """Write by extension: ``.pcd`` (see :func:`write_pcd`), ``.bin`` (raw float32) or ``.npy``."""
    path = Path(path)
    name = path.name.lower()
    if name.endswith(".pcd"):
        return write_pcd(path, points, fields, **kwargs)
    pts = np.ascontiguousarray(points.points if isinstance(points, PointCloud) else points, dtype="<f4")
    if name.endswith(".bin"):
        atomic_write(path, [pts.tobytes()])
    elif name.endswith(".npy"):
        buf = io.BytesIO()
        np.save(buf, pts)
        atomic_write(path, [buf.getvalue()])
    else:
        raise ValueError(f"write_points: unknown extension of {path} (expected .pcd, .bin or .npy)")
    return path
