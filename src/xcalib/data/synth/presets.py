"""Site configuration: every geometry, sensor and noise level of a synthetic site.

A field holding a ``(lo, hi)`` tuple is drawn uniformly per site (ints for integer fields);
a scalar fixes it. Override any field by keyword: ``sample_site(3, camera_height=10.0,
focal_px=(1200, 1400), box_noise_px=0.0)``. Lengths in metres, angles in degrees, pixels for
image quantities, speeds in m/s.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

__all__ = ["SiteConfig", "PRESETS", "preset_config", "NOISE_FIELDS", "zero_noise", "CLASS_SIZES"]

Range = float | tuple[float, float]

# class -> (mean [l, w, h], std [l, w, h]) in metres, typical of road-user statistics.
CLASS_SIZES: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "car": ((4.5, 1.85, 1.5), (0.3, 0.08, 0.08)),
    "van": ((5.3, 2.0, 2.2), (0.35, 0.08, 0.15)),
    "truck": ((9.0, 2.5, 3.3), (2.0, 0.08, 0.3)),
    "bus": ((12.0, 2.55, 3.2), (0.6, 0.04, 0.1)),
    "pedestrian": ((0.6, 0.6, 1.72), (0.08, 0.08, 0.09)),
    "cyclist": ((1.8, 0.6, 1.7), (0.1, 0.06, 0.08)),
}

NOISE_FIELDS = ("box_noise_px", "miss_rate_2d", "miss_rate_3d", "false_positive_rate_2d",
                "false_positive_rate_3d", "center_noise_m", "size_noise_frac", "yaw_noise_deg",
                "lidar_range_noise_m", "lidar_dropout")


def zero_noise() -> dict[str, float]:
    """Overrides that switch every detection and LiDAR noise source off."""
    return {k: 0.0 for k in NOISE_FIELDS}


@dataclass
class SiteConfig:
    """All parameters of a synthetic site (see the module docstring for ranges vs scalars)."""

    preset: str = "roadside"
    # ---- image and lens (pixels)
    width: int = 1920
    height: int = 1200
    focal_px: Range = (1000.0, 2500.0)
    aspect: float = 1.0                      # fy / fx
    principal_jitter_px: float = 20.0        # cx, cy offset from the image centre
    distortion: bool = False                 # OpenCV k1 k2 p1 p2 k3 when True
    k1: Range = (-0.15, 0.05)
    k2: Range = (-0.03, 0.05)
    tangential: Range = (-5e-4, 5e-4)
    camera_model: str = "pinhole"            # or kannala_brandt, unified, ucm, eucm, double_sphere
                                             # (xcalib.geometry.camera_models; images and boxes
                                             # through it, typical lens parameters, see site.py)
    hfov_deg: Range | None = None            # horizontal field of view: sets the focal length
                                             # (None: focal_px; a wide-angle model needs it)
    # ---- road layout (metres)
    lanes_per_direction: tuple[int, int] | int = (1, 3)
    lane_width: float = 3.5
    bike_lane_width: float = 1.6
    sidewalk_width: float = 3.0
    scene_half_length: float = 90.0          # lanes run over [-L, L] from the intersection centre
    # ---- camera mount (roadside: pole/gantry; vehicle: car rig)
    camera_height: Range = (5.0, 12.0)
    camera_setback_m: Range = (1.0, 18.0)    # pole distance beyond the sidewalks
    gantry_prob: float = 0.3                 # probability of a gantry over the road instead of a pole
    look_at_jitter_m: Range = (-8.0, 8.0)    # aim point around the intersection centre
    camera_yaw_offset_deg: Range = (-12.0, 12.0)  # yaw relative to aiming at the aim point
    camera_pitch_deg: Range | None = None    # degrees below horizontal; None = aim at the aim point
    camera_roll_deg: Range = (-2.0, 2.0)
    # ---- LiDAR mount relative to the camera
    lidar_offset_m: Range = (0.5, 4.0)       # horizontal distance from the camera
    lidar_dz_m: Range = (-2.5, 0.5)          # height relative to the camera
    lidar_yaw_offset_deg: Range = (15.0, 60.0)  # |yaw difference| (sign drawn at random)
    lidar_tilt_deg: Range = (5.0, 15.0)      # physical sensor pitch (changes the ring pattern)
    lidar_min_height: float = 2.5
    # ---- LiDAR scanner
    lidar_beams: int = 64
    lidar_vfov_deg: tuple[float, float] = (-30.0, 15.0)
    lidar_azimuth_steps: int = 2048
    lidar_max_range: float = 120.0
    lidar_min_range: float = 0.8
    lidar_range_noise_m: float = 0.02
    lidar_dropout: float = 0.05
    # ---- traffic
    n_objects: tuple[int, int] | int = (3, 30)   # target objects in the scene per sequence
    class_weights: dict[str, float] = field(default_factory=lambda: {
        "car": 0.62, "van": 0.15, "truck": 0.12, "bus": 0.11})
    vehicle_speed: Range = (5.0, 13.0)
    cyclist_speed: Range = (3.0, 6.0)
    pedestrian_speed: Range = (0.9, 1.7)
    min_gap_m: float = 3.0
    frame_dt: float = 0.1                    # seconds between frames (10 Hz)
    moving_share: float = 1.0                # scales the density of moving road users (0: none)
    queue_share: float = 0.25                # expected queued vehicles per target object
    queue_max: int = 6                       # longest queue per stopped lane
    # ---- sensor timing and the calibration handed to the user (realism; defaults = ideal)
    camera_time_offset_s: float = 0.0        # camera exposure time minus LiDAR sweep time (s):
                                             # 2D boxes see the scene at the camera time
    given_focal_scale: float = 1.0           # Frame.intrinsics fx, fy = true ones x this
    given_principal_offset_px: tuple[float, float] = (0.0, 0.0)  # added to the true cx, cy
    image_mirrored: bool = False             # the camera delivers u -> W - u (image and 2D boxes)
    # ---- detection noise and visibility
    box_noise_px: float = 2.0                # std of each 2D box coordinate
    miss_rate_2d: float = 0.05               # probability a visible object has no 2D box
    miss_rate_3d: float = 0.05               # probability an object in LiDAR range has no 3D box
    false_positive_rate_2d: float = 0.05     # expected false 2D boxes per true 2D box (Poisson)
    false_positive_rate_3d: float = 0.05     # expected false 3D boxes per true 3D box (Poisson)
    center_noise_m: float = 0.1              # std of each 3D centre coordinate
    size_noise_frac: float = 0.03            # std of the relative 3D size error
    yaw_noise_deg: float = 2.0               # std of the 3D yaw error
    min_visible_fraction: float = 0.2        # occlusion: fewer visible pixels -> no 2D box
    max_truncation: float = 0.6              # share of the box outside the image -> no 2D box
    min_box_px: float = 8.0                  # smaller 2D boxes are not detected
    detection_range_3d: float = 90.0         # horizontal distance from the LiDAR
    lidar_blind_radius_m: float = 0.0        # no returns and no 3D boxes nearer (horizontal range)
    box3d_yaw: str = "kept"                  # "dropped": exported boxes lose their yaw (A9): length
                                             # along LiDAR x, protocol [M,6] only, no meta box7
    box_convention: str = "extents"          # protocol [M,6] layout: "extents" or "center"
    # ---- rendering
    jpeg_quality: int = 90

    def replace(self, **overrides) -> "SiteConfig":
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(overrides) - names)
        if unknown:
            raise TypeError(f"SiteConfig: unknown parameter(s) {unknown}; see SiteConfig fields")
        return dataclasses.replace(self, **overrides)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


_VEHICLE = dict(
    preset="vehicle", camera_height=(1.3, 1.7), camera_pitch_deg=(-1.0, 6.0), camera_yaw_offset_deg=(-3.0, 3.0),
    camera_roll_deg=(-1.0, 1.0), lidar_offset_m=(0.1, 1.5), lidar_dz_m=(0.1, 0.6), lidar_yaw_offset_deg=(0.0, 5.0),
    lidar_tilt_deg=(0.0, 1.0), lidar_min_height=1.4, lidar_vfov_deg=(-25.0, 15.0), gantry_prob=0.0,
    focal_px=(1000.0, 1800.0),
)

PRESETS: dict[str, dict] = {"roadside": {"preset": "roadside"}, "vehicle": _VEHICLE}


def preset_config(preset: str = "roadside", **overrides) -> SiteConfig:
    """The :class:`SiteConfig` of a preset with ``overrides`` applied."""
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; expected one of {sorted(PRESETS)}")
    return SiteConfig().replace(**PRESETS[preset]).replace(**overrides)


def _draw(rng: np.random.Generator, v, integer: bool = False):
    """Scalar -> itself; (lo, hi) -> uniform draw (inclusive ints when ``integer``)."""
    if isinstance(v, (tuple, list)):
        lo, hi = v
        return int(rng.integers(int(lo), int(hi) + 1)) if integer else float(rng.uniform(lo, hi))
    return int(v) if integer else float(v)
