"""The consensus refinement's batched projection (``poses_refine._Batch``, issue 29 trims): each
edge taken from its defining corner, found once per projection for the rect and the Jacobian, and
one matrix product per pose. Checked against ``boxproj.project_rects`` (rects and validity, bit for
bit), against the Jacobian as it was computed before (written out below: arg-min / arg-max of
the projected corners with a box that cannot be projected set to 0, then gathered), and against
central differences of the residuals."""

from __future__ import annotations

import numpy as np
import pytest

from xcalib.calib import poses_refine as pr
from xcalib.calib.boxproj import project_rects
from xcalib.calib.cost import INWARD, Occlusion, _distort_with_jacobian
from xcalib.calib.inputs import prepare_frames
from xcalib.data.synth import generate_frames, sample_site
from xcalib.geometry.camera import CameraIntrinsics
from xcalib.geometry.rotations import so3_exp


def _old_jacobian(batch, R, t, raw, valid):
    """``_Batch.jacobian`` as it was (before the defining corners were shared with the rect)."""
    H, P, S = batch.C.shape[:3]
    Y = batch.C @ R.transpose(0, 2, 1)[:, None]
    z = Y[..., 2] + t[:, None, None, 2]
    ahead = z > pr.MIN_DEPTH_M
    inv = 1.0 / np.where(ahead, z, np.nan)
    x = (Y[..., 0] + t[:, None, None, 0]) * inv
    y = (Y[..., 1] + t[:, None, None, 1]) * inv
    if batch.dist is not None:
        x, y = _distort_with_jacobian(x, y, batch.dist)[:2]
    u, v = x * batch.intr.fx + batch.intr.cx, y * batch.intr.fy + batch.intr.cy
    uu, vv = np.where(valid[..., None], u, 0.0), np.where(valid[..., None], v, 0.0)
    hh, pp = np.arange(H)[:, None], np.arange(P)[None, :]
    cols = (uu.argmin(-1), vv.argmin(-1), uu.argmax(-1), vv.argmax(-1))
    ext, Ys = np.empty((H, P, 4)), np.empty((H, P, 4, 3))
    for k, (plane, c) in enumerate(zip((uu, vv, uu, vv), cols)):
        ext[..., k] = plane[hh, pp, c]
        Ys[:, :, k] = Y[hh, pp, c]
    W, Hh = batch.size
    inside = (ext > 0.0) & (ext < np.array([W, Hh, W, Hh], dtype=np.float64))
    izs = 1.0 / np.where(valid[..., None], Ys[..., 2] + t[:, None, None, 2], 1.0)
    xs, ys = (Ys[..., 0] + t[:, None, None, 0]) * izs, (Ys[..., 1] + t[:, None, None, 1]) * izs
    a11, a12, a21, a22 = (1.0, 0.0, 0.0, 1.0) if batch.dist is None else _distort_with_jacobian(xs, ys, batch.dist)[2:]
    is_u = np.array([True, False, True, False])
    f = np.where(is_u, batch.intr.fx, batch.intr.fy)
    c1, c2 = f * np.where(is_u, a11, a21), f * np.where(is_u, a12, a22)
    a = np.stack([c1 * izs, c2 * izs, -(c1 * xs + c2 * ys) * izs], -1)
    D = np.empty(a.shape[:-1] + (6,))
    D[..., 0] = Ys[..., 1] * a[..., 2] - Ys[..., 2] * a[..., 1]
    D[..., 1] = Ys[..., 2] * a[..., 0] - Ys[..., 0] * a[..., 2]
    D[..., 2] = Ys[..., 0] * a[..., 1] - Ys[..., 1] * a[..., 0]
    D[..., 3:] = a
    scale = (inside & valid[..., None]) * (batch.w * batch.mask)[..., None]
    if batch.occlusion is not None:
        scale = np.where(raw * INWARD > batch.occlusion.tau, batch.occlusion.slope * scale, scale)
    return D * scale[..., None]


@pytest.fixture(scope="module", params=[(3, 7, False), (5, 5, True)], ids=["site3", "site5_distorted"])
def case(request):
    seed, frame_seed, distorted = request.param
    site = sample_site(seed)
    f = generate_frames(site, 1, seed=frame_seed, render_images=False, lidar=False, box_noise_px=1.0)[0]
    intr = f.intrinsics
    if distorted:
        intr = CameraIntrinsics(fx=intr.fx, fy=intr.fy, cx=intr.cx, cy=intr.cy, width=intr.width, height=intr.height,
                                distortion=np.array([-0.08, 0.02, 0.001, -0.0005, 0.0]))
    cfs, intr, _ = prepare_frames([f], intr)
    fr, T = cfs[0], site.T_cam_lidar
    rng = np.random.default_rng(seed)
    H = 5
    R = np.stack([so3_exp(rng.normal(size=3) * np.radians(2.0)) @ T[:3, :3] for _ in range(H)])
    t = T[:3, 3] + rng.normal(size=(H, 3)) * 0.3
    t[H - 1, 2] -= 60.0  # one pose with boxes behind the camera: rows that cannot be projected
    seen = np.flatnonzero(project_rects(fr.corners, T[:3, :3], T[:3, 3], intr, fr.size)[1])  # 3D boxes in view
    n = min(fr.n2, len(seen))
    assert n >= 4
    pairs = [np.column_stack([rng.permutation(fr.n2)[:n], rng.permutation(seen)[:n]])[: 2 + h] for h in range(H)]
    sigma = [np.full(len(p), 2.0 + h) for h, p in enumerate(pairs)]
    return fr, intr, pairs, pr._Batch(fr, pairs, sigma, intr, Occlusion()), R, t


def test_batch_rects_are_project_rects(case):
    fr, intr, pairs, batch, R, t = case
    _, _, rect, valid = batch._project(R, t)
    assert not valid[-1].any() and valid[0, : len(pairs[0])].any()  # both kinds of rows
    for h, p in enumerate(pairs):
        ref, ok = project_rects(fr.corners[p[:, 1]], R[h], t[h], intr, fr.size)
        assert np.array_equal(valid[h, : len(p)], ok)
        assert np.array_equal(rect[h, : len(p)][ok], ref[ok])


def test_batch_jacobian_is_the_previous_one(case):
    _, _, _, batch, R, t = case
    _, raw, proj = batch.residuals(R, t)
    J = batch.jacobian(t, raw, proj)
    old = _old_jacobian(batch, R, t, raw, proj[3])
    assert np.all(np.isfinite(J)) and np.abs(J).max() > 0
    assert np.array_equal(J, old)


def test_batch_jacobian_matches_central_differences(case):
    _, _, _, batch, R, t = case
    R, t = R[:-1], t[:-1]  # the poses that project every box
    sub = batch.take(np.arange(len(R)))
    r, raw, proj = sub.residuals(R, t)
    J = sub.jacobian(t, raw, proj)
    eps = 1e-6
    num = np.zeros_like(J)
    for k in range(6):
        d = np.zeros((len(R), 6))
        d[:, k] = eps
        rp = sub.residuals(pr._exp(d[:, :3]) @ R, t + d[:, 3:])[0]
        rm = sub.residuals(pr._exp(-d[:, :3]) @ R, t - d[:, 3:])[0]
        num[..., k] = (rp - rm) / (2 * eps)
    # edges on a corner tie or at the occlusion kink are not differentiable: compare the rest
    smooth = np.abs(num - J).max(-1) < 1e-3 * (1.0 + np.abs(J).max(-1))
    assert smooth.mean() > 0.9
    assert np.allclose(num[smooth], J[smooth], rtol=1e-4, atol=1e-4)
