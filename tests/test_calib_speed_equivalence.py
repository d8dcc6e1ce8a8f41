"""The in-place bring-up arithmetic (issue 12 item 6, speed) gives the same bits as the 0.4.0 code:
``iou_batched`` and ``_pair_distances`` against frozen copies, and ``frame_hypotheses`` on a seeded
crowded synthetic frame against poses recorded with 0.4.0."""

from __future__ import annotations

import numpy as np
import pytest

from xcalib.calib.boxproj import iou_batched, project_rects
from xcalib.calib.hypotheses import _pair_distances


def _iou_batched_040(rects, boxes):  # xcalib 0.4.0, verbatim
    r = np.nan_to_num(rects[:, None, :, :], nan=0.0)
    b = boxes[None, :, None, :]
    iw = np.clip(np.minimum(r[..., 2], b[..., 2]) - np.maximum(r[..., 0], b[..., 0]), 0, None)
    ih = np.clip(np.minimum(r[..., 3], b[..., 3]) - np.maximum(r[..., 1], b[..., 1]), 0, None)
    inter = iw * ih
    ar = (r[..., 2] - r[..., 0]) * (r[..., 3] - r[..., 1])
    ab = (b[..., 2] - b[..., 0]) * (b[..., 3] - b[..., 1])
    union = ar + ab - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def _pair_distances_040(P):  # xcalib 0.4.0, verbatim
    sq = np.einsum("ij,ij->i", P, P)
    d2 = sq[:, None] + sq[None, :] - 2.0 * (P @ P.T)
    return np.sqrt(np.maximum(d2, 0.0))


@pytest.mark.parametrize("seed", range(10))
def test_iou_batched_bitwise_equal_040(seed):
    r = np.random.default_rng(seed)
    H, M, K = (int(v) for v in r.integers([1, 0, 0], [40, 30, 15]))
    xy = r.uniform(-100, 1000, (H, M, 2))
    rects = np.concatenate([xy, xy + r.uniform(-5, 300, (H, M, 2))], -1)
    rects[r.random((H, M)) < 0.3] = np.nan
    bxy = r.uniform(-10, 900, (K, 2))
    boxes = np.concatenate([bxy, bxy + r.uniform(0, 200, (K, 2))], -1)
    if seed % 2:  # shared edges, touching and degenerate boxes
        rects, boxes = np.round(rects, -1), np.round(boxes, -1)
    got, want = iou_batched(rects, boxes), _iou_batched_040(rects, boxes)
    assert got.shape == want.shape == (H, K, M)
    assert got.tobytes() == want.tobytes()
    if got.size:
        assert 0.0 <= got.min() and got.max() <= 1.0


@pytest.mark.parametrize("n", [1, 7, 300])
def test_pair_distances_bitwise_equal_040(n):
    P = np.random.default_rng(n).normal(scale=30.0, size=(n, 3))
    P[n // 2] = P[0]  # a zero distance off the diagonal
    got, want = _pair_distances(P), _pair_distances_040(P)
    assert got.tobytes() == want.tobytes()
    assert np.all(got >= 0)


def _project_rects_040(corners, R, t, intr, size, clip=True):  # xcalib 0.4.0, verbatim
    from xcalib.calib.boxproj import MIN_DEPTH_M
    from xcalib.geometry.projection import distort_normalized

    single = np.ndim(R) == 2
    R = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    t = np.asarray(t, dtype=np.float64).reshape(-1, 3)
    c = np.asarray(corners, dtype=np.float64)
    H, M = len(R), len(c)
    S = c.shape[1]
    X = np.matmul(R, c.reshape(-1, 3).T) + t[:, :, None]
    z = X[:, 2].reshape(H, M, S)
    front = np.all(z > MIN_DEPTH_M, axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(z > MIN_DEPTH_M, 1.0 / z, np.nan)
    x = X[:, 0].reshape(H, M, S) * inv
    y = X[:, 1].reshape(H, M, S) * inv
    if intr.distortion is not None:
        flat = np.clip(np.stack([x.ravel(), y.ravel()], 1), -1.5, 1.5)
        d = distort_normalized(flat, intr.distortion)
        x, y = d[:, 0].reshape(H, M, S), d[:, 1].reshape(H, M, S)
    u = x * intr.fx + intr.cx
    v = y * intr.fy + intr.cy
    with np.errstate(invalid="ignore"):
        rect = np.stack([u.min(2), v.min(2), u.max(2), v.max(2)], axis=-1)
    if clip:
        W, Hh = size
        rect[..., [0, 2]] = np.clip(rect[..., [0, 2]], 0.0, W)
        rect[..., [1, 3]] = np.clip(rect[..., [1, 3]], 0.0, Hh)
    with np.errstate(invalid="ignore"):
        valid = front & (rect[..., 2] - rect[..., 0] > 1.0) & (rect[..., 3] - rect[..., 1] > 1.0)
    rect[~valid] = np.nan
    return (rect[0], valid[0]) if single else (rect, valid)


@pytest.mark.parametrize("seed", range(6))
def test_project_rects_bitwise_equal_040(seed):
    from xcalib.calib.boxproj import project_rects
    from xcalib.geometry.camera import CameraIntrinsics
    from xcalib.geometry.rotations import rotvec_to_matrix

    r = np.random.default_rng(seed)
    dist = None if seed % 2 else np.array([-0.3, 0.1, 1e-3, -1e-3, 0.0])
    intr = CameraIntrinsics(fx=900.0, fy=910.0, cx=640.0, cy=360.0, width=1280, height=720, distortion=dist)
    H, M = (int(r.integers(1, 20)), int(r.integers(1, 30))) if seed < 3 else (int(r.integers(150, 300)), 30)
    corners = r.uniform(-30, 30, (M, (8, 1, 3)[seed % 3], 3))  # box corners, single points, outlines
    corners[:, :, 2] += 15.0
    R = np.stack([rotvec_to_matrix(v) for v in r.normal(scale=0.4, size=(H, 3))])
    t = r.normal(scale=2.0, size=(H, 3))
    valid = []
    for args in ((R, t), (R[0], t[0])):
        got, want = project_rects(corners, *args, intr, (1280, 720)), _project_rects_040(corners, *args, intr, (1280, 720))
        assert got[0].tobytes() == want[0].tobytes() and np.array_equal(got[1], want[1])
        valid.append(want[1])
    if corners.shape[1] > 1:  # (a single point has an empty rectangle: never valid)
        assert valid[0].any() and not valid[0].all()  # boxes in view and out of it


@pytest.mark.parametrize("seed", range(4))
def test_centre_hits_equal_broadcast_form(seed):
    from dataclasses import dataclass

    from xcalib.calib.hypotheses import _centre_hits
    from xcalib.geometry.camera import CameraIntrinsics
    from xcalib.geometry.rotations import rotvec_to_matrix

    @dataclass
    class _Fr:  # the fields _centre_hits reads
        boxes2d: np.ndarray
        boxes3d: np.ndarray

        @property
        def n2(self):
            return len(self.boxes2d)

        @property
        def n3(self):
            return len(self.boxes3d)

    r = np.random.default_rng(seed)
    intr = CameraIntrinsics(fx=800.0, fy=800.0, cx=640.0, cy=360.0, width=1280, height=720)
    K, M, H = 25, 60, 40
    xy = r.uniform(0, 1200, (K, 2))
    fr = _Fr(np.concatenate([xy, xy + r.uniform(5, 300, (K, 2))], 1), np.c_[r.uniform(-20, 20, (M, 2)),
                                                                             r.uniform(-2, 40, M)])
    R = np.stack([rotvec_to_matrix(v) for v in r.normal(scale=0.3, size=(H, 3))])
    t = r.normal(size=(H, 3))
    Xc = np.einsum("hij,mj->hmi", R, fr.boxes3d[:, :3]) + t[:, None, :]  # the 0.4.0 broadcast form
    z = Xc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(z > 0.5, Xc[..., 0] / z * intr.fx + intr.cx, np.nan)
        v = np.where(z > 0.5, Xc[..., 1] / z * intr.fy + intr.cy, np.nan)
    b = fr.boxes2d
    inside = ((u[:, None, :] >= b[None, :, 0, None]) & (u[:, None, :] <= b[None, :, 2, None])
              & (v[:, None, :] >= b[None, :, 1, None]) & (v[:, None, :] <= b[None, :, 3, None]))
    want = inside.any(2).sum(1).astype(np.float64)
    got = _centre_hits(fr, intr, R, t, max_elems=(5000, 10**7)[seed % 2])  # chunked and not
    assert 0 < want.max() and np.array_equal(got, want)


def _third_members_060(Cs, pq, rng, pair_w, block=1024):  # xcalib 0.6.0, verbatim (argpartition + sort)
    out = []
    for s in range(0, len(pq), block):
        p = pq[s:s + block]
        both = Cs[p[:, 0]] & Cs[p[:, 1]]
        keys = np.where(both, rng.random(both.shape), -1.0)
        if pair_w is not None:
            keys = np.where(both, keys + pair_w[None, :], -np.inf)
        k = min(2, keys.shape[1])
        third = np.argpartition(-keys, k - 1, axis=1)[:, :k]
        third = np.take_along_axis(third, np.argsort(-np.take_along_axis(keys, third, 1), axis=1, kind="stable"), 1)
        okr = np.take_along_axis(both, third, 1)
        out.append(np.column_stack([np.repeat(p, k, axis=0), third.ravel()])[okr.ravel()])
    return np.concatenate(out) if out else np.zeros((0, 3), dtype=np.int64)


@pytest.mark.parametrize("seed", range(16))
def test_third_members_same_triples_as_060(seed):
    """``hypotheses._third_members`` (two arg-max passes, issue 29; without priors the incompatible
    members' keys shifted below the compatible ones in place, session 15) draws the same third
    members in the same order as the partition-and-sort of 0.6.0, with and without prior weights,
    on sparse and dense compatibility (rows with 0, 1 and 2+ compatible members) and blocks of rows."""
    from xcalib.calib.hypotheses import _third_members

    r = np.random.default_rng(seed)
    n = int(r.integers(3, 60))
    C = r.random((n, n)) < (0.05 if seed % 3 == 0 else 0.4)
    C = C | C.T
    np.fill_diagonal(C, False)
    pq = np.argwhere(np.triu(r.random((n, n)) < 0.5, 1))
    w = r.normal(size=n) if seed % 2 else None
    got = _third_members(C, pq, np.random.default_rng(seed), w, block=7 if seed % 4 == 1 else 1024)
    want = _third_members_060(C, pq, np.random.default_rng(seed), w, block=7 if seed % 4 == 1 else 1024)
    assert got.shape[1] == 3 and got.tobytes() == want.tobytes()
    if len(got):
        assert np.all(C[got[:, 0], got[:, 2]] & C[got[:, 1], got[:, 2]])


@pytest.mark.parametrize("seed", range(6))
def test_near_xy_same_points_as_kdtree(seed):
    """``boxshape._NearXY`` (the yaw fit's disc query, issue 29: sorted x and bisection instead of a
    k-d tree) returns exactly the rows ``cKDTree.query_ball_point`` does, ascending, points on the
    circle included (integer grids put many exactly at the radius)."""
    from scipy.spatial import cKDTree

    from xcalib.calib.boxshape import _NearXY

    r = np.random.default_rng(seed)
    if seed % 2:
        pts = np.c_[r.integers(-20, 20, (3000, 2)).astype(np.float64), r.normal(size=3000)]
    else:
        pts = np.c_[r.uniform(-50, 50, (5000, 2)), r.normal(size=5000)]
    tree, near = cKDTree(pts[:, :2]), _NearXY(pts)
    for x, y, rad in np.c_[r.integers(-25, 25, (40, 2)), r.integers(0, 6, 40)].astype(np.float64).tolist() + \
            r.uniform([-60, -60, 0.1], [60, 60, 9.0], (40, 3)).tolist():
        want = np.sort(np.asarray(tree.query_ball_point([x, y], rad), dtype=np.int64))
        got = near.within(x, y, rad)
        assert np.array_equal(got, want)
    assert len(near.within(0.0, 0.0, 3.0)) > 0


@pytest.mark.parametrize("seed", range(3))
def test_fit_yaw_independent_of_point_order(seed):
    """The yaw fit depends on the points near a box, not on their order (the disc query's order
    changed from a k-d tree's to ascending rows): a shuffled cloud gives the same yaw to rounding."""
    from xcalib.calib.boxshape import fit_yaw_to_points

    r = np.random.default_rng(seed)
    boxes, clouds = [], []
    for k in range(6):  # L-shaped returns of turned boxes
        x, y, yaw, ln, wd = r.uniform(-30, 30), r.uniform(-30, 30), r.uniform(0, np.pi), r.uniform(3.5, 5), 1.8
        s = r.uniform(-0.5, 0.5, 80)
        side = np.r_[np.c_[s * ln, np.full(80, wd / 2)], np.c_[np.full(80, ln / 2), s * wd]]
        c, si = np.cos(yaw), np.sin(yaw)
        xy = side @ np.array([[c, si], [-si, c]]) + [x, y] + r.normal(scale=0.03, size=(160, 2))
        clouds.append(np.c_[xy, r.uniform(0.4, 1.0, 160)])
        boxes.append([x, y, 0.75, ln, wd, 1.5, 0.0])
    pts = np.concatenate(clouds + [r.uniform([-40, -40, -0.2], [40, 40, 2.0], (3000, 3))])
    a = fit_yaw_to_points(np.array(boxes), pts)
    b = fit_yaw_to_points(np.array(boxes), pts[r.permutation(len(pts))])
    assert a.fitted.all() and np.array_equal(a.fitted, b.fitted) and np.array_equal(a.n_points, b.n_points)
    assert np.allclose(a.boxes7, b.boxes7, rtol=0, atol=1e-12) and np.allclose(a.contrast, b.contrast, rtol=1e-12)


def test_closed_form_search_same_poses():
    """The bring-up's per-frame search fits its triples in closed form (``TripleSearch.closed_form``,
    issue 29): on a seeded synthetic frame the same hypotheses as the SVD Kabsch, to 1e-9."""
    from dataclasses import replace

    from xcalib.calib.hypotheses import TripleSearch, frame_hypotheses
    from xcalib.calib.inputs import prepare_frames
    from xcalib.data.synth import generate_frames, sample_site

    site = sample_site(0, preset="roadside")
    frames = generate_frames(site, 3, seed=0, render_images=False, lidar=False)
    cframes, intr, _ = prepare_frames(frames, site.intrinsics)
    fr = max(cframes, key=lambda f: f.n2 * f.n3)
    base = TripleSearch()
    svd = frame_hypotheses(fr, intr, 0, rng=np.random.default_rng(3), search=base)
    closed = frame_hypotheses(fr, intr, 0, rng=np.random.default_rng(3), search=replace(base, closed_form=True))
    assert len(svd) > 5 and len(svd) == len(closed)
    assert np.allclose(closed.R, svd.R, atol=1e-9) and np.allclose(closed.t, svd.t, atol=1e-9)
    assert np.allclose(closed.score, svd.score, atol=1e-9)


def _assign_lsa(iou, dist, valid, gate_iou, gate_dist):  # refine._assign before issue 29's shortcut, verbatim
    from scipy.optimize import linear_sum_assignment

    dist = np.where(valid[None], dist, np.inf)
    allowed = (iou >= gate_iou) if gate_dist <= 0 else ((iou >= gate_iou) | (dist <= gate_dist))
    allowed &= valid[None]
    if not np.any(allowed):
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    cost = np.where(allowed, (1 - iou) + np.minimum(dist, 10.0), 1e6)
    r, c = linear_sum_assignment(cost)
    keep = allowed[r, c]
    pairs = np.column_stack([r[keep], c[keep]]).astype(np.int64)
    return pairs, iou[r[keep], c[keep]]


def test_assign_same_pairs_as_assignment():
    """``refine._assign`` takes the allowed pairs as they are when they share no box (issue 29):
    the same pairs, in the same order, and IoUs as the assignment, on sparse gates (the shortcut)
    and crowded ones (the assignment), with and without the centre-distance gate."""
    from xcalib.calib.refine import _assign

    short = 0
    for seed in range(300):
        r = np.random.default_rng(seed)
        K, M = int(r.integers(1, 12)), int(r.integers(1, 15))
        sparse = seed % 2 == 1
        hit = r.random((K, M)) < (0.7 / max(K, M) if sparse else 0.5)
        iou = np.where(hit, r.uniform(0.3, 1.0, (K, M)), r.uniform(0, 0.3, (K, M)))
        dist = r.uniform(0, 3, (K, M))
        valid = r.random(M) < 0.85
        gate = (0.3, 0.0) if seed % 3 else (0.1, 0.4 if not sparse else 0.02)
        got, want = _assign(iou, dist, valid, *gate), _assign_lsa(iou, dist, valid, *gate)
        assert got[0].dtype == want[0].dtype and got[0].tobytes() == want[0].tobytes(), seed
        assert got[1].tobytes() == want[1].tobytes(), seed
        al = want[0]
        short += bool(len(al) and (hit & valid[None]).sum(0).max() <= 1 and (hit & valid[None]).sum(1).max() <= 1)
    assert 40 <= short <= 260  # both the shortcut and the assignment were taken


def test_score_poses_independent_of_the_batch():
    """Each pose is scored on its own: one call over all hypotheses gives, bit for bit, the
    concatenated scores of the searches' batches (the serial bring-up scores them together, issue 29)."""
    from xcalib.calib.hypotheses import score_poses
    from xcalib.calib.inputs import prepare_frames
    from xcalib.data.synth import generate_frames, sample_site
    from xcalib.geometry.rotations import rotvec_to_matrix

    site = sample_site(1, preset="roadside")
    frames = generate_frames(site, 2, seed=1, render_images=False, lidar=False)
    cframes, intr, _ = prepare_frames(frames, site.intrinsics)
    r = np.random.default_rng(0)
    T = site.T_cam_lidar
    R = np.stack([rotvec_to_matrix(v) @ T[:3, :3] for v in r.normal(scale=0.05, size=(250, 3))])
    t = T[:3, 3] + r.normal(scale=0.5, size=(250, 3))
    for fr in cframes:
        whole = score_poses(fr, intr, R, t)
        parts = np.concatenate([score_poses(fr, intr, R[s:s + 25], t[s:s + 25]) for s in range(0, 250, 25)])
        assert whole.max() > 1.0 and whole.tobytes() == parts.tobytes()


def _match_frames_per_frame(frames, proj, gate_iou, gate_dist):  # refine._match_frames's assignment loop before s7
    from xcalib.calib.refine import _assign, _match_projected

    out = []
    for fr, (rects, valid) in zip(frames, proj):
        out.append(_match_projected(fr, rects, valid, gate_iou, gate_dist)[0] if fr.n2 and fr.n3 and np.any(valid)
                   else np.zeros((0, 2), dtype=np.int64))
    return out


@pytest.mark.parametrize("gate", [(0.3, 0.0), (0.2, 0.5), (0.1, 1.0)])
def test_match_frames_conflict_free_shortcut(gate):
    """``refine._match_frames`` decides ``_assign``'s no-shared-box shortcut for all frames in one
    array computation (issue 29, session 7): the same pairs, in the same order and dtype, as
    matching each frame on its own, at poses near and far from the truth, on frames of several
    sizes (padding) and with boxes behind the camera; both the shortcut and the assignment taken."""
    from xcalib.calib.inputs import prepare_frames
    from xcalib.calib.refine import _conflict_free, _match_frames, project_frames
    from xcalib.data.synth import generate_frames, sample_site
    from xcalib.geometry.rotations import rotvec_to_matrix

    site = sample_site(2, preset="roadside")
    frames = generate_frames(site, 12, seed=4, render_images=False, lidar=False, miss_rate_2d=0.2,
                             false_positive_rate_2d=0.2, box_noise_px=3.0)
    cframes, intr, _ = prepare_frames(frames, site.intrinsics)
    T = site.T_cam_lidar
    r = np.random.default_rng(7)
    kinds = set()
    for scale in (0.0, 0.01, 0.03, 0.08, 0.3):
        R = rotvec_to_matrix(r.normal(scale=scale, size=3)) @ T[:3, :3]
        t = T[:3, 3] + r.normal(scale=10 * scale, size=3)
        proj = project_frames(cframes, intr, R, t)
        got = _match_frames(cframes, proj, *gate)
        want = _match_frames_per_frame(cframes, proj, *gate)
        for g, w in zip(got, want):
            assert g.dtype == w.dtype and g.shape == w.shape and g.tobytes() == w.tobytes()
        kinds.update("shortcut" if len(w) else "none" for w in want)
    # the batch decision itself on padded random blocks: the frames it keeps are exactly those
    # whose allowed pairs share no box, with argwhere's pairs
    rr = np.random.default_rng(1)
    n2, n3 = [3, 7, 1, 5, 0], [4, 2, 6, 6, 3]
    iou = rr.uniform(0, 1, (5, 7, 6)) ** 3
    dist = rr.uniform(0, 2, (5, 7, 6))
    simple, _ = _conflict_free(iou, dist, n2, n3, *gate)
    for i in range(5):
        a = (iou[i, :n2[i], :n3[i]] >= gate[0]) | ((dist[i, :n2[i], :n3[i]] <= gate[1]) if gate[1] > 0 else False)
        free = (a.sum(0).max(initial=0) <= 1) and (a.sum(1).max(initial=0) <= 1)
        assert (i in simple) == free
        if free:
            assert simple[i].tobytes() == np.argwhere(a).astype(np.int64).tobytes()
    assert kinds


def _seeded_edge_problem(seed: int):
    """A seeded synthetic frame set, its matches at the truth, and a BoxEdgeTerm model (boxes cut by
    the image border included)."""
    from xcalib.calib.inputs import prepare_frames
    from xcalib.calib.pose import Pose
    from xcalib.calib.refine import build_cost, match_all
    from xcalib.data.synth import generate_frames, sample_site

    site = sample_site(seed, preset="roadside")
    frames = generate_frames(site, 6, seed=seed, render_images=False, lidar=False, box_noise_px=2.0)
    cframes, intr, _ = prepare_frames(frames, site.intrinsics)
    T = site.T_cam_lidar
    pairs = match_all(cframes, intr, T[:3, :3], T[:3, 3])
    return cframes, intr, T, build_cost(cframes, pairs, intr, Pose(T[:3, :3], T[:3, 3]))


@pytest.mark.parametrize("seed", [0, 3])
def test_jacobian_clipped_edge_mask_from_clipped_rects(seed):
    """``BoxEdgeTerm.jacobian`` takes the clipped-edge mask from the clipped rectangles (issue 29,
    session 7): the same mask as the unclipped defining-corner edges strictly inside the image gave,
    at poses that push boxes across the border."""
    from xcalib.calib.cost import BoxEdgeTerm, PoseState
    from xcalib.calib.pose import Pose
    from xcalib.geometry.rotations import rotvec_to_matrix

    _, intr, T, model = _seeded_edge_problem(seed)
    term = next(t for t in model.terms if type(t) is BoxEdgeTerm)
    r = np.random.default_rng(seed)
    W, H = term.size
    lim = np.array([W, H, W, H], dtype=np.float64)
    clipped = 0
    for _ in range(30):
        R = rotvec_to_matrix(r.normal(scale=0.15, size=3)) @ T[:3, :3]
        rects, valid, u, v = term._projection(PoseState(Pose(R, T[:3, 3] + r.normal(scale=1.0, size=3)), intr))
        u, v = u[term.ragged.padded], v[term.ragged.padded]  # the vertices' pixels as padded rows [n,S]
        uu, vv = np.where(valid[:, None], u, 0.0), np.where(valid[:, None], v, 0.0)
        rows = np.arange(len(uu))
        ext = np.column_stack([uu[rows, uu.argmin(1)], vv[rows, vv.argmin(1)], uu[rows, uu.argmax(1)],
                               vv[rows, vv.argmax(1)]])
        old = (ext > 0.0) & (ext < lim)
        with np.errstate(invalid="ignore"):
            new = (rects > 0.0) & (rects < lim)
        assert np.array_equal(old & valid[:, None], new & valid[:, None])
        assert not new[~valid].any()
        clipped += int((valid[:, None] & ~new).sum())
    assert clipped > 0  # edges at the border were exercised


def test_cost_model_state_cache_same_fit():
    """``CostModel.state`` keeps its last state (issue 29, session 7): the fit, its residuals and
    the Jacobians are bit for bit those of a model that rebuilds the state at every call."""
    from xcalib.calib.cost import CostModel

    class Uncached(CostModel):
        def state(self, x):
            self._last_state = None
            return super().state(x)

    _, _, _, model = _seeded_edge_problem(1)
    plain = Uncached(model.terms, model.pose0, model.intr)
    a, b = model.fit(f_scale=1.0, max_nfev=40), plain.fit(f_scale=1.0, max_nfev=40)
    assert a.x.tobytes() == b.x.tobytes() and a.residuals.tobytes() == b.residuals.tobytes() and a.cost == b.cost
    x = np.full(model.n_params, 1e-3)
    assert model.residuals(x).tobytes() == plain.residuals(x).tobytes()
    assert model.analytic_jacobian(x).tobytes() == plain.analytic_jacobian(x).tobytes()
    x2 = x.copy()
    x2[0] += 1e-4  # a new x: a new state
    assert model.state(x2).pose.R.tobytes() != model.state(x).pose.R.tobytes()


def _padded_outlines(r, n: int, S: int) -> np.ndarray:
    """n random outlines [n,S,3] in front of / around a camera looking along +x (LiDAR frame), each
    padded after a random length by repeating its first vertex (as ``refine._padded`` does)."""
    c = r.normal(size=(n, 1, 3)) * np.array([4.0, 8.0, 1.0]) + np.array([12.0, 0.0, 0.0])
    o = c + r.normal(scale=1.5, size=(n, S, 3))
    o[: n // 5, :, 0] -= 14.0  # some outlines (partly) behind the camera
    lengths = r.integers(1, S + 1, size=n)
    for i, L in enumerate(lengths):
        o[i, L:] = o[i, 0]
    return o


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_project_ragged_matches_project_rects(seed):
    """``boxproj.project_ragged`` of the outlines without their padding gives ``project_rects``'
    rects and valid to the bit (issue 29, session 8), with and without distortion, with outlines
    behind the camera and cut by the image border; the vertices' pixels are the padded rows'."""
    from xcalib.calib.boxproj import project_ragged, ragged_outlines
    from xcalib.geometry.camera import CameraIntrinsics
    from xcalib.geometry.rotations import rotvec_to_matrix

    r = np.random.default_rng(seed)
    o = _padded_outlines(r, 60, 24)
    rg = ragged_outlines(o)
    assert len(rg.flat) < o.shape[0] * o.shape[1]
    assert np.array_equal(rg.flat[rg.padded], o)
    R0 = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # LiDAR x forward -> camera z
    for dist in (None, [-0.3, 0.1, 0.001, -0.002, 0.0]):
        intr = CameraIntrinsics(fx=900.0, fy=910.0, cx=640.0, cy=360.0, width=1280, height=720, distortion=dist)
        for _ in range(5):
            R = rotvec_to_matrix(r.normal(scale=0.2, size=3)) @ R0
            t = r.normal(scale=0.5, size=3)
            want = project_rects(o, R, t, intr, (1280, 720), corner_uv=True)
            got = project_ragged(rg.flat, rg.starts, R, t, intr, (1280, 720))
            assert want[0].tobytes() == got[0].tobytes() and np.array_equal(want[1], got[1])
            assert 0 < want[1].sum() < len(o)  # some outlines valid, some not
            for k in (2, 3):  # u, v: the same bits (NaN behind the camera)
                assert np.array_equal(want[k], got[k][rg.padded], equal_nan=True)


@pytest.mark.parametrize("seed", [0, 3])
def test_edge_term_defining_corners_unpadded(seed):
    """``BoxEdgeTerm`` projects its outlines without the padding: the defining corner of every
    edge (the point whose derivative the Jacobian takes) is the one the argmin / argmax over the
    padded rows picked (session 7's code), and residuals and Jacobian are finite."""
    from xcalib.calib.cost import BoxEdgeTerm, PoseState
    from xcalib.calib.pose import Pose
    from xcalib.geometry.rotations import rotvec_to_matrix

    _, intr, T, model = _seeded_edge_problem(seed)
    term = next(t for t in model.terms if type(t) is BoxEdgeTerm)
    r = np.random.default_rng(seed)
    for _ in range(20):
        R = rotvec_to_matrix(r.normal(scale=0.15, size=3)) @ T[:3, :3]
        st = PoseState(Pose(R, T[:3, 3] + r.normal(scale=1.0, size=3)), intr)
        rects, valid, u, v = term._projection(st)
        want_r, want_v, uu, vv = project_rects(term.outlines, st.pose.R, st.pose.t, intr, term.size, corner_uv=True)
        assert rects.tobytes() == want_r.tobytes() and np.array_equal(valid, want_v)
        uu, vv = np.where(valid[:, None], uu, 0.0), np.where(valid[:, None], vv, 0.0)
        idx = np.column_stack([uu.argmin(1), vv.argmin(1), uu.argmax(1), vv.argmax(1)])
        old = term.outlines[np.arange(len(idx))[:, None], idx]
        new = term.ragged.flat[term._defining(u, v, valid)]
        assert old.tobytes() == new.tobytes()
        assert np.all(np.isfinite(term.jacobian(st, np.zeros(3), [])))
