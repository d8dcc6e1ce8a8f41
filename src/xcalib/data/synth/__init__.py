"""Synthetic camera + LiDAR sites with exact ground truth (matches and ``T_cam_lidar``).

``sample_site(seed, preset="roadside"|"vehicle", **overrides) -> Site`` draws a site (poses,
intrinsics, road layout; every parameter in :class:`SiteConfig`); ``generate_frames(site, n, seed)``
/ ``iter_frames`` give ``xcalib.types.Frame`` records; ``write_site(out_dir, n_train, n_val, n_test,
seed, preset)`` writes HDF5 caches + ``site.json``; ``contact_sheet(frames, path)`` draws a PNG grid.
Modules: presets (config), site (poses), scene (traffic), detections (labels), render (images),
lidar (ray casting), generate (frames, caches), contact (contact sheet).
"""

from .generate import SPLITS, blank_image, generate_frames, iter_frames, write_site
from .presets import CLASS_SIZES, NOISE_FIELDS, PRESETS, SiteConfig, preset_config, zero_noise
from .site import Site, sample_site

__all__ = ["SiteConfig", "Site", "sample_site", "generate_frames", "iter_frames", "write_site", "PRESETS",
           "preset_config", "zero_noise", "NOISE_FIELDS", "CLASS_SIZES", "SPLITS", "blank_image",
           "contact_sheet"]


def __getattr__(name: str):
    if name == "contact_sheet":
        from .contact import contact_sheet

        return contact_sheet
    raise AttributeError(f"module 'xcalib.data.synth' has no attribute {name!r}")
