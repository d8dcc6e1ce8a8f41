"""Corrupted calibration files either load or raise FormatError naming the file (never a bare
TypeError/KeyError/IndexError)."""

from __future__ import annotations

import copy
import json

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from xcalib.calib.result import CalibrationResult
from xcalib.errors import FormatError
from xcalib.formats.export import FORMATS, export_calibration, read_calibration
from xcalib.geometry import CameraIntrinsics, euler_to_matrix

_JUNK = st.one_of(st.none(), st.text(max_size=5), st.integers(-5, 5), st.floats(allow_nan=True),
                  st.lists(st.floats(-2, 2), max_size=20), st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))


def _paths(obj, prefix=()):
    """Every key path in nested dicts/lists."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield prefix + (k,)
            yield from _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield prefix + (i,)
            yield from _paths(v, prefix + (i,))


def _set(obj, path, value):
    for k in path[:-1]:
        obj = obj[k]
    if value is _DELETE and isinstance(obj, dict):
        del obj[path[-1]]
    else:
        obj[path[-1]] = None if value is _DELETE else value


_DELETE = object()


def _sample(fmt: str, tmp_path):
    res = CalibrationResult(success=True, intrinsics=CameraIntrinsics(1000, 1000, 640, 360, [-0.1, 0.01, 0, 0, 0.001],
                                                                      1280, 720),
                            rotation=euler_to_matrix([-1.5, 0.02, -1.6]), translation=[0.1, -0.3, -0.2],
                            camera_name="cam")
    return export_calibration(res, fmt, tmp_path / FORMATS[fmt].filename)[0]


def _mutations(fmt):
    return st.tuples(st.sampled_from([fmt]), st.integers(0, 10_000), st.one_of(_JUNK, st.just(_DELETE)))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(m=st.one_of(*(_mutations(f) for f in ("lucid", "calib_json", "openlabel", "opencalib", "nuscenes"))))
def test_json_corruptions_raise_format_error(tmp_path, m):
    fmt, pick, value = m
    src = _sample(fmt, tmp_path)
    d = json.loads(src.read_text())
    paths = list(_paths(d))
    _set(d, paths[pick % len(paths)], value if value is _DELETE else copy.deepcopy(value))
    bad = tmp_path / ("bad_" + src.name)
    bad.write_text(json.dumps(d))
    try:
        r = read_calibration(bad, fmt)
    except FormatError as exc:
        assert "bad_" in str(exc)
        return
    except (ValueError, KeyError) as exc:  # CalibrationResult.load's own errors for the xcalib JSON
        assert fmt == "json", f"{fmt}: {type(exc).__name__}: {exc}"
        return
    assert np.all(np.isfinite(r.extrinsics))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(line=st.integers(0, 5), tok=st.integers(0, 12), junk=st.sampled_from(["nan", "x", "", "1e400", "0 0", "-"]))
def test_kitti_text_corruptions_raise_format_error(tmp_path, line, tok, junk):
    src = _sample("kitti", tmp_path)
    lines = src.read_text().splitlines()
    parts = lines[line % len(lines)].split()
    parts[tok % len(parts)] = junk
    lines[line % len(lines)] = " ".join(parts)
    bad = tmp_path / "bad_calib.txt"
    bad.write_text("\n".join(lines) + "\n")
    try:
        r = read_calibration(bad, "kitti")
    except FormatError as exc:
        assert "bad_calib.txt" in str(exc)
        return
    assert np.all(np.isfinite(r.extrinsics))
