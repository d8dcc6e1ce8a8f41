"""Matching in a wide-angle camera's own image (issue 26): the geometric consensus behind
``Matcher.match`` and the one-shot augmentation project a 3D box as the outline of its curved
edges under the camera model, not as the rectangle around its 8 projected corners. A synthetic
185-degree Kannala-Brandt site (frames' 2D boxes are the true objects' outlines in that image)."""

from __future__ import annotations

import numpy as np
import pytest

from xcalib.data.crops import prepare_frame
from xcalib.data.synth import generate_frames, sample_site
from xcalib.geometry import box7_corners, iou_matrix
from xcalib.geometry.boxes import boxes2d_from_points
from xcalib.geometry.camera_models import KannalaBrandt, project_outline_rects


@pytest.fixture(scope="module")
def fisheye():
    site = sample_site(0, camera_model="kannala_brandt", hfov_deg=185.0, width=1280, height=800, box_noise_px=0.0)
    frame = generate_frames(site, 1, seed=0, render_images=False)[0]
    return site, frame


def _true_pairs(frame):
    return np.argwhere(np.asarray(frame.match_matrix) > 0)


def test_the_outline_under_the_model_is_the_2d_box_and_8_corners_are_not(fisheye):
    site, frame = fisheye
    assert isinstance(site.intrinsics, KannalaBrandt)
    pairs = _true_pairs(frame)
    b7 = np.asarray(frame.meta["box7_gt"])[pairs[:, 1]]  # the true yawed 3D boxes
    whole = (np.asarray(frame.meta["visibility_2d"])[pairs[:, 0]] > 0.99) & \
        (np.asarray(frame.meta["truncation_2d"])[pairs[:, 0]] < 0.01)
    T = site.T_cam_lidar
    outline, ok = project_outline_rects(box7_corners(b7), T[:3, :3], T[:3, 3], site.intrinsics, (1280, 800))
    clean = np.asarray(frame.meta["boxes_2d_clean"])[pairs[:, 0]]
    sel = ok & whole
    assert sel.sum() >= 3
    iou = np.diag(iou_matrix(outline[sel], clean[sel]))
    assert iou.min() > 0.95, iou  # an unoccluded object's 2D box is its outline in the fisheye image
    # a car 3.7 m from the camera, below it: its 8 corners' rectangle misses the curved lower edge
    box_cam = np.array([[1.0, 2.0, 3.0, 4.5, 1.8, 1.5, 0.0]])  # camera frame (x right, y down, z ahead)
    corners_cam = box7_corners(box_cam)
    rect, ok1 = project_outline_rects(corners_cam, np.eye(3), np.zeros(3), site.intrinsics, (1280, 800), clip=False)
    uv8, _ = site.intrinsics.project(corners_cam[0])
    r8 = boxes2d_from_points(uv8[None])[0]
    assert ok1[0] and np.abs(rect[0] - r8).max() > 5.0
    fine, _ = project_outline_rects(corners_cam, np.eye(3), np.zeros(3), site.intrinsics, (1280, 800), clip=False,
                                    samples=60)
    assert np.abs(rect[0] - fine[0]).max() < 1.0  # dense enough


def test_matcher_geometry_matches_in_the_fisheye_image(fisheye):
    import xcalib

    site, frame = fisheye
    m = xcalib.Matcher.from_pretrained("fastmatch", site="synthetic")
    res = m.match(*frame.inputs(), geometry="on", intrinsics=site.intrinsics, assignment="hungarian",
                  match_threshold=0.5)
    assert res.source == "geometry"
    M = np.asarray(frame.match_matrix)
    pairs = [(int(i), int(j)) for i, j, *_ in res.matches]
    correct = sum(M[i, j] > 0 for i, j in pairs)
    assert len(pairs) >= 0.6 * int((M > 0).sum())
    assert correct >= 0.9 * len(pairs)


def test_oneshot_augment_projects_and_places_through_the_fisheye(fisheye):
    from xcalib.oneshot.augment import GeometricAugment

    site, frame = fisheye
    T = site.T_cam_lidar
    image, cloud, b2, _ = frame.inputs()
    fi = prepare_frame(image, cloud, b2, np.asarray(frame.meta["box7_gt"]))  # the true yawed 3D boxes
    aug = GeometricAugment(site.intrinsics, T[:3, :3], T[:3, 3])
    rects = aug.project(fi)  # no pseudo targets: every 3D box's projected outline, clipped
    M = np.asarray(frame.match_matrix)[np.ix_(fi.kept_2d, fi.kept_3d)]
    pi, pj = np.nonzero(M)
    ok = np.isfinite(rects[pj]).all(1)
    assert ok.sum() >= 5
    iou = np.diag(iou_matrix(rects[pj][ok], fi.boxes_2d[pi][ok].astype(np.float64)))
    assert np.median(iou) > 0.95, iou
    # placing boxes under random pixels goes through the model's unproject: each box's centre lands
    # on the ray of the pixel drawn for it (a pinhole's K^-1 ray would put it elsewhere in a fisheye image)
    b3 = fi.boxes_3d.astype(np.float64)
    c = aug._in_view(b3, 1280, 800, np.random.default_rng(0), tries=1)
    draw = np.random.default_rng(0)
    uv0 = np.stack([draw.uniform(0, 1280, (len(b3), 1)), draw.uniform(0, 800, (len(b3), 1))], -1)[:, 0]
    good = np.isfinite(c).all(1)
    assert good.sum() >= 3
    uv, valid = site.intrinsics.project(c[good] @ T[:3, :3].T + T[:3, 3])
    assert valid.all() and np.abs(uv - uv0[good]).max() < 0.5
    out, tg = aug.apply(fi, _targets(M), np.random.default_rng(1))
    assert np.isfinite(out.boxes_2d).all() and tg.positive.shape == (out.num_2d, out.num_3d)


def _targets(M):
    from xcalib.oneshot.pseudo import PseudoTargets

    return PseudoTargets(M.astype(bool), M.astype(np.float32), ~M.astype(bool))
