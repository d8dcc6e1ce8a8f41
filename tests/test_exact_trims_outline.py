"""Exact trims of the fits' projections (issue 29, session 12): each gives the values of the
formulation it replaces, written out here, to the bit.

* ``boxproj._corner_extremes`` picks between its two ways of taking each rectangle's extremes by
  the array's shape (one reduction per edge, or 4 S element-wise calls): both are checked against
  the written-out previous choice on shapes of both kinds, with NaN and signed zeros.
* ``outline._DenseMemo``: the wide-angle outline's densified edge points are made once per set of
  outlines and reused while only the pose moves; the rects, extremes and points are those of
  densifying at every call.
"""

from __future__ import annotations

import numpy as np
import pytest

from xcalib.calib import boxproj
from xcalib.data.synth.site import WIDE_ANGLE_PARAMS
from xcalib.geometry import box7_corners
from xcalib.geometry.camera_models import get_model, project_outline_rects
from xcalib.geometry.camera_models import outline
from xcalib.geometry.camera_models.outline import outline_extremes

SIZE = (1280, 800)


def _extremes_before(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``_corner_extremes`` as it was: the reduction below 4096 rectangles, else corner by corner."""
    H, M, S = u.shape
    rect = np.empty((H, M, 4))
    if H * M < 4096:
        ut, vt = u.transpose(0, 2, 1), v.transpose(0, 2, 1)
        np.minimum.reduce(ut, axis=1, out=rect[..., 0])
        np.minimum.reduce(vt, axis=1, out=rect[..., 1])
        np.maximum.reduce(ut, axis=1, out=rect[..., 2])
        np.maximum.reduce(vt, axis=1, out=rect[..., 3])
        return rect
    for k, (a, red) in enumerate(((u, np.minimum), (v, np.minimum), (u, np.maximum), (v, np.maximum))):
        rect[..., k] = a[..., 0]
        for j in range(1, S):
            red(rect[..., k], a[..., j], out=rect[..., k])
    return rect


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64).view(np.uint64)


@pytest.mark.parametrize("shape", [(200, 18, 8), (480, 14, 8), (1, 239, 80), (4, 239, 80), (2, 30, 8),
                                   (1, 4000, 8), (16, 30, 8), (1, 1, 4530), (3, 0, 8)])
def test_corner_extremes_are_the_previous_ones_to_the_bit(shape):
    rng = np.random.default_rng(sum(shape))
    u, v = rng.normal(0, 600, shape), rng.normal(0, 400, shape)
    if u.size:
        flat_u, flat_v = u.reshape(-1), v.reshape(-1)
        pick = rng.choice(u.size, size=max(1, u.size // 50), replace=False)
        flat_u[pick[::3]] = np.nan  # behind the camera
        flat_v[pick[1::3]] = 0.0
        flat_v[pick[2::3]] = -0.0  # signed zeros: the same one must win
        flat_u[pick[1::3]] = np.round(flat_u[pick[1::3]])  # ties between corners
    got = boxproj._corner_extremes(u, v)
    want = _extremes_before(u, v)
    assert got.shape == want.shape == shape[:2] + (4,)
    assert np.array_equal(_bits(got), _bits(want))
    if u.size:
        assert np.isnan(got).any()  # the NaN corners reached their rectangles


def _boxes(n: int, seed: int) -> np.ndarray:
    r = np.random.default_rng(seed)
    ang, d = r.uniform(-1.4, 1.4, n), r.uniform(3, 12, n)
    b7 = np.column_stack([d * np.sin(ang), r.uniform(-1, 1.5, n), d * np.cos(ang), r.uniform(1, 8, n),
                          r.uniform(0.5, 3, n), r.uniform(1, 3.5, n), r.uniform(-3, 3, n)])
    return box7_corners(b7)


def _without_memo(monkeypatch):
    """``_Outline.extremes`` as it was: segments chosen and edges densified at every call."""

    class _Fresh:
        def get(self, c, n):
            ii, jj = (outline._EI, outline._EJ) if outline._box7_order(c) else (outline._I, outline._J)
            return (ii, jj), outline._densify(c, n, ii, jj)

    monkeypatch.setattr(outline, "_LAST_DENSE", _Fresh())


@pytest.mark.parametrize("model", sorted(WIDE_ANGLE_PARAMS))
def test_dense_memo_gives_the_densified_outline_of_every_call(model, monkeypatch):
    cam = get_model(model)(fx=300, fy=300, cx=640, cy=400, width=SIZE[0], height=SIZE[1], **WIDE_ANGLE_PARAMS[model])
    c = _boxes(25, 7)
    hull = c[:, [0, 6, 1, 7, 2, 4, 3, 5]]  # 8 points not in box order: the 28 segments
    rng = np.random.default_rng(11)
    poses = []
    for _ in range(4):  # a fit: the same outlines, the pose moving
        w = rng.normal(0, 0.03, 3)
        th = np.linalg.norm(w)
        K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]) / th
        poses.append((np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K, rng.normal(0, 0.2, 3)))

    def run():
        out = []
        for boxes in (c, hull, c):  # back to the first set after another one replaced the slot
            for R, t in poses:
                rect, valid = project_outline_rects(boxes, R, t, cam, SIZE)
                out += [rect, valid.astype(float), outline_extremes(boxes, R, t, cam)]
        return out

    outline._LAST_DENSE.slot = None
    got = run()
    assert outline._LAST_DENSE.slot is not None  # the memo was used
    with monkeypatch.context() as m:
        _without_memo(m)
        want = run()
    assert len(got) == len(want)
    for a, b in zip(got, want):
        assert np.array_equal(_bits(a), _bits(b))
    assert np.isfinite(got[0]).any()


def test_dense_memo_is_keyed_by_the_outlines_numbers():
    memo = outline._DenseMemo()
    c = _boxes(6, 3)
    edges, pts = memo.get(c, 3)
    assert edges[0] is outline._EI and pts.shape == (6, 8 + 12 * 3, 3)
    assert not pts.flags.writeable  # shared between calls: nobody writes into it
    assert memo.get(c.copy(), 3)[1] is pts  # the same numbers: the same points
    assert memo.get(c, 4)[1].shape == (6, 8 + 12 * 4, 3)  # another n: made again
    moved = c.copy()
    moved[2, 5, 1] += 1e-9  # one coordinate moved by a hair: made again, from the new numbers
    again = memo.get(moved, 4)[1]
    assert np.array_equal(_bits(again), _bits(outline._densify(moved, 4, outline._EI, outline._EJ)))
    assert not np.array_equal(again, outline._densify(c, 4, outline._EI, outline._EJ))
    # n = 0 adds nothing: the outlines themselves, their flags untouched and nothing kept
    kept = memo.slot
    edges0, same = memo.get(c, 0)
    assert same is c and c.flags.writeable and memo.slot is kept


@pytest.mark.parametrize("distortion", [None, np.array([-0.2, 0.05, 0.001, -0.002, 0.0])])
def test_frames_projected_without_padding_are_the_padded_projection(distortion):
    """``refine._project_outlines`` (the matching's projection of every frame's outlines) gives
    ``project_rects`` of the padded outlines to the bit: frames with outlines of different lengths
    (8 corners, point hulls already padded within their frame), boxes behind the camera, boxes
    clipped by the image, a frame without boxes."""
    from xcalib.calib import refine
    from xcalib.calib.boxproj import project_rects
    from xcalib.geometry.camera import CameraIntrinsics

    intr = CameraIntrinsics(fx=900.0, fy=880.0, cx=640.0, cy=400.0, distortion=distortion)
    rng = np.random.default_rng(5)
    corners = []
    for m, S in ((7, 8), (0, 8), (5, 23), (9, 64), (1, 80)):
        ctr = np.column_stack([rng.uniform(-12, 12, m), rng.uniform(-2, 2, m), rng.uniform(-4, 40, m)])
        c = ctr[:, None, :] + rng.normal(0, 1.5, (m, S, 3))
        if S > 8 and m:  # a hull padded to its frame's longest one: copies of its first vertex
            cut = rng.integers(4, S, m)
            for i in range(m):
                c[i, cut[i]:] = c[i, 0]
        corners.append(c)
    a = 0.3  # a second pose: turned about the camera's y axis and moved
    turned = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    for R, t in ((np.eye(3), np.zeros(3)), (turned, np.array([0.4, -0.2, 1.0]))):
        got = refine._project_outlines(corners, R, t, intr, (1280, 800))
        want = project_rects(refine._padded(corners), R, t, intr, (1280, 800))
        assert got[0].shape == want[0].shape == (22, 4)
        assert np.array_equal(_bits(got[0]), _bits(want[0])) and np.array_equal(got[1], want[1])
        assert want[1].any() and not want[1].all()  # some boxes seen, some not
