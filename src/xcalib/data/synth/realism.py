"""Realism suite: synthetic roadside sites bent the way real sites are, with the truth kept aside.

A :class:`RealismCondition` (typed, frozen) says how a site is bent; :data:`REALISM_CONDITIONS`
holds the registered ones (``register_condition`` adds more). ``make_realism_case(condition,
site_seed, n_frames=20)`` returns a :class:`RealismCase`: the frames as the calibrator sees them
(``Frame.intrinsics`` = the *given* intrinsics, no ground-truth extrinsics or match matrix), the
given and the true intrinsics, the true ``T_cam_lidar`` and the true time offset.

Every condition starts from the same base: ``sample_site(site_seed, "roadside")`` (the same
poses for every condition), 2D boxes with 1 px noise, 10 % missed and 5 % false 2D boxes, the
generator's 5 % missed / 5 % false 3D boxes, exact 3D boxes (no centre, size or yaw noise),
10 Hz, no LiDAR points unless the condition needs them. Physical conditions are generator
options (:class:`~xcalib.data.synth.presets.SiteConfig`): focal / principal-point error of the
given intrinsics, camera-LiDAR time offset (2D boxes at the camera time, 3D boxes at the LiDAR
time), yaw-less 3D boxes, LiDAR blind ring, queues, mirrored camera. The second camera is a
second :class:`Site` on the same mount, turned 25-35 deg about the vertical, seeing the same
traffic; its 2D boxes are mixed into the first camera's frames.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np

from ...geometry.camera import CameraIntrinsics
from ...geometry.rotations import euler_to_matrix
from ...types import Frame
from .detector import DetectorStyle, detector_frame
from .generate import generate_frames
from .presets import preset_config
from .site import Site, sample_site

__all__ = ["RealismCondition", "RealismCase", "REALISM_CONDITIONS", "register_condition", "make_realism_case",
           "second_camera_site", "identifiable_site_seeds", "MIN_OBJECTS", "MIN_TRUE_PAIRS"]

#: A site is identifiable when its clean frames show >= MIN_OBJECTS distinct objects to both
#: sensors and >= MIN_TRUE_PAIRS true 2D-3D detections (as ``benchmarks/bench_calibration.py``).
MIN_OBJECTS = 3
MIN_TRUE_PAIRS = 20

SecondCamera = Literal["none", "some_boxes", "all_boxes", "half_frames"]


@dataclass(frozen=True)
class RealismCondition:
    """How a site is bent (defaults: the clean base described in the module docstring).

    focal_scale: given fx, fy = true x this. principal_offset_frac: given cx = true cx + this x
    image width. time_offset_s: camera time minus LiDAR time (2D boxes at the camera time).
    vehicle_speed_mps: range of vehicle speeds (None: the generator's 5-13 m/s).
    box3d_yaw: "dropped" exports [M,6] boxes with yaw 0 (length along LiDAR x, as A9).
    lidar_blind_radius_m: no 3D boxes / points nearer the LiDAR (horizontal range).
    moving_share / queue_share / queue_max: traffic mix (see ``SiteConfig``).
    second_camera: "some_boxes" adds a second camera's boxes as ``second_camera_share`` of each
    frame's 2D boxes, "all_boxes" adds all of them, "half_frames" takes every other frame's
    2D (and 3D) boxes from the second camera. mirrored: the image and 2D boxes are flipped.
    box_noise_px ... yaw_noise_deg: detection noise (``iter_frames`` noise fields).
    lidar_points: generate the LiDAR sweep (needed where the calibrator uses points).
    box3d_frame: "camera" gives the 3D boxes (centres moved by the true ``T_cam_lidar``, size and
    yaw kept, as a converter that moves centres only) and the points in the camera frame.
    detector: the 2D boxes as a real detector draws them (``xcalib.data.synth.detector``: visible
    outline, merges, class-dependent misses and false boxes, score-dependent noise; None: exact
    boxes with ``box_noise_px``). max_truncation: share of an object's box outside the image up to
    which it is still detected (None: the site's 0.6).
    """

    name: str
    description: str
    focal_scale: float = 1.0
    principal_offset_frac: float = 0.0
    time_offset_s: float = 0.0
    vehicle_speed_mps: tuple[float, float] | None = None
    box3d_yaw: Literal["kept", "dropped"] = "kept"
    lidar_blind_radius_m: float = 0.0
    moving_share: float = 1.0
    queue_share: float = 0.25
    queue_max: int = 6
    second_camera: SecondCamera = "none"
    second_camera_share: float = 0.3
    mirrored: bool = False
    box_noise_px: float = 1.0
    miss_rate_2d: float = 0.1
    false_positive_rate_2d: float = 0.05
    miss_rate_3d: float = 0.05
    center_noise_m: float = 0.0
    size_noise_frac: float = 0.0
    yaw_noise_deg: float = 0.0
    lidar_points: bool = False
    box3d_frame: Literal["lidar", "camera"] = "lidar"
    detector: DetectorStyle | None = None
    max_truncation: float | None = None

    def __post_init__(self) -> None:
        for name, allowed in (("second_camera", get_args(SecondCamera)), ("box3d_yaw", ("kept", "dropped")),
                              ("box3d_frame", ("lidar", "camera"))):
            if getattr(self, name) not in allowed:
                raise ValueError(f"RealismCondition.{name}: expected one of {allowed}, got {getattr(self, name)!r}")
        if not self.focal_scale > 0 or not 0.0 <= self.second_camera_share < 1.0:
            raise ValueError(f"RealismCondition {self.name!r}: focal_scale must be > 0 and second_camera_share "
                             f"in [0, 1), got {self.focal_scale}, {self.second_camera_share}")

    def site_overrides(self, width: int) -> dict:
        """``sample_site`` keyword overrides of this condition (image ``width`` in pixels)."""
        o = dict(given_focal_scale=self.focal_scale,
                 given_principal_offset_px=(self.principal_offset_frac * width, 0.0),
                 camera_time_offset_s=self.time_offset_s, box3d_yaw=self.box3d_yaw,
                 lidar_blind_radius_m=self.lidar_blind_radius_m, moving_share=self.moving_share,
                 queue_share=self.queue_share, queue_max=self.queue_max, image_mirrored=self.mirrored)
        if self.vehicle_speed_mps is not None:
            o["vehicle_speed"] = tuple(self.vehicle_speed_mps)
        if self.max_truncation is not None:
            o["max_truncation"] = float(self.max_truncation)
        return o

    def noise(self) -> dict[str, float]:
        """``iter_frames`` noise overrides of this condition."""
        return dict(box_noise_px=self.box_noise_px, miss_rate_2d=self.miss_rate_2d,
                    false_positive_rate_2d=self.false_positive_rate_2d, miss_rate_3d=self.miss_rate_3d,
                    center_noise_m=self.center_noise_m, size_noise_frac=self.size_noise_frac,
                    yaw_noise_deg=self.yaw_noise_deg)


REALISM_CONDITIONS: dict[str, RealismCondition] = {}


def register_condition(cond: RealismCondition) -> RealismCondition:
    """Add ``cond`` to :data:`REALISM_CONDITIONS` (its name must be new)."""
    if cond.name in REALISM_CONDITIONS:
        raise ValueError(f"realism condition {cond.name!r} is already registered")
    REALISM_CONDITIONS[cond.name] = cond
    return cond


def _builtin() -> None:
    C = RealismCondition
    register_condition(C("clean", "the base: 1 px 2D noise, 10 % missed / 5 % false 2D boxes, exact 3D boxes"))
    for pct in (5, 10, 20):
        for sign, word in ((1, "+"), (-1, "-")):
            s = 1.0 + sign * pct / 100.0
            register_condition(C(f"focal{word}{pct}%", f"given fx, fy = true x {s:g}", focal_scale=s))
    register_condition(C("principal_point+3%W", "given cx = true cx + 3 % of the image width",
                         principal_offset_frac=0.03))
    register_condition(C("clean_4px", "the base with 4 px 2D box noise (a real detector's)", box_noise_px=4.0))
    register_condition(C("principal_point+3%W_4px", "given cx = true cx + 3 % of the image width, 4 px 2D box noise",
                         principal_offset_frac=0.03, box_noise_px=4.0))
    for dt in (0.05, 0.1, 0.2):
        register_condition(C(f"time_offset_{dt:g}s", f"camera fires {dt:g} s before the LiDAR (3D boxes "
                             f"{dt:g} s late); vehicles at 5-15 m/s, 10 Hz", time_offset_s=-dt,
                             vehicle_speed_mps=(5.0, 15.0)))
    register_condition(C("no_yaw", "3D boxes exported without yaw as A9 ([M,6], length along LiDAR x); "
                         "LiDAR points given", box3d_yaw="dropped", lidar_points=True))
    register_condition(C("blind_ring", "no LiDAR returns or 3D boxes within 15 m of the LiDAR pole",
                         lidar_blind_radius_m=15.0))
    register_condition(C("queues", "mostly queued vehicles repeated in every frame (moving traffic x0.15, "
                         "queues up to 10 long)", moving_share=0.15, queue_share=1.0, queue_max=10))
    register_condition(C("second_camera_30%", "30 % of each frame's 2D boxes from a second camera on the "
                         "same mount turned 25-35 deg", second_camera="some_boxes"))
    register_condition(C("second_camera_all", "every 2D box of a second camera added to each frame",
                         second_camera="all_boxes"))
    register_condition(C("second_camera_half_frames", "every other frame from a second camera",
                         second_camera="half_frames"))
    register_condition(C("mirrored", "image mirrored left-right (u -> W - u)", mirrored=True))
    register_condition(C("box3d_noise", "3D box noise: 0.1 m centre, 3 % size, 2 deg yaw (1 sigma)",
                         center_noise_m=0.1, size_noise_frac=0.03, yaw_noise_deg=2.0))
    register_condition(C("boxes_in_camera_frame", "3D boxes (centres) and points given in the camera frame "
                         "(x right, y down, z forward) instead of the LiDAR frame", box3d_frame="camera"))
    register_condition(C("dropout", "detection dropout: 35 % of 2D and 35 % of 3D detections missed",
                         miss_rate_2d=0.35, miss_rate_3d=0.35))
    _detector_conditions()


def _detector_conditions() -> None:
    """2D boxes as a real detector draws them (issue 25 item 5; ``xcalib.data.synth.detector``).
    Each isolates one habit on top of exact, 1 px boxes; ``detector_all`` has all of them."""
    C, D = RealismCondition, DetectorStyle
    off = dict(outline=False, merge_prob=0.0, class_misses=False, part_boxes=False, score_noise=False)
    base = dict(miss_rate_2d=0.0)  # the detector's own (class-dependent) misses, or none
    register_condition(C("detector_outline", "2D boxes are the visible outline of vehicle-shaped objects (a car "
                         "~10 % narrower, ~12 % lower than its cuboid's corner box; per object and per box jitter; "
                         "persons' boxes wider)", detector=D(**{**off, "outline": True}), **base))
    register_condition(C("detector_truncation", "objects cut by the image border up to 90 % are detected, their "
                         "boxes end at the border; visible outline", detector=D(**{**off, "outline": True}),
                         max_truncation=0.9, **base))
    register_condition(C("detector_merge", "two overlapping vehicles (or persons) drawn as one box with "
                         "probability 0.5", detector=D(**{**off, "merge_prob": 0.5}), **base))
    register_condition(C("detector_misses", "class-dependent misses (persons 15 %, cars 4 %; more for small and "
                         "occluded objects), truck cabs as false car boxes, duplicate boxes",
                         detector=D(**{**off, "class_misses": True, "part_boxes": True}), **base))
    register_condition(C("detector_scores", "score-dependent box noise: 1 px + 6 % of the size x (1 - score), "
                         "scores lower for small, occluded, truncated objects; boxes below 0.3 dropped",
                         detector=D(**{**off, "score_noise": True}), **base))
    register_condition(C("detector_all", "a real detector: visible outline, truncation up to 90 %, merges, "
                         "class-dependent misses and false boxes, score-dependent noise",
                         detector=D(), max_truncation=0.9, **base))


_builtin()


@dataclass(frozen=True)
class RealismCase:
    """One site under one condition.

    frames: what the calibrator sees (``intrinsics`` = ``intrinsics_given``; ``extrinsics`` and
    ``match_matrix`` removed; ``meta`` keeps the generator's per-box ids for diagnostics).
    T_cam_lidar: the true extrinsics [4,4] from the frame the 3D boxes are given in (identity
    when they are given in the camera frame); time_offset_s: true camera minus LiDAR time (s).
    objects_seen / true_pairs: distinct objects seen by both sensors and true 2D-3D detections.
    """

    condition: RealismCondition
    site_seed: int
    frames: tuple[Frame, ...]
    intrinsics_given: CameraIntrinsics
    intrinsics_true: CameraIntrinsics
    T_cam_lidar: np.ndarray
    time_offset_s: float
    objects_seen: int
    true_pairs: int

    @property
    def identifiable(self) -> bool:
        return self.objects_seen >= MIN_OBJECTS and self.true_pairs >= MIN_TRUE_PAIRS


def second_camera_site(site: Site) -> Site:
    """A second camera on the same mount (0.3 m aside) turned 25-35 deg (sign drawn) about the
    vertical, same intrinsics and LiDAR; the same traffic (same seed and road layout)."""
    rng = np.random.default_rng([site.seed, 5151])
    turn = float(rng.choice([-1.0, 1.0]) * rng.uniform(25.0, 35.0))
    Rz = euler_to_matrix([0.0, 0.0, turn], "xyz", degrees=True)
    T = site.T_world_cam.copy()
    T[:3, :3] = Rz @ T[:3, :3]
    T[:3, 3] += Rz @ np.array([0.3, 0.0, 0.0])
    return dataclasses.replace(site, T_world_cam=T, camera_name=site.camera_name + "_2",
                               values={**site.values, "second_camera_turn_deg": turn}, _cache={})


def _truth_counts(frames) -> tuple[int, int]:
    ids, n = set(), 0
    for f in frames:
        rows = np.flatnonzero(f.match_matrix.any(1))
        n += len(rows)
        ids.update(int(f.meta["ids_2d"][i]) for i in rows)
    return len(ids), n


def _merge(f1: Frame, f2: Frame, take: np.ndarray, cam2: str) -> Frame:
    """Frame ``f1`` with the 2D boxes ``take`` of ``f2`` (another camera, same instant) added."""
    b2 = np.vstack([f1.bboxes_2d, f2.bboxes_2d[take]]).astype(np.float32)
    meta = dict(f1.meta)
    meta["ids_2d"] = np.concatenate([f1.meta["ids_2d"], f2.meta["ids_2d"][take]])
    meta["camera_2d"] = [f1.camera_name] * f1.num_2d + [cam2] * len(take)
    for k in ("classes_2d", "boxes_2d_clean", "visibility_2d", "truncation_2d"):
        meta.pop(k, None)
    return dataclasses.replace(f1, bboxes_2d=b2, match_matrix=None, meta=meta)


def _mix_second_camera(cond: RealismCondition, site: Site, frames: list[Frame], seed: int, noise: dict) -> list[Frame]:
    site2 = second_camera_site(site)
    frames2 = generate_frames(site2, len(frames), seed=seed, render_images=False, lidar=cond.lidar_points, **noise)
    rng = np.random.default_rng([site.seed, 6262])
    out = []
    for k, (f1, f2) in enumerate(zip(frames, frames2)):
        if cond.second_camera == "half_frames":
            f = f2 if k % 2 else f1
            meta = {**f.meta, "camera_2d": [f.camera_name] * f.num_2d}
            out.append(dataclasses.replace(f, camera_name=site.camera_name, match_matrix=None, meta=meta))
            continue
        if cond.second_camera == "all_boxes":
            take = np.arange(f2.num_2d)
        else:
            s = cond.second_camera_share
            n = min(f2.num_2d, int(round(s / (1.0 - s) * f1.num_2d)))
            take = np.sort(rng.choice(f2.num_2d, size=n, replace=False))
        out.append(_merge(f1, f2, take, site2.camera_name))
    return out


def _to_camera_frame(f: Frame, T_cam_lidar: np.ndarray) -> Frame:
    """Frame ``f`` with its 3D boxes' centres and its points moved into the camera frame (box7
    rows, size and yaw as they were; the generator's ``box7`` meta dropped)."""
    R, t = T_cam_lidar[:3, :3], T_cam_lidar[:3, 3]
    meta = dict(f.meta)
    b7 = np.array(meta.pop("box7"), dtype=np.float64)
    b7[:, :3] = b7[:, :3] @ R.T + t
    pts = np.array(f.point_cloud, dtype=np.float32)
    if len(pts):
        pts[:, :3] = pts[:, :3] @ R.T.astype(np.float32) + t.astype(np.float32)
    return dataclasses.replace(f, bboxes_3d=b7.astype(np.float32), point_cloud=pts, meta=meta)


def make_realism_case(condition: RealismCondition | str, site_seed: int, n_frames: int = 20) -> RealismCase:
    """Site ``sample_site(site_seed, "roadside")`` bent by ``condition``, ``n_frames`` at 10 Hz."""
    cond = REALISM_CONDITIONS[condition] if isinstance(condition, str) else condition
    site = sample_site(site_seed, "roadside", **cond.site_overrides(int(preset_config("roadside").width)))
    noise = cond.noise()
    frames = generate_frames(site, n_frames, seed=site_seed, render_images=False, lidar=cond.lidar_points, **noise)
    n_obj, n_true = _truth_counts(frames)
    if cond.detector is not None:
        frames = [detector_frame(f, cond.detector, (site.width, site.height), site.seed) for f in frames]
    if cond.second_camera != "none":
        frames = _mix_second_camera(cond, site, frames, site_seed, noise)
    T_true = site.T_cam_lidar.copy()
    if cond.box3d_frame == "camera":
        frames = [_to_camera_frame(f, site.T_cam_lidar) for f in frames]
        T_true = np.eye(4)  # the given 3D frame is the camera's
    seen = tuple(dataclasses.replace(f, extrinsics=None, match_matrix=None) for f in frames)
    return RealismCase(condition=cond, site_seed=int(site_seed), frames=seen, intrinsics_given=site.intrinsics_given,
                       intrinsics_true=site.intrinsics, T_cam_lidar=T_true,
                       time_offset_s=float(site.config.camera_time_offset_s), objects_seen=n_obj, true_pairs=n_true)


def identifiable_site_seeds(n: int, n_frames: int = 20, start: int = 0, max_tries: int = 1000) -> list[int]:
    """The first ``n`` site seeds from ``start`` whose *clean* case is identifiable."""
    out: list[int] = []
    clean = REALISM_CONDITIONS["clean"]
    for seed in range(start, start + max_tries):
        if len(out) >= n:
            break
        if make_realism_case(clean, seed, n_frames).identifiable:
            out.append(seed)
    if len(out) < n:
        raise RuntimeError(f"only {len(out)} identifiable sites among seeds {start}..{start + max_tries - 1}")
    return out

