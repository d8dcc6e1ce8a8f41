"""A sampled site: road layout, camera and LiDAR poses, intrinsics, light (world frame: z up, metres).

World frame: ground plane z = 0, intersection centre at the origin, road A along x, road B along y.
The LiDAR frame is gravity-levelled (origin at the sensor, z up, x along the sensor heading); the
physical sensor tilt only shapes the ring pattern. ``T_cam_lidar`` maps that LiDAR frame to the
OpenCV camera frame (``xcalib.geometry`` convention).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ...geometry.camera import CameraIntrinsics
from ...geometry.camera_models import CameraModel, canonical_name, get_model
from ...geometry.rotations import euler_to_matrix
from ...geometry.transforms import invert_transform, make_transform
from .presets import SiteConfig, _draw, preset_config  # noqa: F401  (_draw: re-exported for old imports)

__all__ = ["Site", "sample_site", "camera_rotation"]


def camera_rotation(yaw_deg: float, pitch_down_deg: float, roll_deg: float) -> np.ndarray:
    """R_world_cam (columns = camera x right, y down, z forward in world) for a heading ``yaw``
    (counter-clockwise from world +x), a downward pitch and a roll about the optical axis."""
    psi, th, phi = np.radians([yaw_deg, pitch_down_deg, roll_deg])
    f = np.array([math.cos(th) * math.cos(psi), math.cos(th) * math.sin(psi), -math.sin(th)])
    r = np.array([math.sin(psi), -math.cos(psi), 0.0])
    d = np.cross(f, r)
    r2 = math.cos(phi) * r + math.sin(phi) * d
    d2 = -math.sin(phi) * r + math.cos(phi) * d
    return np.stack([r2, d2, f], axis=1)


@dataclass
class Site:
    """One synthetic site. Poses are 4x4 (``T_world_cam`` maps camera -> world)."""

    config: SiteConfig
    seed: int
    intrinsics: CameraIntrinsics | CameraModel   # a CameraModel for a wide-angle camera_model
    T_world_cam: np.ndarray
    T_world_lidar: np.ndarray
    R_lidar_sensor: np.ndarray          # physical scanner orientation in the levelled LiDAR frame
    lanes_a: int                        # lanes per direction on road A (along x)
    lanes_b: int                        # lanes per direction on road B (along y)
    mount: str                          # "pole", "gantry" or "car"
    sun_dir: np.ndarray                 # unit vector towards the sun (world)
    values: dict = field(default_factory=dict)   # every drawn value, for site.json
    camera_name: str = "camera"
    lidar_name: str = "lidar"
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def preset(self) -> str:
        return self.config.preset

    @property
    def width(self) -> int:
        return int(self.config.width)

    @property
    def height(self) -> int:
        return int(self.config.height)

    @property
    def T_cam_lidar(self) -> np.ndarray:
        """Ground-truth extrinsics: levelled LiDAR frame -> OpenCV camera frame."""
        return invert_transform(self.T_world_cam) @ self.T_world_lidar

    @property
    def intrinsics_given(self) -> CameraIntrinsics:
        """The intrinsics handed to the user (``Frame.intrinsics``): the true ones with fx, fy x
        ``given_focal_scale`` and cx, cy + ``given_principal_offset_px`` (= ``intrinsics`` by default)."""
        c, k = self.config, self.intrinsics
        s, (dx, dy) = float(c.given_focal_scale), c.given_principal_offset_px
        if s == 1.0 and dx == 0.0 and dy == 0.0:
            return k
        if isinstance(k, CameraModel):
            return k.replace(fx=k.fx * s, fy=k.fy * s, cx=k.cx + float(dx), cy=k.cy + float(dy))
        return CameraIntrinsics(k.fx * s, k.fy * s, k.cx + float(dx), k.cy + float(dy), k.distortion, k.width, k.height)

    @property
    def T_cam_world(self) -> np.ndarray:
        return invert_transform(self.T_world_cam)

    @property
    def T_lidar_world(self) -> np.ndarray:
        return invert_transform(self.T_world_lidar)

    @property
    def camera_position(self) -> np.ndarray:
        return self.T_world_cam[:3, 3].copy()

    @property
    def lidar_position(self) -> np.ndarray:
        return self.T_world_lidar[:3, 3].copy()

    @property
    def lidar_yaw(self) -> float:
        """Heading of the levelled LiDAR frame in the world (radians)."""
        return float(math.atan2(self.T_world_lidar[1, 0], self.T_world_lidar[0, 0]))

    def half_width(self, road: str) -> float:
        """Half width of road ``"a"`` or ``"b"`` including bike lanes and sidewalks (metres)."""
        c = self.config
        n = self.lanes_a if road == "a" else self.lanes_b
        return n * c.lane_width + c.bike_lane_width + c.sidewalk_width

    @property
    def background(self) -> np.ndarray:
        """Rendered static background [H,W,3] uint8 RGB (ground, markings, sky); cached."""
        if "background" not in self._cache:
            from .render import render_background

            bg = render_background(self)
            bg.setflags(write=False)
            self._cache["background"] = bg
        return self._cache["background"]

    def to_dict(self) -> dict:
        """JSON-ready description: config, drawn values and ground truth."""
        return {
            "seed": self.seed, "preset": self.preset, "config": self.config.to_dict(), "values": self.values,
            "camera_name": self.camera_name, "lidar_name": self.lidar_name, "mount": self.mount,
            "image_size": [self.width, self.height], "intrinsics": self.intrinsics.to_dict(),
            "T_cam_lidar": self.T_cam_lidar.tolist(), "T_world_cam": self.T_world_cam.tolist(),
            "T_world_lidar": self.T_world_lidar.tolist(), "R_lidar_sensor": self.R_lidar_sensor.tolist(),
            "lanes_per_direction": {"a": self.lanes_a, "b": self.lanes_b}, "sun_dir": self.sun_dir.tolist(),
            "frames": {"world": "z up, ground z=0, intersection at origin, road A along x, road B along y",
                       "lidar": "levelled: origin at the sensor, z up, x along the sensor heading",
                       "camera": "OpenCV: x right, y down, z forward"},
        }


def sample_site(seed: int, preset: str = "roadside", **overrides) -> Site:
    """Draw a site deterministically from ``seed`` (see :class:`SiteConfig` for ``overrides``)."""
    cfg = preset_config(preset, **overrides)
    rng = np.random.default_rng([int(seed), 7919])
    v: dict = {}
    W, H = int(cfg.width), int(cfg.height)
    if W < 16 or H < 16:
        raise ValueError(f"SiteConfig: image size {W}x{H} px is too small (>= 16x16 expected)")
    if cfg.box3d_yaw not in ("kept", "dropped"):
        raise ValueError(f"SiteConfig: box3d_yaw must be 'kept' or 'dropped', got {cfg.box3d_yaw!r}")
    if not cfg.given_focal_scale > 0:
        raise ValueError(f"SiteConfig: given_focal_scale must be > 0, got {cfg.given_focal_scale}")
    # lens
    fx = v["focal_px"] = _draw(rng, cfg.focal_px)
    cx = W / 2.0 + rng.uniform(-1, 1) * cfg.principal_jitter_px
    cy = H / 2.0 + rng.uniform(-1, 1) * cfg.principal_jitter_px
    dist = None
    if cfg.distortion:
        dist = np.array([_draw(rng, cfg.k1), _draw(rng, cfg.k2), _draw(rng, cfg.tangential),
                         _draw(rng, cfg.tangential), 0.0])
        v["distortion"] = dist.tolist()
    intr = CameraIntrinsics(fx, fx * cfg.aspect, cx, cy, dist, W, H)
    if cfg.camera_model != "pinhole" or cfg.hfov_deg is not None:
        intr = _camera_with_fov(cfg, rng, intr, v)
    # roads
    na = v["lanes_a"] = _draw(rng, cfg.lanes_per_direction, integer=True)
    nb = v["lanes_b"] = _draw(rng, cfg.lanes_per_direction, integer=True)
    extra = cfg.bike_lane_width + cfg.sidewalk_width
    ha, hb = na * cfg.lane_width + extra, nb * cfg.lane_width + extra
    # camera mount
    h = v["camera_height"] = _draw(rng, cfg.camera_height)
    qx, qy = rng.choice([-1.0, 1.0], size=2)
    aim = np.array([_draw(rng, cfg.look_at_jitter_m), _draw(rng, cfg.look_at_jitter_m), 0.0])
    if cfg.preset == "vehicle":
        mount = "car"
        pos = np.array([0.5 * cfg.lane_width + rng.uniform(-0.3, 0.3), -(ha + 1.5), h])
        aim = pos + np.array([0.0, 30.0, -h])
    elif rng.uniform() < cfg.gantry_prob:
        mount = "gantry"
        pos = np.array([qx * (hb + _draw(rng, cfg.camera_setback_m)), qy * rng.uniform(0, na * cfg.lane_width), h])
    else:
        mount = "pole"
        pos = np.array([qx * (hb + _draw(rng, cfg.camera_setback_m)), qy * (ha + _draw(rng, cfg.camera_setback_m)), h])
    d = aim[:2] - pos[:2]
    yaw = math.degrees(math.atan2(d[1], d[0])) + _draw(rng, cfg.camera_yaw_offset_deg)
    if cfg.camera_pitch_deg is None:
        pitch = math.degrees(math.atan2(h, max(float(np.linalg.norm(d)), 1.0)))
    else:
        pitch = _draw(rng, cfg.camera_pitch_deg)
    roll = _draw(rng, cfg.camera_roll_deg)
    v.update(camera_yaw_deg=yaw, camera_pitch_deg=pitch, camera_roll_deg=roll, mount=mount,
             camera_position=pos.tolist(), aim_point=aim.tolist())
    T_world_cam = make_transform(camera_rotation(yaw, pitch, roll), pos)
    # LiDAR mount
    r = _draw(rng, cfg.lidar_offset_m)
    ang = rng.uniform(-math.pi, math.pi)
    lpos = pos + np.array([r * math.cos(ang), r * math.sin(ang), _draw(rng, cfg.lidar_dz_m)])
    lpos[2] = max(lpos[2], cfg.lidar_min_height)
    lyaw = yaw + float(rng.choice([-1.0, 1.0])) * _draw(rng, cfg.lidar_yaw_offset_deg)
    tilt = _draw(rng, cfg.lidar_tilt_deg)
    v.update(lidar_position=lpos.tolist(), lidar_yaw_deg=lyaw, lidar_tilt_deg=tilt)
    T_world_lidar = make_transform(euler_to_matrix([0.0, 0.0, lyaw], "xyz", degrees=True), lpos)
    R_tilt = euler_to_matrix([0.0, tilt, 0.0], "xyz", degrees=True)
    # light
    saz, sel = rng.uniform(0, 2 * math.pi), math.radians(rng.uniform(25, 65))
    sun = np.array([math.cos(sel) * math.cos(saz), math.cos(sel) * math.sin(saz), math.sin(sel)])
    return Site(config=cfg, seed=int(seed), intrinsics=intr, T_world_cam=T_world_cam,
                T_world_lidar=T_world_lidar, R_lidar_sensor=R_tilt, lanes_a=na, lanes_b=nb, mount=mount,
                sun_dir=sun, values=v)


#: typical lens parameters of each wide-angle model (fisheye lenses of 120-200 degrees)
WIDE_ANGLE_PARAMS: dict[str, dict] = {
    "kannala_brandt": {"k": (0.03, -0.006, 0.001, -0.0002)},
    "unified": {"xi": 1.1, "distortion": (-0.05, 0.01, 0.0002, -0.0002)},
    "ucm": {"alpha": 0.6},
    "eucm": {"alpha": 0.62, "beta": 1.05},
    "double_sphere": {"xi": -0.2, "alpha": 0.6},
}


def _camera_with_fov(cfg: SiteConfig, rng: np.random.Generator, intr: CameraIntrinsics, v: dict):
    """The site's camera for ``camera_model`` / ``hfov_deg``: the focal length that spans the
    drawn horizontal field of view over the image width (``v`` records the values)."""
    name = canonical_name(cfg.camera_model)
    if name in ("pinhole", "pinhole_radtan"):
        name = "pinhole"
    if name != "pinhole" and name not in WIDE_ANGLE_PARAMS:
        raise ValueError(f"SiteConfig.camera_model: no synthetic lens for {cfg.camera_model!r}; expected pinhole or "
                         f"one of {', '.join(WIDE_ANGLE_PARAMS)}")
    if cfg.hfov_deg is None:
        raise ValueError(f"SiteConfig.hfov_deg: a {name} camera needs the horizontal field of view (degrees)")
    hfov = v["hfov_deg"] = _draw(rng, cfg.hfov_deg)
    limit = 179.0 if name == "pinhole" else 200.0
    if not 10.0 <= hfov <= limit:
        raise ValueError(f"SiteConfig.hfov_deg: expected 10..{limit:g} degrees for a {name} camera, got {hfov:g}")
    half = math.radians(hfov / 2.0)
    if name == "pinhole":
        f = (intr.width / 2.0) / math.tan(half)
        v["focal_px"] = f
        return CameraIntrinsics(f, f * cfg.aspect, intr.cx, intr.cy, intr.distortion, intr.width, intr.height)
    unit = get_model(name)(fx=1.0, fy=1.0, cx=0.0, cy=0.0, **WIDE_ANGLE_PARAMS[name])
    r, ok = unit.project(np.array([[math.sin(half), 0.0, math.cos(half)]]))
    if not ok[0]:
        raise ValueError(f"SiteConfig.hfov_deg: {hfov:g} degrees is beyond the {name} lens's field of view")
    f = (intr.width / 2.0) / float(r[0, 0])
    v["focal_px"], v["camera_model"] = f, name
    return get_model(name)(fx=f, fy=f * cfg.aspect, cx=intr.cx, cy=intr.cy, width=intr.width, height=intr.height,
                           **WIDE_ANGLE_PARAMS[name])
