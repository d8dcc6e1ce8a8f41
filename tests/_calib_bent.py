"""Quick synthetic sites bent the way real sites are (test support for the calibration verdict;
the full suite is ``xcalib.data.synth.realism`` / ``benchmarks/bench_calibration_realism.py``).

``bent_case(variant, seed)`` -> (frames, given intrinsics, true T_cam_lidar). Variants: "clean",
"focal x1.2" / "focal x0.8" / "focal x1.1" / "focal x0.9" (the given fx, fy scaled), "late 0.2 s"
(3D boxes from 2 frames = 0.2 s earlier than the 2D boxes), "mirrored" (u -> W - u), "second
camera" (all boxes of a second camera on the same mount, turned 30 deg, mixed in), "half frames"
(every other frame's 2D boxes from that second camera only).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from xcalib.data.synth import generate_frames, sample_site
from xcalib.geometry import box7_corners, euler_to_matrix, project_points
from xcalib.types import Frame

VARIANTS = ("clean", "focal x1.2", "focal x0.8", "focal x1.1", "focal x0.9", "late 0.2 s", "mirrored",
            "second camera", "half frames")


def _second_camera_boxes(f: Frame, T2: np.ndarray, intr, rng) -> np.ndarray:
    """2D boxes [k,4] of the frame's exact 3D boxes seen by a camera at T2 (no occlusion), 1 px noise."""
    b7 = np.asarray(f.meta["box7_gt"] if "box7_gt" in f.meta else f.meta["box7"], dtype=np.float64)
    if not len(b7):
        return np.zeros((0, 4))
    uv, z = project_points(box7_corners(b7).reshape(-1, 3), intr, T2[:3, :3], T2[:3, 3])
    uv, z = uv.reshape(-1, 8, 2), z.reshape(-1, 8)
    W, H = intr.width, intr.height
    r = np.column_stack([uv[..., 0].min(1), uv[..., 1].min(1), uv[..., 0].max(1), uv[..., 1].max(1)])
    r[:, [0, 2]] = np.clip(r[:, [0, 2]], 0, W)
    r[:, [1, 3]] = np.clip(r[:, [1, 3]], 0, H)
    ok = np.all(z > 0.5, 1) & (r[:, 2] - r[:, 0] > 8) & (r[:, 3] - r[:, 1] > 8) & (rng.random(len(r)) > 0.1)
    return r[ok] + rng.normal(0, 1.0, (int(ok.sum()), 4))


def bent_case(variant: str, seed: int, n_frames: int = 20):
    site = sample_site(seed, preset="roadside")
    noise = dict(miss_rate_2d=0.1, false_positive_rate_2d=0.05, box_noise_px=1.0, center_noise_m=0.0,
                 size_noise_frac=0.0, yaw_noise_deg=0.0)
    frames = generate_frames(site, n_frames + 2, seed=seed, render_images=False, lidar=False, **noise)
    intr, T = site.intrinsics, site.T_cam_lidar
    rng = np.random.default_rng([seed, 99])
    if variant.startswith("focal"):
        s = float(variant.split("x")[1])
        given = dataclasses.replace(intr, fx=intr.fx * s, fy=intr.fy * s)
        return frames[:n_frames], given, T
    if variant == "late 0.2 s":  # 2D boxes at t, 3D boxes from t - 0.2 s (10 Hz frames)
        out = [Frame(**{**f.__dict__, "bboxes_3d": g.bboxes_3d, "meta": {**g.meta}}) for f, g in zip(frames[2:], frames)]
        return out, intr, T
    frames = frames[:n_frames]
    if variant == "mirrored":
        W = intr.width
        out = [Frame(**{**f.__dict__, "bboxes_2d": np.column_stack([W - f.bboxes_2d[:, 2], f.bboxes_2d[:, 1],
                                                                   W - f.bboxes_2d[:, 0], f.bboxes_2d[:, 3]])})
               for f in frames]
        return out, intr, T
    if variant in ("second camera", "half frames"):
        T2 = T.copy()
        T2[:3, :3] = euler_to_matrix([0.0, np.radians(30.0), 0.0]) @ T[:3, :3]  # turned about the camera's y axis
        T2[:3, 3] = euler_to_matrix([0.0, np.radians(30.0), 0.0]) @ T[:3, 3]
        out = []
        for k, f in enumerate(frames):
            b2 = _second_camera_boxes(f, T2, intr, rng)
            if variant == "second camera":
                b2 = np.vstack([f.bboxes_2d, b2])
            elif k % 2 == 0:
                b2 = f.bboxes_2d
            out.append(Frame(**{**f.__dict__, "bboxes_2d": b2, "match_matrix": None}))
        return out, intr, T
    return frames, intr, T
