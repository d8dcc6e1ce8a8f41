"""Input protocol v1.0: every check of the table (reference-behaviour §1.5), our sparse floor,
and the validate modes."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from xcalib.protocol import (
    MAX_DETECTIONS_2D,
    MIN_POINTS_PER_BOX,
    PROTOCOL_VERSION,
    ProtocolError,
    ProtocolViolation,
    WarningRegistry,
    enforce,
    validate_frame_inputs,
)


def _clean(rng):
    """A frame that passes every check: 640x480 image, 2 boxes each way, 200 points per 3D box."""
    image = rng.integers(0, 256, size=(480, 640, 3), dtype=np.uint8)
    b2 = np.array([[10, 20, 110, 220], [300, 100, 400, 300]], dtype=np.float32)
    b3 = np.array([[5, -1, -1, 9, 1, 1], [20, 3, 0, 2, 2, 2]], dtype=np.float32)  # extents, centre+dims
    pts = np.vstack([rng.uniform([5, -1, -1], [9, 1, 1], size=(200, 3)),
                     rng.uniform([19, 2, -1], [21, 4, 1], size=(200, 3))]).astype(np.float32)
    return image, pts, b2, b3


def _codes(viol):
    return {(v.code, v.severity) for v in viol}


def test_clean_frame_has_no_violations(rng):
    assert validate_frame_inputs(*_clean(rng)) == []
    assert PROTOCOL_VERSION == "1.0"


def _with(rng, **changes):
    image, pts, b2, b3 = _clean(rng)
    args = dict(image=image, point_cloud=pts, bboxes_2d=b2, bboxes_3d=b3)
    for k, v in changes.items():
        args[k] = v(args[k]) if callable(v) else v
    return validate_frame_inputs(args["image"], args["point_cloud"], args["bboxes_2d"], args["bboxes_3d"])


def _set(a, idx, value):
    a = np.array(a, copy=True)
    a[idx] = value
    return a


CASES = [
    # (code, severity, changes)
    ("image.type", "error", dict(image=[[0]])),
    ("image.shape", "error", dict(image=lambda im: im[..., 0])),
    ("image.shape", "error", dict(image=lambda im: np.dstack([im, im[..., :1]]))),
    ("image.empty", "error", dict(image=np.zeros((0, 640, 3), np.uint8))),
    ("image.dtype", "warning", dict(image=lambda im: im.astype(np.float32) / 255)),
    ("image.dtype", "error", dict(image=lambda im: im.astype(np.int16))),
    ("image.resolution", "warning", dict(image=lambda im: im[:479])),
    ("image.resolution", "warning", dict(image=lambda im: im[:, :639])),
    ("point_cloud.type", "error", dict(point_cloud=lambda p: p.tolist())),
    ("point_cloud.shape", "error", dict(point_cloud=lambda p: p[:, :2])),
    ("point_cloud.shape", "error", dict(point_cloud=lambda p: p[:, 0])),
    ("point_cloud.empty", "warning", dict(point_cloud=np.zeros((0, 3), np.float32))),
    ("point_cloud.dtype", "warning", dict(point_cloud=lambda p: np.round(p * 100).astype(np.int32))),
    ("point_cloud.finite", "error", dict(point_cloud=lambda p: _set(p, (3, 1), np.nan))),
    ("point_cloud.finite", "error", dict(point_cloud=lambda p: _set(p, (7, 2), -np.inf))),
    ("bboxes_2d.empty", "warning", dict(bboxes_2d=np.zeros((0, 4)))),
    ("bboxes_2d.shape", "error", dict(bboxes_2d=lambda b: b[:, :3])),
    ("bboxes_2d.shape", "error", dict(bboxes_2d=lambda b: b.reshape(-1))),
    ("bboxes_2d.finite", "error", dict(bboxes_2d=lambda b: _set(b, (1, 2), np.nan))),
    ("bboxes_2d.order", "warning", dict(bboxes_2d=lambda b: _set(b, (0, 2), 5.0))),
    ("bboxes_2d.small", "warning", dict(bboxes_2d=lambda b: _set(b, (0, 3), 27.0))),
    ("bboxes_2d.bounds", "warning", dict(bboxes_2d=lambda b: _set(b, 1, [700, 10, 760, 60]))),
    ("bboxes_2d.count", "warning", dict(bboxes_2d=np.tile([[10, 20, 110, 220]], (MAX_DETECTIONS_2D + 1, 1)))),
    ("bboxes_3d.empty", "warning", dict(bboxes_3d=[])),
    ("bboxes_3d.shape", "error", dict(bboxes_3d=lambda b: np.hstack([b, b[:, :1]]))),
    ("bboxes_3d.shape", "error", dict(bboxes_3d=lambda b: b[:, :5])),
    ("bboxes_3d.finite", "error", dict(bboxes_3d=lambda b: _set(b, (0, 4), np.inf))),
    ("bboxes_3d.degenerate", "warning", dict(bboxes_3d=lambda b: _set(b, (0, 3), 5.0))),
    ("bboxes_3d.count", "warning", dict(bboxes_3d=lambda b: np.tile(b, (17, 1)))),
    ("bboxes_3d.sparse", "warning", dict(bboxes_3d=lambda b: _set(b, 1, [50, 50, 0, 2, 2, 2]))),
]


@pytest.mark.parametrize("code, severity, changes", CASES, ids=[f"{c[0]}-{c[1]}-{i}" for i, c in enumerate(CASES)])
def test_each_check_reports_its_code(rng, code, severity, changes):
    viol = _with(rng, **changes)
    assert (code, severity) in _codes(viol), viol
    v = next(v for v in viol if v.code == code)
    assert isinstance(v, ProtocolViolation) and v.message and str(v).startswith(f"[{severity}] {code}")


def test_every_code_of_the_table_is_covered():
    table = {
        "image.type", "image.shape", "image.empty", "image.dtype", "image.resolution", "point_cloud.type",
        "point_cloud.shape", "point_cloud.empty", "point_cloud.dtype", "point_cloud.finite", "bboxes_2d.empty",
        "bboxes_2d.shape", "bboxes_2d.finite", "bboxes_2d.order", "bboxes_2d.small", "bboxes_2d.bounds",
        "bboxes_2d.count", "bboxes_3d.empty", "bboxes_3d.shape", "bboxes_3d.finite", "bboxes_3d.degenerate",
        "bboxes_3d.count", "bboxes_3d.sparse",
    }
    assert table == {c[0] for c in CASES}


def test_order_failures_are_not_also_reported_small(rng):
    viol = _with(rng, bboxes_2d=lambda b: _set(b, 0, [50, 20, 49, 21]))
    assert "bboxes_2d.order" in {v.code for v in viol}
    assert "bboxes_2d.small" not in {v.code for v in viol}


def test_sparse_floor_counts_points_in_the_expanded_box(rng):
    image, pts, b2, b3 = _clean(rng)
    # exactly MIN_POINTS_PER_BOX - 1 points in a box far away: sparse; one more: not sparse
    far = np.array([[100, 100, 0, 102, 102, 2]], dtype=np.float32)
    inside = rng.uniform([100.5, 100.5, 0.5], [101.5, 101.5, 1.5], size=(MIN_POINTS_PER_BOX, 3)).astype(np.float32)
    few = np.vstack([pts, inside[:-1]])
    enough = np.vstack([pts, inside])
    assert "bboxes_3d.sparse" in {v.code for v in validate_frame_inputs(image, few, b2, np.vstack([b3, far]))}
    assert validate_frame_inputs(image, enough, b2, np.vstack([b3, far])) == []


def test_box_checks_accept_lists_and_never_raise(rng):
    image, pts, b2, b3 = _clean(rng)
    assert validate_frame_inputs(image, pts, b2.tolist(), b3.tolist()) == []
    viol = validate_frame_inputs(image, pts, "abc", [[1, 2], [3]])
    assert {"bboxes_2d.type", "bboxes_3d.type"} <= {v.code for v in viol}
    assert all(v.severity == "error" for v in viol if v.code.endswith(".type"))


# -------------------------------------------------------------------------------- enforce
def test_enforce_off_passes_everything_through(rng):
    viol = _with(rng, point_cloud=lambda p: _set(p, (0, 0), np.nan))
    assert enforce(viol, "off") == viol


def test_enforce_strict_raises_on_warnings(rng):
    viol = _with(rng, image=lambda im: im[:470])
    with pytest.raises(ProtocolError) as ei:
        enforce(viol, "strict")
    assert [v.code for v in ei.value.violations] == ["image.resolution"]
    assert isinstance(ei.value, ValueError) and "protocol v1.0" in str(ei.value)


def test_enforce_warn_raises_only_errors(rng):
    viol = _with(rng, image=lambda im: im[:470], point_cloud=lambda p: _set(p, (0, 0), np.inf))
    with pytest.raises(ProtocolError) as ei:
        enforce(viol, "warn", registry=WarningRegistry())
    assert [v.code for v in ei.value.violations] == ["point_cloud.finite"]


def test_invalid_mode_raises_even_on_a_clean_frame(rng):
    assert enforce(validate_frame_inputs(*_clean(rng)), "strict") == []
    with pytest.raises(ValueError, match="validate must be one of"):
        enforce([], "loud")


def test_warn_logs_each_code_once_per_registry(rng, caplog):
    viol = _with(rng, image=lambda im: im[:470], bboxes_2d=lambda b: _set(b, (0, 3), 27.0))
    reg = WarningRegistry()
    with caplog.at_level(logging.WARNING, logger="xcalib.protocol"):
        for _ in range(3):
            assert enforce(viol, "warn", registry=reg) == viol
    codes = [r.getMessage().split(":")[0] for r in caplog.records]
    assert sorted(codes) == ["[warning] bboxes_2d.small", "[warning] image.resolution"]
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="xcalib.protocol"):
        enforce(viol, "warn", registry=WarningRegistry())
    assert len(caplog.records) == 2
    reg.reset()
    assert reg.first_time("image.resolution")
